// OctoMap backend: an OccupancyOcTreeBase whose nodes carry log-odds, colour and last-observed time.
//
// The node extends ColorOcTreeNode by a float time (seconds relative to the map's time origin) and a flag
// byte, and serialises exactly like ColorOcTreeNode (log-odds + r, g, b), so the tree's write() stream and
// octomap_full messages are ColorOcTree data that octovis, octomap_msgs and rviz read. The times and flags
// go to a trailer after the tree data in .ot files, which ColorOcTree readers ignore.
#pragma once

#include <uav_mapping/voxel_map.h>

#include <octomap/ColorOcTree.h>
#include <octomap/OccupancyOcTreeBase.h>

#include <cstddef>
#include <iosfwd>
#include <string>
#include <vector>

namespace uav_mapping {

class UavOcTreeNode : public octomap::ColorOcTreeNode {
 public:
  enum Flags : uint8_t { kColorSet = 1 };

  // OctoMap allocates every node with `new NODE()` and frees it as NODE*; nodes come from a pool of exact-size
  // slots instead of malloc, which saves malloc's per-allocation overhead (24-byte nodes in 32-byte chunks).
  static void* operator new(std::size_t size);
  static void operator delete(void* p, std::size_t size) noexcept;

  UavOcTreeNode() : ColorOcTreeNode() {}
  UavOcTreeNode(const UavOcTreeNode& rhs) = delete;  // OctoMap's deep copy would slice the node type
  UavOcTreeNode& operator=(const UavOcTreeNode&) = delete;

  bool operator==(const UavOcTreeNode& rhs) const {
    return rhs.value == value && rhs.color == color && rhs.time_s_ == time_s_ && rhs.flags_ == flags_;
  }
  void copyData(const UavOcTreeNode& from) {
    ColorOcTreeNode::copyData(from);
    time_s_ = from.time_s_;
    flags_ = from.flags_;
  }

  float time() const { return time_s_; }
  void setTime(float t) { time_s_ = t; }
  bool colorSet() const { return (flags_ & kColorSet) != 0; }
  uint8_t flags() const { return flags_; }
  void setFlags(uint8_t f) { flags_ = f; }
  void setColorRgb(uint8_t r, uint8_t g, uint8_t b) {
    color = Color(r, g, b);
    flags_ |= kColorSet;
  }
  void clearColor() {
    color = Color();
    flags_ &= static_cast<uint8_t>(~kColorSet);
  }

 private:
  uint8_t flags_ = 0;
  float time_s_ = kNoTime;
};

}  // namespace uav_mapping

// The 8-pointer child arrays of inner nodes come from a pool of 64-byte slots as well (malloc would round each
// 64-byte array up to an 80-byte chunk). OctoMap allocates them in allocNodeChildren() and frees them in
// pruneNode() and deleteNodeRecurs(NODE*) only; these three are specialised for our node type.
namespace octomap {
template <>
void OcTreeBaseImpl<uav_mapping::UavOcTreeNode, AbstractOccupancyOcTree>::allocNodeChildren(
    uav_mapping::UavOcTreeNode* node);
template <>
bool OcTreeBaseImpl<uav_mapping::UavOcTreeNode, AbstractOccupancyOcTree>::pruneNode(uav_mapping::UavOcTreeNode* node);
template <>
void OcTreeBaseImpl<uav_mapping::UavOcTreeNode, AbstractOccupancyOcTree>::deleteNodeRecurs(
    uav_mapping::UavOcTreeNode* node);
}  // namespace octomap

namespace uav_mapping {

class UavOcTree : public octomap::OccupancyOcTreeBase<UavOcTreeNode> {
 public:
  explicit UavOcTree(double resolution_m);
  UavOcTree* create() const override { return new UavOcTree(resolution); }
  /// The serialised node format is ColorOcTree's, so that is the type id standard readers must use.
  std::string getTreeType() const override { return "ColorOcTree"; }

  struct ApplyParams {
    float hit, miss, clamp_min, clamp_max, occupied;
    float time_s;
    unsigned color_weight_q8;
    bool prune;
  };
  /// Applies Morton-sorted unique updates with one shared descent (lazy inner updates on the way back up,
  /// pruning of collapsible nodes); per-update TransitionBits go to `transitions`.
  void applySorted(const VoxelUpdate* updates, std::size_t count, const ApplyParams& params, uint8_t* transitions);

  /// Sets known voxels inside the key box to `log_odds` (free), expanding pruned nodes that straddle it.
  std::size_t setBox(const KeyBox& box, float log_odds, bool prune);

  /// Pre-order node visit (same order as write()): visit(node).
  void forEachNodePreorder(const std::function<void(const UavOcTreeNode&)>& visit) const;
  void forEachNodePreorder(const std::function<void(UavOcTreeNode&)>& visit);

  /// Recomputes inner nodes (max log-odds, max time, mean colour) of the whole tree.
  void updateInnerNodes();

  /// Exchanges the whole content (nodes and size) with another tree of the same resolution.
  void swapTree(UavOcTree& other);
  /// The root node, created if the tree is empty.
  UavOcTreeNode* ensureRoot();

  UavOcTreeNode* rootNode() { return root; }
  const UavOcTreeNode* rootNode() const { return root; }

 private:
  struct ApplyState;
  void applyRecurs(UavOcTreeNode* node, bool created, int depth, std::size_t begin, std::size_t end, ApplyState& st);
  void updateInner(UavOcTreeNode* node);
  std::size_t setBoxRecurs(UavOcTreeNode* node, int depth, const Key& node_key, const KeyBox& box, float log_odds,
                           bool prune);
  void updateInnerRecurs(UavOcTreeNode* node, int depth);
};

class OctreeMap final : public VoxelMap {
 public:
  OctreeMap(double resolution_m, const SensorModel& model);

  std::string backendName() const override { return "octomap"; }
  std::vector<std::string> fileExtensions() const override { return {".ot", ".bt"}; }

  void apply(const FrameUpdate& frame, float time_s, std::vector<uint8_t>& transitions) override;
  void clear() override;
  std::size_t clearBox(const KeyBox& box) override;
  void forEachLeaf(const LeafVisitor& visit, bool occupied_only) const override;
  bool query(const Key& key, VoxelState& state) const override;
  int topOccupiedZ(uint16_t kx, uint16_t ky, int kz_hi, int kz_lo) const override;
  std::size_t leafCount() const override;
  std::size_t memoryBytes() const override;
  std::function<void()> prepareSave(const std::string& path, double time_origin_s) const override;
  double load(const std::string& path) override;

  /// Serialisations used by octomap_msgs/Octomap and by save(): OcTree binary data (id "OcTree") and
  /// ColorOcTree full data (id "ColorOcTree"), without file headers.
  void writeBinaryData(std::ostream& out) const;
  void writeFullData(std::ostream& out) const;
  /// Whole .bt / .ot file streams (header + data; the .ot adds the time trailer).
  void writeBtStream(std::ostream& out) const;
  void writeOtStream(std::ostream& out, double time_origin_s) const;

  void setPrune(bool prune) { prune_ = prune; }
  const UavOcTree& tree() const { return tree_; }
  UavOcTree& tree() { return tree_; }

 private:
  UavOcTree tree_;
  bool prune_ = true;
};

/// Fills a (fresh) tree from any map's leaves: used to publish octomap messages from the OpenVDB backend.
void copyLeavesToTree(const VoxelMap& map, UavOcTree& tree);

}  // namespace uav_mapping
