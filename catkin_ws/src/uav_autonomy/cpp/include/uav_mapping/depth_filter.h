// The rgbd front end without ROS: a z-depth image (plus optional registered colour image) back-projected
// through a pinhole camera into points in the sensor's optical frame.
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

}  // namespace uav_mapping
