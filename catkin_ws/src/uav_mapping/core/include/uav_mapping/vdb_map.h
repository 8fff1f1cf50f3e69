// OpenVDB backend: three sparse grids over the same voxels as the octree (index i = key - 32768).
//
//   log_odds  float grid occupancy log-odds with octomap_server's hit/miss/clamping; its active mask is the
//                        observed mask (a voxel is active once any ray ended in it or crossed it)
//   time_s    float grid last-observed time in seconds relative to the map's time origin
//   color_rgb int32 grid 0x00RRGGBB of occupied voxels, active where a colour has been observed
//
// The trees use 4^3-voxel leaves instead of OpenVDB's default 8^3: a surface at 0.5 m fills an 8^3 leaf only
// about 10 % (a 1 km^2 surface map needed 740 MiB with 8^3 leaves), so smaller leaves waste less. The grid types
// are registered at start-up, so .vdb files load with any OpenVDB that registers the same tree configuration.
// After each frame, every touched leaf whose three grids are constant is replaced by tiles (the VDB counterpart
// of OctoMap's pruning), so large uniform free regions stay cheap.
#pragma once

#include <uav_mapping/voxel_map.h>

#include <openvdb/openvdb.h>

#include <string>
#include <vector>

namespace uav_mapping {

using VdbFloatTree = openvdb::tree::Tree4<float, 4, 3, 2>::Type;
using VdbInt32Tree = openvdb::tree::Tree4<int32_t, 4, 3, 2>::Type;
using VdbFloatGrid = openvdb::Grid<VdbFloatTree>;
using VdbInt32Grid = openvdb::Grid<VdbInt32Tree>;
constexpr int kVdbLeafDim = static_cast<int>(VdbFloatTree::LeafNodeType::DIM);

class VdbMap final : public VoxelMap {
 public:
  VdbMap(double resolution_m, const SensorModel& model);

  std::string backendName() const override { return "openvdb"; }
  std::vector<std::string> fileExtensions() const override { return {".vdb"}; }

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

  void setPrune(bool prune) { prune_ = prune; }
  const VdbFloatGrid& logOddsGrid() const { return *log_odds_; }
  const VdbFloatGrid& timeGrid() const { return *time_; }
  const VdbInt32Grid& colorGrid() const { return *color_; }

 private:
  void makeGrids();
  void pruneLeaves(const std::vector<openvdb::Coord>& leaf_origins);

  VdbFloatGrid::Ptr log_odds_;
  VdbFloatGrid::Ptr time_;
  VdbInt32Grid::Ptr color_;
  bool prune_ = true;
};

}  // namespace uav_mapping
