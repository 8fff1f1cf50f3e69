#include <uav_mapping/vdb_map.h>

#include <openvdb/io/File.h>
#include <openvdb/math/Transform.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <memory>
#include <mutex>

namespace uav_mapping {

namespace {

constexpr const char* kLogOddsName = "log_odds";
constexpr const char* kTimeName = "time_s";
constexpr const char* kColorName = "color_rgb";
constexpr const char* kFormatKey = "uav_autonomy_map_format";
constexpr const char* kFormatValue = "openvdb-voxel-map-1";

inline openvdb::Coord coordOf(const Key& k) {
  return openvdb::Coord(static_cast<int>(k[0]) - kKeyOffset, static_cast<int>(k[1]) - kKeyOffset,
                        static_cast<int>(k[2]) - kKeyOffset);
}
inline Key keyOf(const openvdb::Coord& c) {
  return Key(static_cast<uint16_t>(c.x() + kKeyOffset), static_cast<uint16_t>(c.y() + kKeyOffset),
             static_cast<uint16_t>(c.z() + kKeyOffset));
}
inline int32_t packRgb(uint8_t r, uint8_t g, uint8_t b) {
  return static_cast<int32_t>((static_cast<uint32_t>(r) << 16) | (static_cast<uint32_t>(g) << 8) | b);
}

void initOpenVdb() {
  static std::once_flag once;
  std::call_once(once, [] {
    openvdb::initialize();
    if (!VdbFloatGrid::isRegistered()) VdbFloatGrid::registerGrid();
    if (!VdbInt32Grid::isRegistered()) VdbInt32Grid::registerGrid();
  });
}

}  // namespace

VdbMap::VdbMap(double resolution_m, const SensorModel& model) : VoxelMap(resolution_m, model) {
  initOpenVdb();
  makeGrids();
}

void VdbMap::makeGrids() {
  auto transform = openvdb::math::Transform::createLinearTransform(resolution_m_);
  transform->postTranslate(openvdb::Vec3d(0.5 * resolution_m_));  // index i is the voxel [i*res, (i+1)*res)
  log_odds_ = VdbFloatGrid::create(0.0f);
  log_odds_->setName(kLogOddsName);
  log_odds_->setTransform(transform);
  time_ = VdbFloatGrid::create(kNoTime);
  time_->setName(kTimeName);
  time_->setTransform(transform->copy());
  color_ = VdbInt32Grid::create(0);
  color_->setName(kColorName);
  color_->setTransform(transform->copy());
}

void VdbMap::apply(const FrameUpdate& frame, float time_s, std::vector<uint8_t>& transitions) {
  const std::size_t n = frame.updates.size();
  transitions.resize(n);
  std::vector<openvdb::Coord> touched;
  {
    auto lo = log_odds_->getAccessor();
    auto ta = time_->getAccessor();
    auto ca = color_->getAccessor();
    const LogOddsModel& m = logodds_;
    openvdb::Coord last_leaf(std::numeric_limits<int>::max());
    for (std::size_t i = 0; i < n; ++i) {
      const VoxelUpdate& u = frame.updates[i];
      const openvdb::Coord c = coordOf(keyOfMorton(u.morton));
      float old = 0.0f;
      const bool known = lo.probeValue(c, old);
      if (!known) old = 0.0f;
      uint8_t t = 0;
      if (known) {
        t |= kWasKnown;
        if (old >= m.occupied) t |= kWasOccupied;
      }
      float v = old + (u.hit ? m.hit : m.miss);  // same arithmetic as the octree (OctoMap updateNodeLogOdds)
      if (v < m.clamp_min)
        v = m.clamp_min;
      else if (v > m.clamp_max)
        v = m.clamp_max;
      lo.setValue(c, v);
      float old_t = kNoTime;
      ta.probeValue(c, old_t);
      ta.setValue(c, std::max(old_t, time_s));  // last observation = latest stamp
      if (u.hit && u.has_color) {
        int32_t stored = 0;
        if (ca.probeValue(c, stored)) {
          const auto s = static_cast<uint32_t>(stored);
          ca.setValue(c, packRgb(blendChannel((s >> 16) & 0xFF, u.r, color_weight_q8_),
                                 blendChannel((s >> 8) & 0xFF, u.g, color_weight_q8_),
                                 blendChannel(s & 0xFF, u.b, color_weight_q8_)));
        } else {
          ca.setValue(c, packRgb(u.r, u.g, u.b));
        }
      }
      if (v >= m.occupied) t |= kIsOccupied;
      transitions[i] = t;
      const openvdb::Coord leaf = c & ~(kVdbLeafDim - 1);
      if (leaf != last_leaf) {  // Morton order keeps each leaf (an aligned power-of-two cube) contiguous
        touched.push_back(leaf);
        last_leaf = leaf;
      }
    }
  }
  if (prune_) pruneLeaves(touched);
}

void VdbMap::pruneLeaves(const std::vector<openvdb::Coord>& leaf_origins) {
  auto& lo_tree = log_odds_->tree();
  auto& t_tree = time_->tree();
  auto& c_tree = color_->tree();
  for (const openvdb::Coord& o : leaf_origins) {
    auto* lo_leaf = lo_tree.probeLeaf(o);
    auto* t_leaf = t_tree.probeLeaf(o);
    if (lo_leaf == nullptr || t_leaf == nullptr) continue;
    float lo_value;
    float t_value;
    bool lo_on;
    bool t_on;
    if (!lo_leaf->isConstant(lo_value, lo_on) || !t_leaf->isConstant(t_value, t_on)) continue;
    auto* c_leaf = c_tree.probeLeaf(o);
    int32_t c_value = 0;
    bool c_on = false;
    if (c_leaf != nullptr) {
      if (!c_leaf->isConstant(c_value, c_on)) continue;
    } else {
      c_on = c_tree.probeValue(o, c_value);
    }
    lo_tree.addTile(1, o, lo_value, lo_on);
    t_tree.addTile(1, o, t_value, t_on);
    if (c_leaf != nullptr) c_tree.addTile(1, o, c_value, c_on);
  }
}

void VdbMap::clear() { makeGrids(); }

std::size_t VdbMap::clearBox(const KeyBox& box) {
  if (box.empty()) return 0;
  const openvdb::CoordBBox bbox(openvdb::Coord(box.min[0] - kKeyOffset, box.min[1] - kKeyOffset, box.min[2] - kKeyOffset),
                                openvdb::Coord(box.max[0] - kKeyOffset, box.max[1] - kKeyOffset, box.max[2] - kKeyOffset));
  std::vector<openvdb::CoordBBox> regions;
  for (auto it = log_odds_->cbeginValueOn(); it; ++it) {
    openvdb::CoordBBox vb = it.getBoundingBox();
    if (!vb.hasOverlap(bbox)) continue;
    vb.intersect(bbox);
    regions.push_back(vb);
  }
  std::size_t changed = 0;
  std::vector<openvdb::Coord> touched;
  {
    auto lo = log_odds_->getAccessor();
    auto ca = color_->getAccessor();
    for (const auto& r : regions) {
      for (auto c = r.beginXYZ(); c; ++c) {
        lo.setValue(*c, logodds_.clamp_min);
        ca.setValueOff(*c, 0);
        touched.push_back(*c & ~(kVdbLeafDim - 1));
        ++changed;
      }
    }
  }
  std::sort(touched.begin(), touched.end());
  touched.erase(std::unique(touched.begin(), touched.end()), touched.end());
  if (prune_) pruneLeaves(touched);
  return changed;
}

void VdbMap::forEachLeaf(const LeafVisitor& visit, bool occupied_only) const {
  auto ta = time_->getConstAccessor();
  auto ca = color_->getConstAccessor();
  const auto& t_tree = time_->tree();
  const auto& c_tree = color_->tree();
  auto emit = [&](const openvdb::Coord& c, unsigned size, float lo_value) {
    Leaf leaf;
    leaf.key = keyOf(c);
    leaf.size = size;
    leaf.state.log_odds = lo_value;
    leaf.state.time_s = ta.getValue(c);
    int32_t rgb = 0;
    leaf.state.color_set = ca.probeValue(c, rgb);
    if (leaf.state.color_set) {
      const auto u = static_cast<uint32_t>(rgb);
      leaf.state.r = (u >> 16) & 0xFF;
      leaf.state.g = (u >> 8) & 0xFF;
      leaf.state.b = u & 0xFF;
    }
    visit(leaf);
  };
  for (auto it = log_odds_->cbeginValueOn(); it; ++it) {
    const float v = *it;
    if (occupied_only && v < logodds_.occupied) continue;
    if (it.isVoxelValue()) {
      emit(it.getCoord(), 1, v);
      continue;
    }
    // A tile: emit it whole where the other grids are tiles too, else voxel by voxel.
    const openvdb::CoordBBox tb = it.getBoundingBox();
    for (int x = tb.min().x(); x <= tb.max().x(); x += kVdbLeafDim) {
      for (int y = tb.min().y(); y <= tb.max().y(); y += kVdbLeafDim) {
        for (int z = tb.min().z(); z <= tb.max().z(); z += kVdbLeafDim) {
          const openvdb::Coord o(x, y, z);
          if (t_tree.probeConstLeaf(o) == nullptr && c_tree.probeConstLeaf(o) == nullptr) {
            emit(o, kVdbLeafDim, v);
          } else {
            for (auto c = openvdb::CoordBBox(o, o.offsetBy(kVdbLeafDim - 1)).beginXYZ(); c; ++c) emit(*c, 1, v);
          }
        }
      }
    }
  }
}

bool VdbMap::query(const Key& key, VoxelState& state) const {
  const openvdb::Coord c = coordOf(key);
  float v;
  if (!log_odds_->tree().probeValue(c, v)) return false;
  state.log_odds = v;
  state.time_s = time_->tree().getValue(c);
  int32_t rgb = 0;
  state.color_set = color_->tree().probeValue(c, rgb);
  const auto u = static_cast<uint32_t>(rgb);
  state.r = state.color_set ? (u >> 16) & 0xFF : 0;
  state.g = state.color_set ? (u >> 8) & 0xFF : 0;
  state.b = state.color_set ? u & 0xFF : 0;
  return true;
}

int VdbMap::topOccupiedZ(uint16_t kx, uint16_t ky, int kz_hi, int kz_lo) const {
  auto lo = log_odds_->getConstAccessor();
  for (int kz = std::min(kz_hi, 2 * kKeyOffset - 1); kz >= std::max(kz_lo, 0); --kz) {
    float v;
    if (lo.probeValue(coordOf(Key(kx, ky, static_cast<uint16_t>(kz))), v) && v >= logodds_.occupied) return kz;
  }
  return -1;
}

std::size_t VdbMap::leafCount() const {
  return log_odds_->tree().activeLeafVoxelCount() + log_odds_->tree().activeTileCount();
}

std::size_t VdbMap::memoryBytes() const { return log_odds_->memUsage() + time_->memUsage() + color_->memUsage(); }

std::function<void()> VdbMap::prepareSave(const std::string& path, double time_origin_s) const {
  if (fileExtension(path) != ".vdb") throw MapIoError(path + ": the openvdb backend saves .vdb files");
  openvdb::GridCPtrVec grids{log_odds_->deepCopy(), time_->deepCopy(), color_->deepCopy()};
  auto meta = std::make_shared<openvdb::MetaMap>();
  meta->insertMeta(kFormatKey, openvdb::StringMetadata(kFormatValue));
  meta->insertMeta("resolution_m", openvdb::DoubleMetadata(resolution_m_));
  meta->insertMeta("time_origin_s", openvdb::DoubleMetadata(time_origin_s));
  meta->insertMeta("prob_hit", openvdb::DoubleMetadata(model_.hit));
  meta->insertMeta("prob_miss", openvdb::DoubleMetadata(model_.miss));
  meta->insertMeta("clamp_min", openvdb::DoubleMetadata(model_.clamp_min));
  meta->insertMeta("clamp_max", openvdb::DoubleMetadata(model_.clamp_max));
  return [path, grids, meta] {
    const std::string tmp = path + ".tmp";
    try {
      openvdb::io::File file(tmp);
      file.write(grids, *meta);
      file.close();
    } catch (const openvdb::Exception& e) {
      std::remove(tmp.c_str());
      throw MapIoError(path + ": " + e.what());
    }
    if (std::rename(tmp.c_str(), path.c_str()) != 0)
      throw MapIoError(path + ": rename failed: " + std::strerror(errno));
  };
}

double VdbMap::load(const std::string& path) {
  if (fileExtension(path) != ".vdb") throw MapIoError(path + ": the openvdb backend loads .vdb files");
  VdbFloatGrid::Ptr lo;
  VdbFloatGrid::Ptr t;
  VdbInt32Grid::Ptr c;
  double time_origin = std::numeric_limits<double>::quiet_NaN();
  try {
    openvdb::io::File file(path);
    file.open();
    const auto meta = file.getMetadata();
    const auto format = meta->metaValue<std::string>(kFormatKey);
    if (format != kFormatValue) throw MapIoError(path + ": not a map file of this node (format '" + format + "')");
    const double res = meta->metaValue<double>("resolution_m");
    if (std::fabs(res - resolution_m_) > 1e-9 * resolution_m_)
      throw MapIoError(path + ": resolution " + std::to_string(res) + " m differs from the map's " +
                       std::to_string(resolution_m_) + " m");
    time_origin = meta->metaValue<double>("time_origin_s");
    lo = openvdb::gridPtrCast<VdbFloatGrid>(file.readGrid(kLogOddsName));
    t = openvdb::gridPtrCast<VdbFloatGrid>(file.readGrid(kTimeName));
    c = openvdb::gridPtrCast<VdbInt32Grid>(file.readGrid(kColorName));
    file.close();
  } catch (const openvdb::Exception& e) {
    throw MapIoError(path + ": " + e.what());
  }
  if (!lo || !t || !c) throw MapIoError(path + ": grids have unexpected types");
  log_odds_ = lo;
  time_ = t;
  color_ = c;
  return time_origin;
}

}  // namespace uav_mapping
