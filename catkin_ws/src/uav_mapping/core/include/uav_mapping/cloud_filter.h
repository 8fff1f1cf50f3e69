// Pre-insertion filtering: sensor -> map transform, non-finite / range / box filters, voxel grid (PCL's
// VoxelGrid, or the same arithmetic several times faster).
#pragma once

#include <uav_mapping/frame_update.h>

#include <cstddef>
#include <limits>
#include <string>

namespace uav_mapping {

/// x_map = R * x_sensor + t (metres).
struct RigidTransform {
  double r[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  double t[3] = {0, 0, 0};

  Point3 origin() const {
    return Point3(static_cast<float>(t[0]), static_cast<float>(t[1]), static_cast<float>(t[2]));
  }

  /// Rotation of the quaternion (w, x, y, z), normalised first (left as is if zero), then translation t.
  static RigidTransform fromQuaternion(double w, double x, double y, double z, double tx, double ty, double tz);
};

/// Who downsamples: kFast (default) reproduces pcl::VoxelGrid's leaves, centroids and mean colours (float
/// summation order within a leaf aside; leaves in first-hit order instead of PCL's leaf index order, which the
/// map does not depend on) several times faster; kPcl runs pcl::VoxelGrid itself.
enum class VoxelFilterImpl { kFast, kPcl };
std::string toString(VoxelFilterImpl impl);
/// Parses "fast" or "pcl"; throws std::invalid_argument otherwise.
VoxelFilterImpl voxelFilterImplFromString(const std::string& name);

struct FilterOptions {
  double min_range_m = -1.0;  // points closer to the sensor are dropped (< 0: off)
  double min_x_m = -std::numeric_limits<double>::infinity();  // pass-through box in the map frame
  double max_x_m = std::numeric_limits<double>::infinity();
  double min_y_m = -std::numeric_limits<double>::infinity();
  double max_y_m = std::numeric_limits<double>::infinity();
  double min_z_m = -std::numeric_limits<double>::infinity();
  double max_z_m = std::numeric_limits<double>::infinity();
  double voxel_leaf_m = 0.0;  // PCL VoxelGrid leaf size in the map frame (0: off)
  VoxelFilterImpl voxel_impl = VoxelFilterImpl::kFast;
};

struct FilterStats {
  std::size_t points_in = 0;
  std::size_t nonfinite = 0;      // NaN / inf coordinates
  std::size_t too_close = 0;      // closer than min_range_m
  std::size_t outside_box = 0;    // outside the pass-through box
  std::size_t points_out = 0;     // after the voxel grid
  bool voxel_grid_skipped = false;  // extent too large for PCL's int32 voxel indices
};

/// Transforms sensor-frame points to the map frame and applies the non-finite, range and box filters.
void transformAndFilter(const ColoredPoints& sensor_points, const RigidTransform& map_from_sensor,
                        const FilterOptions& options, ColoredPoints& out, FilterStats& stats);

/// PCL VoxelGrid (centroid and mean colour per leaf; kPcl: leaves in PCL's order, kFast: in the order they are
/// first hit), in place. Skipped
/// (stats.voxel_grid_skipped) when the cloud's extent would overflow PCL's voxel index.
void voxelGridFilter(ColoredPoints& points, double leaf_m, FilterStats& stats,
                     VoxelFilterImpl impl = VoxelFilterImpl::kFast);

}  // namespace uav_mapping
