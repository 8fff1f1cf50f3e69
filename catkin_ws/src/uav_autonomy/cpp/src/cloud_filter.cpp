// The only translation unit that includes PCL (its headers are slow to compile).
#include <uav_mapping/cloud_filter.h>

#include <pcl/filters/voxel_grid.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>

#include <cmath>
#include <cstdint>
#include <limits>
#include <stdexcept>

namespace uav_mapping {

std::string toString(VoxelFilterImpl impl) { return impl == VoxelFilterImpl::kPcl ? "pcl" : "fast"; }

VoxelFilterImpl voxelFilterImplFromString(const std::string& name) {
  if (name == "fast") return VoxelFilterImpl::kFast;
  if (name == "pcl") return VoxelFilterImpl::kPcl;
  throw std::invalid_argument("voxel filter must be 'fast' or 'pcl', got '" + name + "'");
}

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

namespace {

thread_local std::vector<MortonItem> tl_items;
thread_local std::vector<MortonItem> tl_scratch;
thread_local ColoredPoints tl_out;

/// std::floor for |v| < 2^62 without the libm call (baseline x86-64 has no SSE4.1 round instruction).
inline int64_t floorToInt(float v) {
  const auto i = static_cast<int64_t>(v);  // truncates toward zero
  return i - static_cast<int64_t>(v < static_cast<float>(i));
}

/// PCL VoxelGrid's arithmetic (leaf = floor(p * (1 / leaf)) in float, row-major index over the cloud's leaf
/// box, leaves in index order, float centroid, colour = truncated float mean) without its per-point index
/// vector and comparison sort: runs of consecutive points in one leaf (neighbouring pixels) become one item,
/// then a stable radix sort. Points of a leaf are summed in cloud order (PCL's order within a leaf varies).
void fastVoxelGrid(ColoredPoints& points, double leaf_m, const float lo[3], const float hi[3]) {
  const float inv = 1.0f / static_cast<float>(leaf_m);
  int32_t min_b[3];
  int32_t div_b[3];
  for (int a = 0; a < 3; ++a) {
    min_b[a] = static_cast<int32_t>(std::floor(lo[a] * inv));
    div_b[a] = static_cast<int32_t>(std::floor(hi[a] * inv)) - min_b[a] + 1;
  }
  const uint64_t mul_y = static_cast<uint64_t>(div_b[0]);
  const uint64_t mul_z = mul_y * static_cast<uint64_t>(div_b[1]);
  const std::size_t n = points.size();
  std::vector<MortonItem>& items = tl_items;
  items.clear();
  items.reserve(n / 2 + 16);
  for (std::size_t i = 0; i < n; ++i) {
    const Point3& p = points.xyz[i];
    const int64_t ix = floorToInt(p(0) * inv) - min_b[0];
    const int64_t iy = floorToInt(p(1) * inv) - min_b[1];
    const int64_t iz = floorToInt(p(2) * inv) - min_b[2];
    const uint64_t idx = static_cast<uint64_t>(ix) + static_cast<uint64_t>(iy) * mul_y + static_cast<uint64_t>(iz) * mul_z;
    if (!items.empty() && items.back().morton == idx && items.back().index + items.back().count == i) {
      ++items.back().count;
    } else {
      items.push_back({idx, static_cast<uint32_t>(i), 1});
    }
  }
  radixSortByMorton(items, tl_scratch);
  const bool color = points.hasColor();
  ColoredPoints& out = tl_out;
  out.clear();
  out.xyz.reserve(items.size());
  if (color) out.rgb.reserve(items.size());
  for (std::size_t a = 0; a < items.size();) {
    float sx = 0.0f, sy = 0.0f, sz = 0.0f, sr = 0.0f, sg = 0.0f, sb = 0.0f;
    uint32_t count = 0;
    std::size_t b = a;
    for (; b < items.size() && items[b].morton == items[a].morton; ++b) {
      for (uint32_t j = items[b].index; j < items[b].index + items[b].count; ++j) {
        const Point3& p = points.xyz[j];
        sx += p(0);
        sy += p(1);
        sz += p(2);
        if (color) {
          sr += static_cast<float>(points.rgb[j][0]);
          sg += static_cast<float>(points.rgb[j][1]);
          sb += static_cast<float>(points.rgb[j][2]);
        }
      }
      count += items[b].count;
    }
    const auto fc = static_cast<float>(count);
    out.xyz.emplace_back(sx / fc, sy / fc, sz / fc);
    if (color)
      out.rgb.push_back({static_cast<uint8_t>(sr / fc), static_cast<uint8_t>(sg / fc), static_cast<uint8_t>(sb / fc)});
    a = b;
  }
  std::swap(points, out);
}

}  // namespace

void voxelGridFilter(ColoredPoints& points, double leaf_m, FilterStats& stats, VoxelFilterImpl impl) {
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
  if (impl == VoxelFilterImpl::kFast) {
    fastVoxelGrid(points, leaf_m, lo, hi);
    stats.points_out = points.size();
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
