// The only translation unit that includes PCL (its headers are slow to compile).
#include <uav_mapping/cloud_filter.h>

#include <pcl/filters/voxel_grid.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>

#include <cmath>
#include <cstdint>
#include <limits>

namespace uav_mapping {

void transformAndFilter(const ColoredPoints& sensor_points, const RigidTransform& tf, const FilterOptions& options,
                        ColoredPoints& out, FilterStats& stats) {
  out.clear();
  const std::size_t n = sensor_points.size();
  stats.points_in += n;
  const bool color = sensor_points.hasColor();
  out.xyz.reserve(n);
  if (color) out.rgb.reserve(n);
  const double min_range_sq = options.min_range_m > 0.0 ? options.min_range_m * options.min_range_m : -1.0;
  for (std::size_t i = 0; i < n; ++i) {
    const Point3& p = sensor_points.xyz[i];
    const double x = p(0);
    const double y = p(1);
    const double z = p(2);
    if (!std::isfinite(x) || !std::isfinite(y) || !std::isfinite(z)) {
      ++stats.nonfinite;
      continue;
    }
    if (min_range_sq > 0.0 && x * x + y * y + z * z < min_range_sq) {
      ++stats.too_close;
      continue;
    }
    const double mx = tf.r[0][0] * x + tf.r[0][1] * y + tf.r[0][2] * z + tf.t[0];
    const double my = tf.r[1][0] * x + tf.r[1][1] * y + tf.r[1][2] * z + tf.t[1];
    const double mz = tf.r[2][0] * x + tf.r[2][1] * y + tf.r[2][2] * z + tf.t[2];
    if (mx < options.min_x_m || mx > options.max_x_m || my < options.min_y_m || my > options.max_y_m ||
        mz < options.min_z_m || mz > options.max_z_m) {
      ++stats.outside_box;
      continue;
    }
    out.xyz.emplace_back(static_cast<float>(mx), static_cast<float>(my), static_cast<float>(mz));
    if (color) out.rgb.push_back(sensor_points.rgb[i]);
  }
  stats.points_out = out.size();
}

void voxelGridFilter(ColoredPoints& points, double leaf_m, FilterStats& stats) {
  stats.points_out = points.size();
  if (leaf_m <= 0.0 || points.size() < 2) return;
  // PCL indexes voxels with int32 over the cloud's bounding box; refuse clouds that would overflow it.
  float lo[3] = {std::numeric_limits<float>::max(), std::numeric_limits<float>::max(),
                 std::numeric_limits<float>::max()};
  float hi[3] = {std::numeric_limits<float>::lowest(), std::numeric_limits<float>::lowest(),
                 std::numeric_limits<float>::lowest()};
  for (const Point3& p : points.xyz) {
    for (int a = 0; a < 3; ++a) {
      lo[a] = std::min(lo[a], p(a));
      hi[a] = std::max(hi[a], p(a));
    }
  }
  double cells = 1.0;
  for (int a = 0; a < 3; ++a) cells *= std::floor((hi[a] - lo[a]) / leaf_m) + 1.0;
  if (cells > static_cast<double>(std::numeric_limits<int32_t>::max())) {
    stats.voxel_grid_skipped = true;
    return;
  }
  pcl::PointCloud<pcl::PointXYZRGB>::Ptr in(new pcl::PointCloud<pcl::PointXYZRGB>);
  in->resize(points.size());
  const bool color = points.hasColor();
  for (std::size_t i = 0; i < points.size(); ++i) {
    pcl::PointXYZRGB& q = (*in)[i];
    q.x = points.xyz[i](0);
    q.y = points.xyz[i](1);
    q.z = points.xyz[i](2);
    if (color) {
      q.r = points.rgb[i][0];
      q.g = points.rgb[i][1];
      q.b = points.rgb[i][2];
    } else {
      q.r = q.g = q.b = 0;
    }
    q.a = 255;
  }
  pcl::PointCloud<pcl::PointXYZRGB> filtered;
  pcl::VoxelGrid<pcl::PointXYZRGB> grid;
  const auto leaf = static_cast<float>(leaf_m);
  grid.setLeafSize(leaf, leaf, leaf);
  grid.setDownsampleAllData(true);
  grid.setInputCloud(in);
  grid.filter(filtered);
  points.clear();
  points.xyz.reserve(filtered.size());
  if (color) points.rgb.reserve(filtered.size());
  for (const auto& q : filtered) {
    points.xyz.emplace_back(q.x, q.y, q.z);
    if (color) points.rgb.push_back({q.r, q.g, q.b});
  }
  stats.points_out = points.size();
}

}  // namespace uav_mapping
