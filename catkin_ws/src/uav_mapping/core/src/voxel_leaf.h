// Internal to the core (not installed): the voxel grid's leaf arithmetic, shared by the cloud path
// (cloud_filter.cpp) and the fused depth-image path (depth_filter.cpp) so that both find the same leaves and
// give up on the same clouds.
#pragma once

#include <cmath>
#include <cstdint>
#include <limits>

namespace uav_mapping {
namespace voxel_leaf {

/// std::floor for |v| < 2^62 without the libm call (baseline x86-64 has no SSE4.1 round instruction).
inline int64_t floorToInt(float v) {
  const auto i = static_cast<int64_t>(v);  // truncates toward zero
  return i - static_cast<int64_t>(v < static_cast<float>(i));
}

/// One voxel-grid leaf of the cloud path: its points' float sums in the order they were added, and its place in
/// its column's list (the fused path's FusedLeaf sums colours as integers).
struct LeafSum {
  int32_t iz;
  uint32_t next;  // next leaf of the same column, or kNoLeaf
  uint32_t count;
  float sx, sy, sz, sr, sg, sb;
};
constexpr uint32_t kNoLeaf = std::numeric_limits<uint32_t>::max();

/// Widest (x, y) extent in leaf columns that the column map handles (16 MiB of column heads); wider clouds use
/// the sorting variant.
constexpr uint64_t kMaxColumns = 1ULL << 22;

/// PCL indexes voxels with int32 over the cloud's bounding box [lo, hi]: true when that would overflow (the
/// voxel grid then leaves the cloud alone, as PCL does), or when the leaf indices floor(p / leaf) themselves do
/// not fit int32 (points ~5e8 m out at 0.25 m leaves, i.e. a broken transform: their int32 casts are undefined
/// and sent the column map's index far outside it).
inline bool voxelIndexOverflows(const float lo[3], const float hi[3], double leaf_m) {
  const float inv = 1.0f / static_cast<float>(leaf_m);
  constexpr float kInt32Span = 2147483648.0f;  // 2^31
  for (int a = 0; a < 3; ++a) {
    if (!(std::floor(lo[a] * inv) >= -kInt32Span && std::floor(hi[a] * inv) < kInt32Span)) return true;
  }
  double cells = 1.0;
  for (int a = 0; a < 3; ++a) cells *= std::floor((hi[a] - lo[a]) / leaf_m) + 1.0;
  return cells > static_cast<double>(std::numeric_limits<int32_t>::max());
}

}  // namespace voxel_leaf
}  // namespace uav_mapping
