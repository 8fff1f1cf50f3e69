// The only translation unit that includes PCL (its headers are slow to compile).
#include <uav_mapping/cloud_filter.h>

#include "voxel_leaf.h"

#include <pcl/filters/voxel_grid.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>

#include <array>
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

RigidTransform RigidTransform::fromQuaternion(double w, double x, double y, double z, double tx, double ty,
                                              double tz) {
  const double norm = std::sqrt(w * w + x * x + y * y + z * z);
  if (norm > 0.0) {
    w /= norm;
    x /= norm;
    y /= norm;
    z /= norm;
  }
  RigidTransform t;
  t.r[0][0] = 1 - 2 * (y * y + z * z);
  t.r[0][1] = 2 * (x * y - z * w);
  t.r[0][2] = 2 * (x * z + y * w);
  t.r[1][0] = 2 * (x * y + z * w);
  t.r[1][1] = 1 - 2 * (x * x + z * z);
  t.r[1][2] = 2 * (y * z - x * w);
  t.r[2][0] = 2 * (x * z - y * w);
  t.r[2][1] = 2 * (y * z + x * w);
  t.r[2][2] = 1 - 2 * (x * x + y * y);
  t.t[0] = tx;
  t.t[1] = ty;
  t.t[2] = tz;
  return t;
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

using voxel_leaf::floorToInt;
using voxel_leaf::kMaxColumns;
using voxel_leaf::kNoLeaf;
using voxel_leaf::LeafSum;

thread_local std::vector<uint32_t> tl_column_head;  // all kNoLeaf between calls
thread_local std::vector<LeafSum> tl_leaves;
thread_local std::vector<uint32_t> tl_leaf_column;

/// PCL VoxelGrid's arithmetic (leaf = floor(p * (1 / leaf)) in float, float centroid, colour = truncated float
/// mean) without its per-point index vector and comparison sort. Each point finds its leaf through a dense
/// map of the cloud's (x, y) leaf columns to a short list of the column's occupied leaves, and is summed into it
/// at once, in cloud order. A camera's neighbouring pixels fall into the same or recently used leaves, so the
/// sums stay in cache (sorting the points by leaf and then gathering them was the cost). Leaves come out in the
/// order they were first hit (PCL: leaf index order; the map built from them is the same either way).
bool columnVoxelGrid(ColoredPoints& points, double leaf_m, const int32_t min_b[3], const int32_t div_b[3]) {
  const uint64_t columns = static_cast<uint64_t>(div_b[0]) * static_cast<uint64_t>(div_b[1]);
  if (columns > kMaxColumns) return false;
  const float inv = 1.0f / static_cast<float>(leaf_m);
  std::vector<uint32_t>& head = tl_column_head;
  if (head.size() < columns) head.assign(columns, kNoLeaf);
  std::vector<LeafSum>& leaves = tl_leaves;
  std::vector<uint32_t>& leaf_column = tl_leaf_column;
  leaves.clear();
  leaf_column.clear();
  const bool color = points.hasColor();
  const std::size_t n = points.size();
  const uint64_t stride_y = static_cast<uint64_t>(div_b[0]);
  uint64_t last_col = ~0ULL;
  int64_t last_iz = 0;
  uint32_t cur = kNoLeaf;
  for (std::size_t i = 0; i < n; ++i) {
    const Point3& p = points.xyz[i];
    const int64_t ix = floorToInt(p(0) * inv) - min_b[0];
    const int64_t iy = floorToInt(p(1) * inv) - min_b[1];
    const int64_t iz = floorToInt(p(2) * inv) - min_b[2];
    const uint64_t col = static_cast<uint64_t>(ix) + static_cast<uint64_t>(iy) * stride_y;
    if (col != last_col || iz != last_iz) {  // not the previous point's leaf: look it up in its column
      uint32_t e = head[col];
      while (e != kNoLeaf && leaves[e].iz != iz) e = leaves[e].next;
      if (e == kNoLeaf) {
        e = static_cast<uint32_t>(leaves.size());
        leaves.push_back({static_cast<int32_t>(iz), head[col], 0, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f});
        leaf_column.push_back(static_cast<uint32_t>(col));
        head[col] = e;
      }
      cur = e;
      last_col = col;
      last_iz = iz;
    }
    LeafSum& l = leaves[cur];
    l.sx += p(0);
    l.sy += p(1);
    l.sz += p(2);
    if (color) {
      l.sr += static_cast<float>(points.rgb[i][0]);
      l.sg += static_cast<float>(points.rgb[i][1]);
      l.sb += static_cast<float>(points.rgb[i][2]);
    }
    ++l.count;
  }
  for (uint32_t col : leaf_column) head[col] = kNoLeaf;
  ColoredPoints& out = tl_out;
  out.clear();
  out.xyz.resize(leaves.size());
  if (color) out.rgb.resize(leaves.size());
  for (std::size_t j = 0; j < leaves.size(); ++j) {
    const LeafSum& l = leaves[j];
    const auto fc = static_cast<float>(l.count);
    out.xyz[j] = Point3(l.sx / fc, l.sy / fc, l.sz / fc);
    if (color) {
      std::array<uint8_t, 3>& c = out.rgb[j];  // written in place (a temporary array stalled on store forwarding)
      c[0] = static_cast<uint8_t>(l.sr / fc);
      c[1] = static_cast<uint8_t>(l.sg / fc);
      c[2] = static_cast<uint8_t>(l.sb / fc);
    }
  }
  std::swap(points, out);
  return true;
}

/// The same leaves for clouds too wide for the column map (e.g. a distant horizon): runs of consecutive points
/// in one leaf become one item, then a stable radix sort by leaf index and a gather.
void sortingVoxelGrid(ColoredPoints& points, const float inv, const int32_t min_b[3], const int32_t div_b[3]) {
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

void fastVoxelGrid(ColoredPoints& points, double leaf_m, const float lo[3], const float hi[3]) {
  const float inv = 1.0f / static_cast<float>(leaf_m);
  int32_t min_b[3];
  int32_t div_b[3];
  for (int a = 0; a < 3; ++a) {
    min_b[a] = static_cast<int32_t>(std::floor(lo[a] * inv));
    div_b[a] = static_cast<int32_t>(std::floor(hi[a] * inv)) - min_b[a] + 1;
  }
  if (!columnVoxelGrid(points, leaf_m, min_b, div_b)) sortingVoxelGrid(points, inv, min_b, div_b);
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
  if (voxel_leaf::voxelIndexOverflows(lo, hi, leaf_m)) {
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
