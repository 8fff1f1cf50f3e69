// OpenVDB backend: three sparse grids over the same voxels as the octree (index i = key - 32768).
//
//   log_odds  FloatGrid  occupancy log-odds with octomap_server's hit/miss/clamping; its active mask is the
//                        observed mask (a voxel is active once any ray ended in it or crossed it)
//   time_s    FloatGrid  last-observed time in seconds relative to the map's time origin
//   color_rgb Int32Grid  0x00RRGGBB of occupied voxels, active where a colour has been observed
//
// After each frame, every touched 8^3 leaf whose three grids are constant is replaced by tiles (the VDB
// counterpart of OctoMap's pruning), so large uniform free regions stay cheap.
#pragma once

#include <uav_mapping/voxel_map.h>

#include <openvdb/openvdb.h>

#include <string>
#include <vector>

namespace uav_mapping {

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
  const openvdb::FloatGrid& logOddsGrid() const { return *log_odds_; }
  const openvdb::FloatGrid& timeGrid() const { return *time_; }
  const openvdb::Int32Grid& colorGrid() const { return *color_; }

 private:
  void makeGrids();
  void pruneLeaves(const std::vector<openvdb::Coord>& leaf_origins);

  openvdb::FloatGrid::Ptr log_odds_;
  openvdb::FloatGrid::Ptr time_;
  openvdb::Int32Grid::Ptr color_;
  bool prune_ = true;
};

}  // namespace uav_mapping
