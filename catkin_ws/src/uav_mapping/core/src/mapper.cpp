#include <uav_mapping/mapper.h>

#include <uav_mapping/octree_map.h>
#include <uav_mapping/vdb_map.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <iomanip>
#include <limits>
#include <sstream>
#include <stdexcept>

namespace uav_mapping {

namespace {
using Clock = std::chrono::steady_clock;
double msSince(Clock::time_point t0) { return std::chrono::duration<double, std::milli>(Clock::now() - t0).count(); }

int64_t floorToCell(double v, double res) { return static_cast<int64_t>(std::floor(v / res)); }
}  // namespace

std::string toString(Backend backend) { return backend == Backend::kOctomap ? "octomap" : "openvdb"; }

Backend backendFromString(const std::string& name) {
  if (name == "octomap") return Backend::kOctomap;
  if (name == "openvdb") return Backend::kOpenVdb;
  throw std::invalid_argument("backend must be octomap or openvdb, got '" + name + "'");
}

std::unique_ptr<VoxelMap> makeVoxelMap(Backend backend, double resolution_m, const SensorModel& model) {
  if (backend == Backend::kOctomap) return std::make_unique<OctreeMap>(resolution_m, model);
  return std::make_unique<VdbMap>(resolution_m, model);
}

void MapperConfig::validate() const {
  auto require = [](bool ok, const std::string& what) {
    if (!ok) throw std::invalid_argument(what);
  };
  require(std::isfinite(resolution_m) && resolution_m >= 0.01 && resolution_m <= 10.0,
          "resolution must be in [0.01, 10] m");
  auto prob = [&](double p, const char* name) {
    require(std::isfinite(p) && p > 0.0 && p < 1.0, std::string("sensor_model/") + name + " must be in (0, 1)");
  };
  prob(sensor.hit, "hit");
  prob(sensor.miss, "miss");
  prob(sensor.clamp_min, "min");
  prob(sensor.clamp_max, "max");
  require(sensor.hit > 0.5, "sensor_model/hit must be > 0.5 (a hit must raise occupancy)");
  require(sensor.miss < 0.5, "sensor_model/miss must be < 0.5 (a miss must lower occupancy)");
  require(sensor.clamp_min < 0.5 && sensor.clamp_max > 0.5, "sensor_model/min must be < 0.5 < sensor_model/max");
  require(!std::isnan(max_range_m) && (max_range_m < 0.0 || max_range_m > 0.0), "sensor_model/max_range must be > 0 or < 0 (unlimited)");
  require(std::isfinite(truncation_m) && truncation_m > 0.0, "truncation_m must be > 0");
  require(filter.voxel_leaf_m >= 0.0 && std::isfinite(filter.voxel_leaf_m), "voxel_leaf_m must be >= 0");
  require(filter.min_z_m <= filter.max_z_m, "pointcloud_min_z must be <= pointcloud_max_z");
  require(filter.min_x_m <= filter.max_x_m, "pointcloud_min_x must be <= pointcloud_max_x");
  require(filter.min_y_m <= filter.max_y_m, "pointcloud_min_y must be <= pointcloud_max_y");
  require(threads >= 1 && threads <= 64, "threads must be in [1, 64]");
  require(color_blend >= 0.0 && color_blend <= 1.0, "color_blend must be in [0, 1]");
}

Mapper::Mapper(const MapperConfig& config)
    : config_(config),
      builder_(config.resolution_m),
      layers_(config.resolution_m),
      time_origin_s_(std::numeric_limits<double>::quiet_NaN()) {
  config_.validate();
  map_ = makeVoxelMap(config_.backend, config_.resolution_m, config_.sensor);
  map_->setColorBlend(config_.color_blend);
  if (auto* octree = dynamic_cast<OctreeMap*>(map_.get())) octree->setPrune(config_.prune);
  if (auto* vdb = dynamic_cast<VdbMap*>(map_.get())) vdb->setPrune(config_.prune);
}

float Mapper::relativeTime(double stamp_s) {
  if (std::isnan(time_origin_s_)) time_origin_s_ = std::floor(stamp_s);
  return static_cast<float>(stamp_s - time_origin_s_);
}

InsertStats Mapper::insert(const ColoredPoints& sensor_points, const RigidTransform& map_from_sensor, double stamp_s) {
  FilterStats filter;
  const auto t0 = Clock::now();
  transformAndFilter(sensor_points, map_from_sensor, config_.filter, filtered_, filter);
  voxelGridFilter(filtered_, config_.filter.voxel_leaf_m, filter, config_.filter.voxel_impl);
  return insertFiltered(filtered_, filter, msSince(t0), map_from_sensor.origin(), stamp_s);
}

InsertStats Mapper::insertFiltered(const ColoredPoints& map_points, const FilterStats& filter, double filter_ms,
                                   const Point3& origin, double stamp_s) {
  InsertStats stats;
  stats.filter = filter;
  stats.filter_ms = filter_ms;
  const InsertStats inner = insertMapPoints(map_points, origin, stamp_s);
  stats.points_inserted = inner.points_inserted;
  stats.points_out_of_map = inner.points_out_of_map;
  stats.rays = inner.rays;
  stats.hits = inner.hits;
  stats.misses = inner.misses;
  stats.raycast_ms = inner.raycast_ms;
  stats.update_ms = inner.update_ms;
  stats.layers_ms = inner.layers_ms;
  stats.total_ms = filter_ms + inner.total_ms;
  return stats;
}

InsertStats Mapper::insertMapPoints(const ColoredPoints& map_points, const Point3& origin, double stamp_s) {
  InsertStats stats;
  const auto t0 = Clock::now();
  stats.points_inserted = map_points.size();
  if (map_points.size() == 0) return stats;
  RayOptions ro;
  ro.mode = config_.mode;
  ro.max_range_m = config_.max_range_m;
  ro.truncation_m = config_.truncation_m;
  ro.threads = config_.threads;
  builder_.build(map_points, origin, ro, frame_);
  stats.raycast_ms = msSince(t0);
  stats.points_out_of_map = frame_.points_out_of_map;
  stats.rays = frame_.rays;
  stats.hits = frame_.hits;
  stats.misses = frame_.misses;
  applyFrame(relativeTime(stamp_s), stats);
  stats.total_ms = msSince(t0);
  ++frames_;
  return stats;
}

void Mapper::applyFrame(float time_s, InsertStats& stats) {
  const auto t0 = Clock::now();
  map_->apply(frame_, time_s, transitions_);
  stats.update_ms = msSince(t0);
  const auto t1 = Clock::now();
  layers_.applyFrame(frame_, transitions_, time_s);
  layers_.resolveDirty(*map_);
  stats.layers_ms = msSince(t1);
}

LayersSnapshot Mapper::layers(int factor) const {
  return layers_.snapshot(factor, std::isnan(time_origin_s_) ? 0.0 : time_origin_s_);
}

void Mapper::reset() {
  map_->clear();
  layers_.clear();
  time_origin_s_ = std::numeric_limits<double>::quiet_NaN();
  frames_ = 0;
}

std::size_t Mapper::clearBox(const std::array<double, 3>& min_m, const std::array<double, 3>& max_m) {
  const KeyGrid grid(config_.resolution_m);
  KeyBox box;
  for (int a = 0; a < 3; ++a) {
    const double lo = std::min(min_m[a], max_m[a]);
    const double hi = std::max(min_m[a], max_m[a]);
    // Clamp to the addressable cube, then convert (OctoMap's coordToKey on each corner).
    const double limit = kKeyOffset * config_.resolution_m;
    uint16_t klo = 0;
    uint16_t khi = 0;
    grid.toKey(std::max(lo, -limit), klo);
    grid.toKey(std::min(hi, limit * (1.0 - 1e-12)), khi);
    box.min[a] = klo;
    box.max[a] = khi;
  }
  const std::size_t changed = map_->clearBox(box);
  if (changed > 0) layers_.rebuild(*map_);
  return changed;
}

std::function<void()> Mapper::prepareSave(const std::string& path) const { return map_->prepareSave(path, time_origin_s_); }

void Mapper::save(const std::string& path) const { prepareSave(path)(); }

void Mapper::load(const std::string& path) {
  const double origin = map_->load(path);
  time_origin_s_ = std::isnan(origin) ? 0.0 : origin;
  layers_.rebuild(*map_);
}

std::vector<std::array<int32_t, 3>> Mapper::occupiedCells(double res) const {
  if (!(res > 0.0) || !std::isfinite(res)) throw std::invalid_argument("export resolution must be > 0");
  const double map_res = config_.resolution_m;
  const KeyGrid grid(map_res);
  std::vector<std::array<int32_t, 3>> cells;
  const bool coarser = res >= map_res * (1.0 - 1e-9);
  map_->forEachLeaf(
      [&](const Leaf& leaf) {
        for (unsigned dz = 0; dz < leaf.size; ++dz) {
          for (unsigned dy = 0; dy < leaf.size; ++dy) {
            for (unsigned dx = 0; dx < leaf.size; ++dx) {
              const uint16_t k[3] = {static_cast<uint16_t>(leaf.key[0] + dx), static_cast<uint16_t>(leaf.key[1] + dy),
                                     static_cast<uint16_t>(leaf.key[2] + dz)};
              if (coarser) {
                cells.push_back({static_cast<int32_t>(floorToCell(grid.toCoord(k[0]), res)),
                                 static_cast<int32_t>(floorToCell(grid.toCoord(k[1]), res)),
                                 static_cast<int32_t>(floorToCell(grid.toCoord(k[2]), res))});
                continue;
              }
              // Finer cells: every cell whose centre (j + 0.5) * res lies in [lo, lo + map_res).
              int64_t j0[3];
              int64_t j1[3];
              for (int a = 0; a < 3; ++a) {
                const double lo = grid.lowerFace(k[a]);
                j0[a] = static_cast<int64_t>(std::ceil(lo / res - 0.5));
                j1[a] = static_cast<int64_t>(std::ceil((lo + map_res) / res - 0.5)) - 1;
              }
              for (int64_t z = j0[2]; z <= j1[2]; ++z)
                for (int64_t y = j0[1]; y <= j1[1]; ++y)
                  for (int64_t x = j0[0]; x <= j1[0]; ++x)
                    cells.push_back({static_cast<int32_t>(x), static_cast<int32_t>(y), static_cast<int32_t>(z)});
            }
          }
        }
      },
      true);
  std::sort(cells.begin(), cells.end());
  cells.erase(std::unique(cells.begin(), cells.end()), cells.end());
  return cells;
}

std::size_t Mapper::exportOccupied(const std::string& path, double resolution_m, const std::string& frame_id) const {
  const auto cells = occupiedCells(resolution_m);
  writeNpyInt32x3(path, cells);
  std::ostringstream json;
  json << std::setprecision(17) << "{\n  \"format\": \"occupied voxel cells (i, j, k): cell = [i*res, (i+1)*res) x ...\",\n"
       << "  \"resolution_m\": " << resolution_m << ",\n  \"map_resolution_m\": " << config_.resolution_m
       << ",\n  \"frame_id\": \"" << frame_id << "\",\n  \"backend\": \"" << map_->backendName()
       << "\",\n  \"count\": " << cells.size() << ",\n  \"frames_inserted\": " << frames_ << "\n}\n";
  writeFileAtomically(path + ".json", json.str());
  return cells.size();
}

void writeNpyInt32x3(const std::string& path, const std::vector<std::array<int32_t, 3>>& rows) {
  std::string header = "{'descr': '<i4', 'fortran_order': False, 'shape': (" + std::to_string(rows.size()) + ", 3), }";
  // magic (6) + version (2) + header length (2) + header, padded with spaces to a multiple of 64, ending in \n
  const std::size_t total = 10 + header.size() + 1;
  header.append((64 - total % 64) % 64, ' ');
  header.push_back('\n');
  std::string bytes;
  bytes.reserve(10 + header.size() + rows.size() * 12);
  bytes.append("\x93NUMPY", 6);
  bytes.push_back('\x01');
  bytes.push_back('\x00');
  const auto len = static_cast<uint16_t>(header.size());
  bytes.push_back(static_cast<char>(len & 0xFF));
  bytes.push_back(static_cast<char>(len >> 8));
  bytes += header;
  for (const auto& r : rows) bytes.append(reinterpret_cast<const char*>(r.data()), 12);  // x86-64: little-endian
  writeFileAtomically(path, bytes);
}

}  // namespace uav_mapping
