// A deterministic synthetic world and a CPU depth camera, for the core tests and the benchmark while no
// rendered frames are given: rolling terrain, box buildings and trees rasterised into a height/colour map,
// and a pinhole camera (optical frame: z forward, x right, y down) ray-marched against it.
#pragma once

#include <uav_mapping/cloud_filter.h>
#include <uav_mapping/depth_filter.h>
#include <uav_mapping/frame_update.h>

#include <cstdint>
#include <vector>

namespace uav_mapping {
namespace synthetic {

struct WorldOptions {
  double half_size_m = 300.0;  // world covers [-half, half]^2
  double raster_m = 0.25;      // height/colour raster cell
  uint32_t seed = 7;
  double building_density = 1.0;  // buildings per 10,000 m^2
  double tree_density = 6.0;      // trees per 10,000 m^2
};

class World {
 public:
  explicit World(const WorldOptions& options);
  /// Surface height (metres, terrain + objects) and colour at (x, y); outside the world: terrain only.
  float height(double x, double y) const;
  void color(double x, double y, uint8_t rgb[3]) const;
  /// Smooth terrain alone (no objects), defined everywhere.
  static double terrain(double x, double y);
  double halfSize() const { return opt_.half_size_m; }

 private:
  std::size_t cell(double x, double y, bool& inside) const;
  WorldOptions opt_;
  int n_ = 0;
  std::vector<float> height_;
  std::vector<uint8_t> rgb_;
};

struct Camera {
  int width = 640;
  int height = 480;
  double hfov_deg = 90.0;
  double max_range_m = 300.0;  // rays without a surface closer than this return no point
};

/// A nadir-looking camera pose: optical z down, x east, y south, at (x, y) and `agl_m` above the surface.
RigidTransform nadirPose(const World& world, double x, double y, double agl_m);

/// A camera looking `tilt_deg` away from nadir towards +y (north): optical x east, at (x, y) `agl_m` above the
/// surface. 0 is nadirPose's orientation; 60 sees the terrain up to the camera's range ahead.
RigidTransform tiltedPose(const World& world, double x, double y, double agl_m, double tilt_deg);

/// One frame as an rgbd camera driver publishes it: a z-depth image (32FC1 metres, NaN = no return, row-major),
/// the registered rgb8 image and the intrinsics (pixel centres at integer (u, v), cx = (width - 1) / 2).
struct DepthFrame {
  uint32_t width = 0;
  uint32_t height = 0;
  std::vector<float> depth_m;
  std::vector<uint8_t> rgb;
  PinholeIntrinsics k;

  DepthImageView depthView() const {
    return DepthImageView{reinterpret_cast<const uint8_t*>(depth_m.data()), width, height, 4 * std::size_t{width},
                          DepthEncoding::kFloat32Metres};
  }
  ColorImageView colorView() const { return ColorImageView{rgb.data(), 3 * std::size_t{width}, ColorEncoding::kRgb8}; }
};

/// Renders one depth + colour frame by ray marching the height field.
DepthFrame renderDepth(const World& world, const Camera& camera, const RigidTransform& map_from_optical, int threads);

/// Renders one frame: points in the optical frame (finite only, like the sim bridge's clouds) with colours.
ColoredPoints render(const World& world, const Camera& camera, const RigidTransform& map_from_optical, int threads);

/// Transforms optical-frame points to the map frame.
ColoredPoints toMap(const ColoredPoints& optical, const RigidTransform& map_from_optical);

}  // namespace synthetic
}  // namespace uav_mapping
