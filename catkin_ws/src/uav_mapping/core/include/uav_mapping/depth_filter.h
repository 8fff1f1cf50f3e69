// The rgbd front end without ROS: a z-depth image (plus optional registered colour image) back-projected
// through a pinhole camera into points, in the sensor's optical frame or straight into the map frame through
// the filters and the voxel grid of cloud_filter.h.
#pragma once

#include <uav_mapping/cloud_filter.h>
#include <uav_mapping/frame_update.h>

#include <cstddef>
#include <cstdint>

namespace uav_mapping {

enum class DepthEncoding {
  kFloat32Metres,     // 32FC1: NaN, inf and <= 0 mean no return
  kUint16Millimetres  // 16UC1: 0 means no return
};

enum class ColorEncoding { kRgb8, kBgr8, kRgba8, kBgra8 };

/// A row-major depth image in someone else's buffer (e.g. a sensor_msgs/Image's data), little-endian.
struct DepthImageView {
  const uint8_t* data = nullptr;
  uint32_t width = 0;
  uint32_t height = 0;
  std::size_t step_bytes = 0;  // bytes from one row to the next (>= width x bytes per pixel)
  DepthEncoding encoding = DepthEncoding::kFloat32Metres;
};

/// A colour image registered to the depth image (same width and height); data == nullptr: no colour.
struct ColorImageView {
  const uint8_t* data = nullptr;
  std::size_t step_bytes = 0;
  ColorEncoding encoding = ColorEncoding::kRgb8;
};

/// Pinhole intrinsics in pixels (the K of sensor_msgs/CameraInfo): pixel (u, v) looks along
/// ((u - cx) / fx, (v - cy) / fy, 1) in the optical frame (x right, y down, z forward).
struct PinholeIntrinsics {
  double fx = 0.0;
  double fy = 0.0;
  double cx = 0.0;
  double cy = 0.0;
};

/// Back-projects every pixel with a finite positive depth into the optical frame, row-major, coloured when
/// `color.data` is set: x = z * x_n[u], y = z * y_n[v] in float with the normalised rays rounded to float once
/// (the sim bridge's cloud packing, uav_common.pointcloud.DepthImagePacker, so both inputs give the same points).
/// Throws std::invalid_argument when the views or intrinsics are unusable (callers validate first and say why).
void depthToOpticalPoints(const DepthImageView& depth, const ColorImageView& color, const PinholeIntrinsics& k,
                          ColoredPoints& out);

/// How filterDepthImage processed a frame (the result is the same either way).
enum class DepthFrontEndPath {
  kOnePass,               // everything, voxel grid included, in one pass (voxel_filter fast, leaf > 0)
  kOnePassThenVoxelGrid,  // one pass to the filtered cloud, then voxelGridFilter on it (leaf 0, or pcl)
  kThreeStages,           // a point lies beyond the pass's leaf window (more than 1024 leaves from the sensor
                          // along x or y: 512 m at 0.5 m): the three stages one after the other
};

/// The whole front end of a depth frame in one pass over the pixels: back-projection, transform into the map
/// frame, the non-finite / range / box filters and the voxel grid, summing each point into its voxel-grid leaf
/// as soon as it is made instead of materialising the optical-frame and map-frame clouds in between.
/// Bit for bit the result of depthToOpticalPoints -> transformAndFilter -> voxelGridFilter with the same
/// options: the same floats in the same order and the same stats (every floating-point operation and each
/// leaf's summation order, which is pixel order, are the same). Stats are added to like transformAndFilter's;
/// stats.points_in counts the pixels with a return (0: nothing to insert). Throws like depthToOpticalPoints.
DepthFrontEndPath filterDepthImage(const DepthImageView& depth, const ColorImageView& color,
                                   const PinholeIntrinsics& k, const RigidTransform& map_from_optical,
                                   const FilterOptions& options, ColoredPoints& out, FilterStats& stats);

}  // namespace uav_mapping
