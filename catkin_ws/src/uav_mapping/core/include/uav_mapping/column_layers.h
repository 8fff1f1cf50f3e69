// 2D layers over the map's (x, y) columns, maintained incrementally from each frame's voxel transitions.
//
//   elevation   key z of the highest occupied voxel in the column (published as its centre, metres)
//   last seen   latest observation time of any voxel in the column (seconds relative to the time origin)
//   observed    whether any voxel of the column has been observed (hit or crossed by a ray)
//
// The grid grows (in 64-column chunks, amortised doubling) as the map grows. A column whose top voxel turns
// free is marked dirty and re-evaluated from the map after the frame.
#pragma once

#include <uav_mapping/voxel_map.h>

#include <cstdint>
#include <limits>
#include <vector>

namespace uav_mapping {

/// A snapshot in the uav_msgs/GridLayers convention: row 0 is the southern-most row, data row-major.
struct LayersSnapshot {
  double resolution_m = 0.0;
  double origin_x_m = 0.0;
  double origin_y_m = 0.0;
  uint32_t width = 0;   // columns along x
  uint32_t height = 0;  // rows along y
  std::vector<float> elevation_m;  // NaN where no occupied voxel is known
  std::vector<float> last_seen_s;  // absolute seconds; NaN where never observed or time unknown
  std::vector<float> observed;     // 1 or 0
};

class ColumnLayers {
 public:
  static constexpr int32_t kNoTop = std::numeric_limits<int32_t>::min();

  explicit ColumnLayers(double resolution_m) : res_m_(resolution_m) {}

  void clear();
  /// Makes sure columns [kx0, kx1] x [ky0, ky1] are addressable (grows the arrays if needed).
  void reserve(int kx0, int ky0, int kx1, int ky1);
  /// Updates from one applied frame (updates and their TransitionBits from VoxelMap::apply).
  void applyFrame(const FrameUpdate& frame, const std::vector<uint8_t>& transitions, float time_s);
  /// Re-evaluates dirty columns' tops from the map.
  void resolveDirty(const VoxelMap& map);
  /// Rebuilds everything from the map's leaves (after load, clear_bbx or reset).
  void rebuild(const VoxelMap& map);

  /// The observed region, coarsened by `factor` (>= 1) map cells per layer cell: elevation = max, last seen =
  /// max, observed = any. time_origin_s is added to the relative times.
  LayersSnapshot snapshot(int factor, double time_origin_s) const;

  bool empty() const { return obs_box_.empty(); }
  /// Inclusive key box of observed columns (z unused).
  const KeyBox& observedBox() const { return obs_box_; }
  int32_t top(int kx, int ky) const;
  float lastSeen(int kx, int ky) const;
  bool observed(int kx, int ky) const;
  std::size_t memoryBytes() const;

 private:
  std::size_t index(int kx, int ky) const {
    return static_cast<std::size_t>(ky - ky0_) * static_cast<std::size_t>(w_) + static_cast<std::size_t>(kx - kx0_);
  }
  bool inside(int kx, int ky) const { return kx >= kx0_ && ky >= ky0_ && kx < kx0_ + w_ && ky < ky0_ + h_; }
  void observeColumn(int kx, int ky, int kz, bool occupied_now, bool was_top_candidate, float time_s);

  double res_m_;
  int kx0_ = 0;
  int ky0_ = 0;
  int w_ = 0;
  int h_ = 0;
  std::vector<int32_t> top_;
  std::vector<float> last_;
  std::vector<uint8_t> observed_;
  std::vector<uint8_t> dirty_flag_;
  std::vector<std::size_t> dirty_;
  KeyBox obs_box_;
  int min_kz_ = std::numeric_limits<int>::max();  // lowest observed key z (bounds dirty-column searches)
};

}  // namespace uav_mapping
