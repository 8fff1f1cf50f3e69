#include <uav_mapping/octree_map.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <iterator>
#include <iomanip>
#include <limits>
#include <cstdlib>
#include <memory>
#include <mutex>
#include <new>
#include <sstream>

namespace uav_mapping {

namespace {

constexpr const char* kOtHeader = "# Octomap OcTree file";
constexpr const char* kBtHeader = "# Octomap OcTree binary file";
constexpr const char* kTrailerTag = "uav_autonomy_voxel_times";
constexpr int kTrailerVersion = 1;

void writeHeader(std::ostream& out, const char* first_line, const std::string& id, std::size_t size, double res) {
  out << first_line << "\n# (feel free to add / change comments, but leave the first line as it is!)\n#\n";
  out << "id " << id << "\n";
  out << "size " << size << "\n";
  out << std::setprecision(17) << "res " << res << "\n";
  out << "data\n";
}

struct Header {
  std::string id;
  std::size_t size = 0;
  double res = 0.0;
};

/// Parses an OctoMap file header (after the first line) up to and including the "data" line.
Header readHeader(std::istream& in, const std::string& path) {
  Header h;
  bool have_res = false;
  bool have_size = false;
  std::string line;
  while (std::getline(in, line)) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.empty() || line[0] == '#') continue;
    std::istringstream ls(line);
    std::string token;
    ls >> token;
    if (token == "data") {
      if (h.id.empty() || !have_res || !have_size) throw MapIoError(path + ": OctoMap header lacks id, size or res");
      return h;
    }
    if (token == "id") {
      ls >> h.id;
    } else if (token == "size") {
      have_size = static_cast<bool>(ls >> h.size);
    } else if (token == "res") {
      have_res = static_cast<bool>(ls >> h.res);
    } else {
      throw MapIoError(path + ": unknown OctoMap header line '" + line + "'");
    }
  }
  throw MapIoError(path + ": OctoMap header ends before its 'data' line");
}

/// Walks serialised tree data without building it, bounded by the buffer and the tree depth, so a truncated
/// or corrupt file is rejected before OctoMap's recursive readers (which do not check for the end of the
/// stream) see it. Returns the number of bytes the tree occupies, or 0 if it is malformed; `nodes` receives
/// the node count. Full (.ot, ColorOcTree) format: per node 4 + 3 bytes of data and a child-mask byte.
std::size_t validateFullData(const std::string& buf, std::size_t& nodes) {
  std::vector<int> depth_stack{0};
  std::size_t pos = 0;
  nodes = 0;
  while (!depth_stack.empty()) {
    const int depth = depth_stack.back();
    depth_stack.pop_back();
    if (pos + 8 > buf.size()) return 0;
    const auto mask = static_cast<uint8_t>(buf[pos + 7]);
    pos += 8;
    ++nodes;
    if (mask != 0 && depth >= kTreeDepth) return 0;
    for (int c = 7; c >= 0; --c) {  // pre-order: child 0 is read first
      if (mask & (1U << c)) depth_stack.push_back(depth + 1);
    }
  }
  return pos;
}

/// Binary (.bt) format: per inner node two bytes holding a 2-bit code per child (1 free leaf, 2 occupied
/// leaf, 3 inner node, 0 none); inner children follow in child order.
std::size_t validateBinaryData(const std::string& buf, std::size_t& nodes) {
  std::vector<int> depth_stack{0};
  std::size_t pos = 0;
  nodes = 1;  // the root
  while (!depth_stack.empty()) {
    const int depth = depth_stack.back();
    depth_stack.pop_back();
    if (pos + 2 > buf.size()) return 0;
    const unsigned bits = static_cast<uint8_t>(buf[pos]) | (static_cast<unsigned>(static_cast<uint8_t>(buf[pos + 1])) << 8);
    pos += 2;
    for (int c = 7; c >= 0; --c) {
      const unsigned code = (bits >> (2 * c)) & 3U;
      if (code == 0) continue;
      ++nodes;
      if (code == 3) {
        if (depth + 1 >= kTreeDepth) return 0;
        depth_stack.push_back(depth + 1);
      }
    }
  }
  return pos;
}

std::string readRest(std::istream& in) {
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

inline Key childKey(const Key& parent, unsigned child, uint16_t half) {
  return Key(static_cast<uint16_t>(parent[0] + ((child & 1) ? half : 0)),
             static_cast<uint16_t>(parent[1] + ((child & 2) ? half : 0)),
             static_cast<uint16_t>(parent[2] + ((child & 4) ? half : 0)));
}

VoxelState stateOf(const UavOcTreeNode& n) {
  VoxelState s;
  s.log_odds = n.getLogOdds();
  s.time_s = n.time();
  s.color_set = n.colorSet();
  const auto c = n.getColor();
  s.r = c.r;
  s.g = c.g;
  s.b = c.b;
  return s;
}

}  // namespace

LogOddsModel::LogOddsModel(const SensorModel& m)
    : hit(octomap::logodds(m.hit)),
      miss(octomap::logodds(m.miss)),
      clamp_min(octomap::logodds(m.clamp_min)),
      clamp_max(octomap::logodds(m.clamp_max)),
      occupied(octomap::logodds(m.occupancy_threshold)) {}

std::string fileExtension(const std::string& path) {
  const auto slash = path.find_last_of('/');
  const auto dot = path.find_last_of('.');
  if (dot == std::string::npos || (slash != std::string::npos && dot < slash)) return "";
  std::string ext = path.substr(dot);
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return std::tolower(c); });
  return ext;
}

void writeFileAtomically(const std::string& path, const std::string& bytes) {
  const std::string tmp = path + ".tmp";
  {
    std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
    if (!out) throw MapIoError(path + ": cannot open for writing: " + std::strerror(errno));
    out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
    out.flush();
    if (!out) {
      std::remove(tmp.c_str());
      throw MapIoError(path + ": write failed");
    }
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) throw MapIoError(path + ": rename failed: " + std::strerror(errno));
}

// ---------------------------------------------------------------------------------------------------------
// Node pool

namespace {

/// Fixed-size slots carved from blocks of 65536, recycled through a free list. Blocks are kept for the
/// process's lifetime (a reset map reuses them). Thread-safe.
template <std::size_t kSize, std::size_t kAlign>
class SlotPool {
 public:
  static SlotPool& instance() {
    static SlotPool* pool = new SlotPool();  // never destroyed: trees may outlive static destruction order
    return *pool;
  }
  void* allocate() {
    std::lock_guard<std::mutex> lock(mutex_);
    if (free_ == nullptr) grow();
    Slot* s = free_;
    free_ = s->next;
    return s;
  }
  void release(void* p) noexcept {
    std::lock_guard<std::mutex> lock(mutex_);
    auto* s = static_cast<Slot*>(p);
    s->next = free_;
    free_ = s;
  }

 private:
  union Slot {
    Slot* next;
    alignas(kAlign) unsigned char bytes[kSize];
  };
  static constexpr std::size_t kSlotsPerBlock = 65536;
  void grow() {
    auto* block = static_cast<Slot*>(std::malloc(sizeof(Slot) * kSlotsPerBlock));
    if (block == nullptr) throw std::bad_alloc();
    for (std::size_t i = 0; i + 1 < kSlotsPerBlock; ++i) block[i].next = &block[i + 1];
    block[kSlotsPerBlock - 1].next = nullptr;
    free_ = block;
  }
  std::mutex mutex_;
  Slot* free_ = nullptr;
};

using NodePool = SlotPool<sizeof(UavOcTreeNode), alignof(UavOcTreeNode)>;
using ChildArrayPool = SlotPool<8 * sizeof(octomap::AbstractOcTreeNode*), alignof(octomap::AbstractOcTreeNode*)>;

}  // namespace

void* UavOcTreeNode::operator new(std::size_t size) {
  if (size != sizeof(UavOcTreeNode)) return ::operator new(size);  // a derived type: not ours to pool
  return NodePool::instance().allocate();
}

void UavOcTreeNode::operator delete(void* p, std::size_t size) noexcept {
  if (p == nullptr) return;
  if (size != sizeof(UavOcTreeNode)) {
    ::operator delete(p);
    return;
  }
  NodePool::instance().release(p);
}

}  // namespace uav_mapping

namespace octomap {

using uav_mapping::ChildArrayPool;
using uav_mapping::UavOcTreeNode;

template <>
void OcTreeBaseImpl<UavOcTreeNode, AbstractOccupancyOcTree>::allocNodeChildren(UavOcTreeNode* node) {
  node->children = static_cast<AbstractOcTreeNode**>(ChildArrayPool::instance().allocate());
  for (unsigned i = 0; i < 8; ++i) node->children[i] = nullptr;
}

template <>
bool OcTreeBaseImpl<UavOcTreeNode, AbstractOccupancyOcTree>::pruneNode(UavOcTreeNode* node) {
  if (!isNodeCollapsible(node)) return false;
  node->copyData(*getNodeChild(node, 0));
  for (unsigned i = 0; i < 8; ++i) deleteNodeChild(node, i);
  ChildArrayPool::instance().release(node->children);
  node->children = nullptr;
  return true;
}

template <>
void OcTreeBaseImpl<UavOcTreeNode, AbstractOccupancyOcTree>::deleteNodeRecurs(UavOcTreeNode* node) {
  if (node->children != nullptr) {
    for (unsigned i = 0; i < 8; ++i) {
      if (node->children[i] != nullptr) deleteNodeRecurs(static_cast<UavOcTreeNode*>(node->children[i]));
    }
    ChildArrayPool::instance().release(node->children);
    node->children = nullptr;
  }
  delete node;
}

}  // namespace octomap

namespace uav_mapping {

// ---------------------------------------------------------------------------------------------------------
// UavOcTree

UavOcTree::UavOcTree(double resolution_m) : octomap::OccupancyOcTreeBase<UavOcTreeNode>(resolution_m) {}

struct UavOcTree::ApplyState {
  const VoxelUpdate* u;
  uint8_t* tr;
  ApplyParams p;
};

void UavOcTree::applySorted(const VoxelUpdate* updates, std::size_t count, const ApplyParams& params,
                            uint8_t* transitions) {
  if (count == 0) return;
  bool created = false;
  if (root == nullptr) {
    root = new UavOcTreeNode();
    ++tree_size;
    created = true;
  }
  ApplyState st{updates, transitions, params};
  applyRecurs(root, created, 0, 0, count, st);
  size_changed = true;
}

void UavOcTree::applyRecurs(UavOcTreeNode* node, bool created, int depth, std::size_t begin, std::size_t end,
                            ApplyState& st) {
  if (depth == kTreeDepth) {  // unique keys: exactly one update reaches a leaf
    const VoxelUpdate& u = st.u[begin];
    const float old = node->getLogOdds();
    uint8_t t = 0;
    if (!created) {
      t |= kWasKnown;
      if (old >= st.p.occupied) t |= kWasOccupied;
    }
    // OctoMap's updateNodeLogOdds: add, then clamp.
    float v = old + (u.hit ? st.p.hit : st.p.miss);
    if (v < st.p.clamp_min)
      v = st.p.clamp_min;
    else if (v > st.p.clamp_max)
      v = st.p.clamp_max;
    node->setLogOdds(v);
    if (st.p.time_s > node->time()) node->setTime(st.p.time_s);  // last observation = latest stamp
    if (u.hit && u.has_color) {
      if (node->colorSet()) {
        const auto c = node->getColor();
        node->setColorRgb(blendChannel(c.r, u.r, st.p.color_weight_q8), blendChannel(c.g, u.g, st.p.color_weight_q8),
                          blendChannel(c.b, u.b, st.p.color_weight_q8));
      } else {
        node->setColorRgb(u.r, u.g, u.b);
      }
    }
    if (v >= st.p.occupied) t |= kIsOccupied;
    st.tr[begin] = t;
    return;
  }
  if (!created && !nodeHasChildren(node)) expandNode(node);  // a pruned node: children inherit its data
  std::size_t i = begin;
  while (i < end) {
    const unsigned c = childIndexAt(st.u[i].morton, depth);
    std::size_t j = i + 1;
    while (j < end && childIndexAt(st.u[j].morton, depth) == c) ++j;
    bool child_created = false;
    UavOcTreeNode* child;
    if (nodeChildExists(node, c)) {
      child = getNodeChild(node, c);
    } else {
      child = createNodeChild(node, c);
      child_created = true;
    }
    applyRecurs(child, child_created, depth + 1, i, j, st);
    i = j;
  }
  updateInner(node);
  if (st.p.prune) pruneNode(node);
}

void UavOcTree::updateInner(UavOcTreeNode* node) {
  float max_lo = -std::numeric_limits<float>::max();
  float max_t = kNoTime;
  unsigned sum[3] = {0, 0, 0};
  unsigned n_color = 0;
  for (unsigned c = 0; c < 8; ++c) {
    if (!nodeChildExists(node, c)) continue;
    const UavOcTreeNode* ch = getNodeChild(node, c);
    max_lo = std::max(max_lo, ch->getLogOdds());
    max_t = std::max(max_t, ch->time());
    if (ch->colorSet()) {
      const auto col = ch->getColor();
      sum[0] += col.r;
      sum[1] += col.g;
      sum[2] += col.b;
      ++n_color;
    }
  }
  node->setLogOdds(max_lo);
  node->setTime(max_t);
  if (n_color > 0) {
    node->setColorRgb(static_cast<uint8_t>(sum[0] / n_color), static_cast<uint8_t>(sum[1] / n_color),
                      static_cast<uint8_t>(sum[2] / n_color));
  } else {
    node->clearColor();
  }
}

void UavOcTree::updateInnerRecurs(UavOcTreeNode* node, int depth) {
  if (!nodeHasChildren(node)) return;
  for (unsigned c = 0; c < 8; ++c) {
    if (nodeChildExists(node, c)) updateInnerRecurs(getNodeChild(node, c), depth + 1);
  }
  updateInner(node);
}

void UavOcTree::updateInnerNodes() {
  if (root != nullptr) updateInnerRecurs(root, 0);
}

std::size_t UavOcTree::setBox(const KeyBox& box, float log_odds, bool prune) {
  if (root == nullptr || box.empty()) return 0;
  return setBoxRecurs(root, 0, Key(0, 0, 0), box, log_odds, prune);
}

std::size_t UavOcTree::setBoxRecurs(UavOcTreeNode* node, int depth, const Key& key, const KeyBox& box, float log_odds,
                                    bool prune) {
  const int size = 1 << (kTreeDepth - depth);
  bool inside = true;
  for (int i = 0; i < 3; ++i) {
    const int lo = key[i];
    const int hi = lo + size - 1;
    if (hi < box.min[i] || lo > box.max[i]) return 0;
    if (lo < box.min[i] || hi > box.max[i]) inside = false;
  }
  if (!nodeHasChildren(node)) {
    if (inside || depth == kTreeDepth) {
      node->setLogOdds(log_odds);
      node->clearColor();
      return static_cast<std::size_t>(size) * size * size;
    }
    expandNode(node);
  }
  std::size_t changed = 0;
  const auto half = static_cast<uint16_t>(size / 2);
  for (unsigned c = 0; c < 8; ++c) {
    if (nodeChildExists(node, c))
      changed += setBoxRecurs(getNodeChild(node, c), depth + 1, childKey(key, c, half), box, log_odds, prune);
  }
  updateInner(node);
  if (prune) pruneNode(node);
  return changed;
}

namespace {
template <class NodePtr, class Tree, class Fn>
void preorder(Tree& tree, NodePtr node, Fn& fn) {
  fn(*node);
  if (!tree.nodeHasChildren(node)) return;
  for (unsigned c = 0; c < 8; ++c) {
    if (tree.nodeChildExists(node, c)) preorder(tree, tree.getNodeChild(node, c), fn);
  }
}
}  // namespace

void UavOcTree::forEachNodePreorder(const std::function<void(const UavOcTreeNode&)>& visit) const {
  if (root != nullptr) preorder(*this, static_cast<const UavOcTreeNode*>(root), visit);
}

void UavOcTree::forEachNodePreorder(const std::function<void(UavOcTreeNode&)>& visit) {
  if (root != nullptr) preorder(*this, root, visit);
}

UavOcTreeNode* UavOcTree::ensureRoot() {
  if (root == nullptr) {
    root = new UavOcTreeNode();
    ++tree_size;
    size_changed = true;
  }
  return root;
}

void UavOcTree::swapTree(UavOcTree& other) {
  swapContent(other);
  size_changed = true;
  other.size_changed = true;
}

// ---------------------------------------------------------------------------------------------------------
// OctreeMap

namespace {
void configureTree(UavOcTree& tree, const SensorModel& m) {
  tree.setProbHit(m.hit);
  tree.setProbMiss(m.miss);
  tree.setClampingThresMin(m.clamp_min);
  tree.setClampingThresMax(m.clamp_max);
  tree.setOccupancyThres(m.occupancy_threshold);
}
}  // namespace

OctreeMap::OctreeMap(double resolution_m, const SensorModel& model) : VoxelMap(resolution_m, model), tree_(resolution_m) {
  configureTree(tree_, model);
}

void OctreeMap::apply(const FrameUpdate& frame, float time_s, std::vector<uint8_t>& transitions) {
  transitions.resize(frame.updates.size());
  UavOcTree::ApplyParams p{logodds_.hit,     logodds_.miss, logodds_.clamp_min, logodds_.clamp_max,
                           logodds_.occupied, time_s,        color_weight_q8_,   prune_};
  tree_.applySorted(frame.updates.data(), frame.updates.size(), p, transitions.data());
}

void OctreeMap::clear() { tree_.clear(); }

std::size_t OctreeMap::clearBox(const KeyBox& box) { return tree_.setBox(box, logodds_.clamp_min, prune_); }

namespace {
void leafRecurs(const UavOcTree& tree, const UavOcTreeNode* node, int depth, const Key& key, float occ,
                bool occupied_only, const LeafVisitor& visit) {
  if (!tree.nodeHasChildren(node)) {
    if (occupied_only && node->getLogOdds() < occ) return;
    Leaf leaf;
    leaf.key = key;
    leaf.size = 1U << (kTreeDepth - depth);
    leaf.state = stateOf(*node);
    visit(leaf);
    return;
  }
  if (occupied_only && node->getLogOdds() < occ) return;  // inner value = max of children
  const auto half = static_cast<uint16_t>(1U << (kTreeDepth - depth - 1));
  for (unsigned c = 0; c < 8; ++c) {
    if (tree.nodeChildExists(node, c))
      leafRecurs(tree, tree.getNodeChild(node, c), depth + 1, childKey(key, c, half), occ, occupied_only, visit);
  }
}
}  // namespace

void OctreeMap::forEachLeaf(const LeafVisitor& visit, bool occupied_only) const {
  const UavOcTreeNode* root = tree_.rootNode();
  if (root != nullptr) leafRecurs(tree_, root, 0, Key(0, 0, 0), logodds_.occupied, occupied_only, visit);
}

bool OctreeMap::query(const Key& key, VoxelState& state) const {
  const UavOcTreeNode* n = tree_.search(key);
  if (n == nullptr) return false;
  state = stateOf(*n);
  return true;
}

int OctreeMap::topOccupiedZ(uint16_t kx, uint16_t ky, int kz_hi, int kz_lo) const {
  for (int kz = std::min(kz_hi, 2 * kKeyOffset - 1); kz >= std::max(kz_lo, 0); --kz) {
    const UavOcTreeNode* n = tree_.search(Key(kx, ky, static_cast<uint16_t>(kz)));
    if (n != nullptr && n->getLogOdds() >= logodds_.occupied) return kz;
  }
  return -1;
}

std::size_t OctreeMap::leafCount() const { return tree_.rootNode() == nullptr ? 0 : tree_.getNumLeafNodes(); }

std::size_t OctreeMap::memoryBytes() const { return tree_.rootNode() == nullptr ? 0 : tree_.memoryUsage(); }

void OctreeMap::writeBinaryData(std::ostream& out) const { tree_.writeBinaryData(out); }

void OctreeMap::writeFullData(std::ostream& out) const { tree_.writeData(out); }

void OctreeMap::writeBtStream(std::ostream& out) const {
  writeHeader(out, kBtHeader, "OcTree", tree_.size(), resolution_m_);
  tree_.writeBinaryData(out);
}

void OctreeMap::writeOtStream(std::ostream& out, double time_origin_s) const {
  writeHeader(out, kOtHeader, "ColorOcTree", tree_.size(), resolution_m_);
  tree_.writeData(out);
  out << "\n" << kTrailerTag << " " << kTrailerVersion << "\n";
  const uint64_t n = tree_.size();
  out.write(reinterpret_cast<const char*>(&time_origin_s), sizeof(time_origin_s));
  out.write(reinterpret_cast<const char*>(&n), sizeof(n));
  tree_.forEachNodePreorder([&out](const UavOcTreeNode& node) {
    const float t = node.time();
    const uint8_t f = node.flags();
    out.write(reinterpret_cast<const char*>(&t), sizeof(t));
    out.write(reinterpret_cast<const char*>(&f), sizeof(f));
  });
}

std::function<void()> OctreeMap::prepareSave(const std::string& path, double time_origin_s) const {
  const std::string ext = fileExtension(path);
  if (ext != ".ot" && ext != ".bt") throw MapIoError(path + ": the octomap backend saves .ot or .bt files");
  auto bytes = std::make_shared<std::string>();
  {
    std::ostringstream out(std::ios::binary);
    if (ext == ".ot")
      writeOtStream(out, time_origin_s);
    else
      writeBtStream(out);
    *bytes = out.str();
  }
  return [path, bytes] { writeFileAtomically(path, *bytes); };
}

double OctreeMap::load(const std::string& path) {
  const std::string ext = fileExtension(path);
  if (ext != ".ot" && ext != ".bt") throw MapIoError(path + ": the octomap backend loads .ot or .bt files");
  std::ifstream in(path, std::ios::binary);
  if (!in) throw MapIoError(path + ": cannot open: " + std::strerror(errno));
  std::string first;
  std::getline(in, first);
  if (!first.empty() && first.back() == '\r') first.pop_back();
  const bool binary = first.rfind(kBtHeader, 0) == 0;
  const bool full = first.rfind(kOtHeader, 0) == 0 && !binary;
  if (!binary && !full) throw MapIoError(path + ": not an OctoMap .bt/.ot file (first line '" + first + "')");
  const Header h = readHeader(in, path);
  if (std::fabs(h.res - resolution_m_) > 1e-9 * resolution_m_) {
    std::ostringstream msg;
    msg << path << ": resolution " << h.res << " m differs from the map's " << resolution_m_ << " m";
    throw MapIoError(msg.str());
  }
  UavOcTree fresh(resolution_m_);
  configureTree(fresh, model_);
  double time_origin = std::numeric_limits<double>::quiet_NaN();
  const std::string data = readRest(in);
  std::size_t nodes = 0;
  if (binary) {
    if (h.id != "OcTree" && h.id != "ColorOcTree") throw MapIoError(path + ": unsupported binary tree id " + h.id);
    const std::size_t used = h.size > 0 ? validateBinaryData(data, nodes) : 0;
    if (h.size > 0 && (used == 0 || nodes != h.size)) throw MapIoError(path + ": truncated or corrupt tree data");
    std::istringstream tree_in(data.substr(0, used));
    if (h.size > 0) fresh.readBinaryData(tree_in);
    fresh.forEachNodePreorder([](UavOcTreeNode& n) {
      n.setTime(kNoTime);
      n.clearColor();
    });
  } else {
    if (h.id != "ColorOcTree") throw MapIoError(path + ": full .ot files must hold a ColorOcTree, not " + h.id);
    const std::size_t used = h.size > 0 ? validateFullData(data, nodes) : 0;
    if (h.size > 0 && (used == 0 || nodes != h.size)) throw MapIoError(path + ": truncated or corrupt tree data");
    std::istringstream tree_in(data.substr(0, used));
    if (h.size > 0) fresh.readData(tree_in);
    fresh.forEachNodePreorder([](UavOcTreeNode& n) {
      const auto c = n.getColor();
      const bool set = !(c.r == 255 && c.g == 255 && c.b == 255);  // ColorOcTree's "no colour" convention
      n.setFlags(set ? UavOcTreeNode::kColorSet : 0);
      n.setTime(kNoTime);
    });
    // Optional trailer with times and flags.
    std::istringstream rest(data.substr(used));
    std::string line;
    while (std::getline(rest, line) && line.empty()) {
    }
    if (rest && line.rfind(kTrailerTag, 0) == 0) {
      int version = 0;
      std::istringstream(line.substr(std::strlen(kTrailerTag))) >> version;
      if (version != kTrailerVersion) throw MapIoError(path + ": unknown time trailer version");
      uint64_t n = 0;
      rest.read(reinterpret_cast<char*>(&time_origin), sizeof(time_origin));
      rest.read(reinterpret_cast<char*>(&n), sizeof(n));
      if (!rest || n != fresh.size()) throw MapIoError(path + ": time trailer does not match the tree");
      bool ok = true;
      fresh.forEachNodePreorder([&rest, &ok](UavOcTreeNode& node) {
        float t;
        uint8_t f;
        rest.read(reinterpret_cast<char*>(&t), sizeof(t));
        rest.read(reinterpret_cast<char*>(&f), sizeof(f));
        if (!rest) {
          ok = false;
          return;
        }
        node.setTime(t);
        node.setFlags(f);
      });
      if (!ok) throw MapIoError(path + ": truncated time trailer");
    }
  }
  tree_.swapTree(fresh);
  return time_origin;
}

// ---------------------------------------------------------------------------------------------------------

namespace {
void setNodeAt(UavOcTree& tree, const Leaf& leaf) {
  int target_depth = kTreeDepth;
  for (unsigned s = leaf.size; s > 1; s >>= 1) --target_depth;
  UavOcTreeNode* node = tree.rootNode();
  for (int depth = 0; depth < target_depth; ++depth) {
    const unsigned c = childIndexAt(mortonOf(leaf.key), depth);
    node = tree.nodeChildExists(node, c) ? tree.getNodeChild(node, c) : tree.createNodeChild(node, c);
  }
  node->setLogOdds(leaf.state.log_odds);
  node->setTime(leaf.state.time_s);
  if (leaf.state.color_set)
    node->setColorRgb(leaf.state.r, leaf.state.g, leaf.state.b);
  else
    node->clearColor();
}
}  // namespace

void copyLeavesToTree(const VoxelMap& map, UavOcTree& tree) {
  tree.clear();
  bool any = false;
  map.forEachLeaf(
      [&](const Leaf& leaf) {
        tree.ensureRoot();
        any = true;
        setNodeAt(tree, leaf);
      },
      false);
  if (any) tree.updateInnerNodes();
}

}  // namespace uav_mapping
