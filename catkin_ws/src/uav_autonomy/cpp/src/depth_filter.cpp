#include <uav_mapping/depth_filter.h>

#include "voxel_leaf.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <new>
#include <stdexcept>
#include <string>
#include <vector>

namespace uav_mapping {

namespace {

uint32_t bytesPerPixel(DepthEncoding e) { return e == DepthEncoding::kFloat32Metres ? 4 : 2; }
uint32_t channelsOf(ColorEncoding e) { return e == ColorEncoding::kRgb8 || e == ColorEncoding::kBgr8 ? 3 : 4; }
bool isBgr(ColorEncoding e) { return e == ColorEncoding::kBgr8 || e == ColorEncoding::kBgra8; }

/// The preconditions every reader of the views relies on (the ROS adapter checks them first, with messages
/// that name the topic and what to publish instead; this is the core's own guard).
void checkViews(const DepthImageView& depth, const ColorImageView& color, const PinholeIntrinsics& k) {
  const uint64_t min_step = static_cast<uint64_t>(depth.width) * bytesPerPixel(depth.encoding);
  if (depth.step_bytes < min_step)
    throw std::invalid_argument("depth image: step " + std::to_string(depth.step_bytes) + " bytes < width " +
                                std::to_string(depth.width) + " x " + std::to_string(bytesPerPixel(depth.encoding)));
  if (depth.data == nullptr && depth.width > 0 && depth.height > 0)
    throw std::invalid_argument("depth image: no data");
  if (color.data != nullptr && color.step_bytes < static_cast<uint64_t>(depth.width) * channelsOf(color.encoding))
    throw std::invalid_argument("color image: step " + std::to_string(color.step_bytes) + " bytes < width " +
                                std::to_string(depth.width) + " x " + std::to_string(channelsOf(color.encoding)));
  if (!(k.fx > 0.0 && k.fy > 0.0 && std::isfinite(k.fx) && std::isfinite(k.fy) && std::isfinite(k.cx) &&
        std::isfinite(k.cy)))
    throw std::invalid_argument("pinhole intrinsics need positive finite fx, fy and finite cx, cy");
}

/// Normalised ray per column and row, rounded to float once (as the bridge's packer does).
void normalisedRays(const DepthImageView& depth, const PinholeIntrinsics& k, std::vector<float>& x_n,
                    std::vector<float>& y_n) {
  x_n.resize(depth.width);
  y_n.resize(depth.height);
  for (uint32_t u = 0; u < depth.width; ++u) x_n[u] = static_cast<float>((static_cast<double>(u) - k.cx) / k.fx);
  for (uint32_t v = 0; v < depth.height; ++v) y_n[v] = static_cast<float>((static_cast<double>(v) - k.cy) / k.fy);
}

/// Depth of pixel u of a row in metres (0 for a 16UC1 no-return; the caller drops !(z > 0) and non-finite z).
template <bool kMetres>
inline float depthAt(const uint8_t* row, uint32_t u) {
  if (kMetres) {
    float z;
    std::memcpy(&z, row + 4 * static_cast<std::size_t>(u), 4);
    return z;
  }
  uint16_t mm;
  std::memcpy(&mm, row + 2 * static_cast<std::size_t>(u), 2);
  return mm == 0 ? 0.0f : static_cast<float>(mm) * 0.001f;
}

}  // namespace

void depthToOpticalPoints(const DepthImageView& depth, const ColorImageView& color, const PinholeIntrinsics& k,
                          ColoredPoints& out) {
  out.clear();
  checkViews(depth, color, k);
  const bool metres = depth.encoding == DepthEncoding::kFloat32Metres;
  const std::size_t channels = channelsOf(color.encoding);
  const bool bgr = isBgr(color.encoding);
  std::vector<float> x_n;
  std::vector<float> y_n;
  normalisedRays(depth, k, x_n, y_n);
  const std::size_t n = static_cast<std::size_t>(depth.width) * depth.height;
  out.xyz.reserve(n);
  if (color.data != nullptr) out.rgb.reserve(n);
  for (uint32_t v = 0; v < depth.height; ++v) {
    const uint8_t* row = depth.data + static_cast<std::size_t>(v) * depth.step_bytes;
    const uint8_t* crow = color.data != nullptr ? color.data + static_cast<std::size_t>(v) * color.step_bytes : nullptr;
    for (uint32_t u = 0; u < depth.width; ++u) {
      const float z = metres ? depthAt<true>(row, u) : depthAt<false>(row, u);
      if (!(z > 0.0f) || !std::isfinite(z)) continue;  // no return (NaN, inf, 0, negative)
      out.xyz.emplace_back(z * x_n[u], z * y_n[v], z);
      if (crow != nullptr) {
        const uint8_t* c = crow + channels * u;
        out.rgb.push_back(bgr ? std::array<uint8_t, 3>{c[2], c[1], c[0]} : std::array<uint8_t, 3>{c[0], c[1], c[2]});
      }
    }
  }
}

namespace {

using voxel_leaf::floorToInt;
using voxel_leaf::LeafSum;

// The fused pass cannot know the filtered cloud's bounding box before it has seen every pixel, and the cloud
// path's column map is indexed relative to that box. So it indexes the (x, y) leaf columns of a fixed window
// centred on the sensor instead (leaf identity is floor(p / leaf) per axis either way; the box only shifts the
// indices). A frame with a point outside the window is handed to the three-stage path, which is what the
// result must equal anyway; at 0.5 m leaves the window reaches 512 m from the sensor each way.
constexpr int64_t kWindowSide = 2048;
// Inside the window the cloud is at most kWindowSide^2 columns wide, so the three-stage path would take the
// column variant of the voxel grid (leaves in first-hit order, as here) and never the sorting one.
static_assert(static_cast<uint64_t>(kWindowSide * kWindowSide) <= voxel_leaf::kMaxColumns,
              "the window must not be wider than the cloud path's column map");
// Leaf indices floor(p / leaf) of at most 2^29 in magnitude keep the three-stage path's int32 leaf arithmetic
// (min_b, div_b) far from overflow; clouds reaching further are left to it.
constexpr float kMaxLeafIndex = 536870912.0f;  // 2^29

/// The window's column heads and the frame's leaves. head[column] is the column's newest leaf + 1 (0: none),
/// LeafSum::next likewise, so that the heads can come from calloc: the OS hands out zero pages lazily and a
/// frame only ever touches (and keeps resident) the window rows its footprint covers.
class LeafWindow {
 public:
  LeafWindow() = default;
  LeafWindow(const LeafWindow&) = delete;
  LeafWindow& operator=(const LeafWindow&) = delete;
  ~LeafWindow() { std::free(head_); }

  uint32_t* heads() {
    if (head_ == nullptr) {
      head_ = static_cast<uint32_t*>(std::calloc(static_cast<std::size_t>(kWindowSide * kWindowSide), sizeof(uint32_t)));
      if (head_ == nullptr) throw std::bad_alloc();
    }
    return head_;
  }
  /// Back to all-empty heads and no leaves (also after an aborted pass).
  void reset() {
    for (uint32_t col : leaf_column) head_[col] = 0;
    leaves.clear();
    leaf_column.clear();
  }

  std::vector<LeafSum> leaves;
  std::vector<uint32_t> leaf_column;  // column of each leaf, to reset the heads

 private:
  uint32_t* head_ = nullptr;
};

thread_local LeafWindow tl_window;
thread_local std::vector<float> tl_x_n;
thread_local std::vector<float> tl_y_n;
thread_local ColoredPoints tl_optical;

/// What one pass over the pixels found besides its output.
struct PassResult {
  FilterStats stats;     // this pass's counts (merged into the caller's only when the pass is used)
  std::size_t kept = 0;  // points through the filters, i.e. the three-stage path's filtered cloud size
  // Bounding box of the kept points, accumulated in pixel order exactly as voxelGridFilter does.
  float lo[3] = {std::numeric_limits<float>::max(), std::numeric_limits<float>::max(),
                 std::numeric_limits<float>::max()};
  float hi[3] = {std::numeric_limits<float>::lowest(), std::numeric_limits<float>::lowest(),
                 std::numeric_limits<float>::lowest()};
  Point3 last;  // the last kept point and colour (the whole cloud when only one is kept)
  std::array<uint8_t, 3> last_rgb{};
};

struct VoxelSetup {
  float inv = 0.0f;            // 1 / leaf in float, as voxelGridFilter computes it
  int64_t col0[2] = {0, 0};    // leaf index of the window's first column along x and y
  LeafWindow* window = nullptr;
};

/// One pass over the pixels: back-projection (depthToOpticalPoints), transform and filters
/// (transformAndFilter), each with its own arithmetic. kVoxel: every kept point is summed into its voxel-grid
/// leaf (columnVoxelGrid's arithmetic) and false is returned as soon as one falls outside the window or
/// kMaxLeafIndex; otherwise the kept points are appended to `out`. kChannels: 0 (no colour), 3 or 4.
template <bool kMetres, int kChannels, bool kVoxel>
bool fusedPass(const DepthImageView& depth, const ColorImageView& color, const float* x_n, const float* y_n,
               const RigidTransform& tf, const FilterOptions& options, const VoxelSetup& vs, ColoredPoints& out,
               PassResult& res) {
  const bool bgr = isBgr(color.encoding);
  const std::size_t ci_r = bgr ? 2 : 0;
  const std::size_t ci_b = bgr ? 0 : 2;
  const double min_range_sq = options.min_range_m > 0.0 ? options.min_range_m * options.min_range_m : -1.0;
  const double r00 = tf.r[0][0], r01 = tf.r[0][1], r02 = tf.r[0][2], t0 = tf.t[0];
  const double r10 = tf.r[1][0], r11 = tf.r[1][1], r12 = tf.r[1][2], t1 = tf.t[1];
  const double r20 = tf.r[2][0], r21 = tf.r[2][1], r22 = tf.r[2][2], t2 = tf.t[2];
  const double min_x = options.min_x_m, max_x = options.max_x_m;
  const double min_y = options.min_y_m, max_y = options.max_y_m;
  const double min_z = options.min_z_m, max_z = options.max_z_m;
  // The voxel pass's leaves (without kVoxel, nothing below touches them).
  LeafWindow& window = kVoxel ? *vs.window : tl_window;
  uint32_t* const head = kVoxel ? window.heads() : nullptr;
  std::vector<LeafSum>& leaves = window.leaves;
  std::vector<uint32_t>& leaf_column = window.leaf_column;
  const float inv = vs.inv;
  // The previous point's leaf: a camera's neighbouring pixels mostly share it, and then need no lookup.
  int64_t last_ix = std::numeric_limits<int64_t>::min();
  int64_t last_iy = 0;
  int64_t last_iz = 0;
  LeafSum* cur = nullptr;
  std::size_t nonfinite = 0, too_close = 0, outside_box = 0, points_in = 0, kept = 0;
  // Kept in locals, not in `res`: stores through it could alias the float leaf sums and pin it to memory.
  float lo0 = res.lo[0], lo1 = res.lo[1], lo2 = res.lo[2];
  float hi0 = res.hi[0], hi1 = res.hi[1], hi2 = res.hi[2];
  float last_x = 0.0f, last_y = 0.0f, last_z = 0.0f;
  std::array<uint8_t, 3> last_rgb{};
  for (uint32_t v = 0; v < depth.height; ++v) {
    const uint8_t* row = depth.data + static_cast<std::size_t>(v) * depth.step_bytes;
    const uint8_t* crow = kChannels != 0 ? color.data + static_cast<std::size_t>(v) * color.step_bytes : nullptr;
    const float yv = y_n[v];
    for (uint32_t u = 0; u < depth.width; ++u) {
      // depthToOpticalPoints
      const float z = depthAt<kMetres>(row, u);
      if (!(z > 0.0f) || !std::isfinite(z)) continue;  // no return (NaN, inf, 0, negative)
      ++points_in;
      const float xs = z * x_n[u];
      const float ys = z * yv;
      // transformAndFilter (in double, from the optical point's floats)
      const double x = xs;
      const double y = ys;
      const double zd = z;
      if (!std::isfinite(x) || !std::isfinite(y) || !std::isfinite(zd)) {  // z * x_n can overflow
        ++nonfinite;
        continue;
      }
      if (min_range_sq > 0.0 && x * x + y * y + zd * zd < min_range_sq) {
        ++too_close;
        continue;
      }
      const double mx = r00 * x + r01 * y + r02 * zd + t0;
      const double my = r10 * x + r11 * y + r12 * zd + t1;
      const double mz = r20 * x + r21 * y + r22 * zd + t2;
      if (mx < min_x || mx > max_x || my < min_y || my > max_y || mz < min_z || mz > max_z) {
        ++outside_box;
        continue;
      }
      const auto px = static_cast<float>(mx);
      const auto py = static_cast<float>(my);
      const auto pz = static_cast<float>(mz);
      std::array<uint8_t, 3> rgb{};
      if (kChannels != 0) {
        const uint8_t* c = crow + static_cast<std::size_t>(kChannels) * u;
        rgb = {c[ci_r], c[1], c[ci_b]};
      }
      ++kept;
      if constexpr (!kVoxel) {
        out.xyz.emplace_back(px, py, pz);
        if (kChannels != 0) out.rgb.push_back(rgb);
      } else {
        // voxelGridFilter: the bounding box, then columnVoxelGrid's leaf sums
        lo0 = std::min(lo0, px);
        hi0 = std::max(hi0, px);
        lo1 = std::min(lo1, py);
        hi1 = std::max(hi1, py);
        lo2 = std::min(lo2, pz);
        hi2 = std::max(hi2, pz);
        const float qx = px * inv;
        const float qy = py * inv;
        const float qz = pz * inv;
        if (!(std::fabs(qx) < kMaxLeafIndex && std::fabs(qy) < kMaxLeafIndex && std::fabs(qz) < kMaxLeafIndex))
          return false;  // also NaN and inf
        const int64_t ix = floorToInt(qx);
        const int64_t iy = floorToInt(qy);
        const int64_t iz = floorToInt(qz);
        if (ix != last_ix || iy != last_iy || iz != last_iz) {
          const auto wx = static_cast<uint64_t>(ix - vs.col0[0]);
          const auto wy = static_cast<uint64_t>(iy - vs.col0[1]);
          if (wx >= static_cast<uint64_t>(kWindowSide) || wy >= static_cast<uint64_t>(kWindowSide)) return false;
          const auto col = static_cast<uint32_t>(wx + wy * static_cast<uint64_t>(kWindowSide));
          uint32_t e = head[col];
          while (e != 0 && leaves[e - 1].iz != iz) e = leaves[e - 1].next;
          if (e == 0) {
            leaves.push_back({static_cast<int32_t>(iz), head[col], 0, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f});
            leaf_column.push_back(col);
            e = static_cast<uint32_t>(leaves.size());
            head[col] = e;
          }
          cur = &leaves[e - 1];
          last_ix = ix;
          last_iy = iy;
          last_iz = iz;
        }
        cur->sx += px;
        cur->sy += py;
        cur->sz += pz;
        if (kChannels != 0) {
          cur->sr += static_cast<float>(rgb[0]);
          cur->sg += static_cast<float>(rgb[1]);
          cur->sb += static_cast<float>(rgb[2]);
        }
        ++cur->count;
        last_x = px;
        last_y = py;
        last_z = pz;
        last_rgb = rgb;
      }
    }
  }
  res.lo[0] = lo0;
  res.lo[1] = lo1;
  res.lo[2] = lo2;
  res.hi[0] = hi0;
  res.hi[1] = hi1;
  res.hi[2] = hi2;
  res.last = Point3(last_x, last_y, last_z);
  res.last_rgb = last_rgb;
  res.stats.points_in += points_in;
  res.stats.nonfinite += nonfinite;
  res.stats.too_close += too_close;
  res.stats.outside_box += outside_box;
  res.kept = kept;
  return true;
}

template <bool kVoxel>
bool dispatchPass(const DepthImageView& depth, const ColorImageView& color, const float* x_n, const float* y_n,
                  const RigidTransform& tf, const FilterOptions& options, const VoxelSetup& vs, ColoredPoints& out,
                  PassResult& res) {
  const int channels = color.data == nullptr ? 0 : static_cast<int>(channelsOf(color.encoding));
  if (depth.encoding == DepthEncoding::kFloat32Metres) {
    if (channels == 0) return fusedPass<true, 0, kVoxel>(depth, color, x_n, y_n, tf, options, vs, out, res);
    if (channels == 3) return fusedPass<true, 3, kVoxel>(depth, color, x_n, y_n, tf, options, vs, out, res);
    return fusedPass<true, 4, kVoxel>(depth, color, x_n, y_n, tf, options, vs, out, res);
  }
  if (channels == 0) return fusedPass<false, 0, kVoxel>(depth, color, x_n, y_n, tf, options, vs, out, res);
  if (channels == 3) return fusedPass<false, 3, kVoxel>(depth, color, x_n, y_n, tf, options, vs, out, res);
  return fusedPass<false, 4, kVoxel>(depth, color, x_n, y_n, tf, options, vs, out, res);
}

void addStats(FilterStats& to, const FilterStats& from) {
  to.points_in += from.points_in;
  to.nonfinite += from.nonfinite;
  to.too_close += from.too_close;
  to.outside_box += from.outside_box;
}

/// Back-projection and filters in one pass into `out`, then voxelGridFilter on it (leaf 0: none; kPcl).
DepthFrontEndPath filterWithoutFusedVoxelGrid(const DepthImageView& depth, const ColorImageView& color,
                                              const float* x_n, const float* y_n, const RigidTransform& tf,
                                              const FilterOptions& options, ColoredPoints& out, FilterStats& stats) {
  out.clear();
  const std::size_t n = static_cast<std::size_t>(depth.width) * depth.height;
  out.xyz.reserve(n);
  if (color.data != nullptr) out.rgb.reserve(n);
  PassResult res;
  dispatchPass<false>(depth, color, x_n, y_n, tf, options, VoxelSetup(), out, res);
  addStats(stats, res.stats);
  stats.points_out = out.size();
  voxelGridFilter(out, options.voxel_leaf_m, stats, options.voxel_impl);
  return DepthFrontEndPath::kOnePassThenVoxelGrid;
}

/// The three stages one after the other: the reference, and what frames the window cannot hold get.
DepthFrontEndPath threeStages(const DepthImageView& depth, const ColorImageView& color, const PinholeIntrinsics& k,
                              const RigidTransform& tf, const FilterOptions& options, ColoredPoints& out,
                              FilterStats& stats) {
  depthToOpticalPoints(depth, color, k, tl_optical);
  transformAndFilter(tl_optical, tf, options, out, stats);
  voxelGridFilter(out, options.voxel_leaf_m, stats, options.voxel_impl);
  return DepthFrontEndPath::kThreeStages;
}

/// Resets the window however the fused pass ends (an exception from a vector included).
struct WindowReset {
  LeafWindow& window;
  ~WindowReset() { window.reset(); }
};

}  // namespace

DepthFrontEndPath filterDepthImage(const DepthImageView& depth, const ColorImageView& color,
                                   const PinholeIntrinsics& k, const RigidTransform& tf, const FilterOptions& options,
                                   ColoredPoints& out, FilterStats& stats) {
  checkViews(depth, color, k);
  normalisedRays(depth, k, tl_x_n, tl_y_n);
  const float* x_n = tl_x_n.data();
  const float* y_n = tl_y_n.data();
  if (!(options.voxel_leaf_m > 0.0) || options.voxel_impl != VoxelFilterImpl::kFast) {
    return filterWithoutFusedVoxelGrid(depth, color, x_n, y_n, tf, options, out, stats);
  }
  VoxelSetup vs;
  vs.inv = 1.0f / static_cast<float>(options.voxel_leaf_m);
  for (int a = 0; a < 2; ++a) {
    const double sensor_col = std::floor(tf.t[a] * static_cast<double>(vs.inv));
    if (!(std::fabs(sensor_col) < static_cast<double>(kMaxLeafIndex))) {
      return threeStages(depth, color, k, tf, options, out, stats);
    }
    vs.col0[a] = static_cast<int64_t>(sensor_col) - kWindowSide / 2;
  }
  vs.window = &tl_window;
  const WindowReset reset{tl_window};
  PassResult res;
  if (!dispatchPass<true>(depth, color, x_n, y_n, tf, options, vs, out, res)) {
    return threeStages(depth, color, k, tf, options, out, stats);
  }
  addStats(stats, res.stats);
  out.clear();
  const bool has_color = color.data != nullptr;
  if (res.kept < 2) {  // voxelGridFilter leaves clouds of fewer than two points alone
    if (res.kept == 1) {
      out.xyz.push_back(res.last);
      if (has_color) out.rgb.push_back(res.last_rgb);
    }
    stats.points_out = out.size();
    return DepthFrontEndPath::kOnePass;
  }
  if (voxel_leaf::voxelIndexOverflows(res.lo, res.hi, options.voxel_leaf_m)) {
    // voxelGridFilter leaves such clouds alone: the filtered points themselves (counted already).
    PassResult again;
    out.xyz.reserve(res.kept);
    if (has_color) out.rgb.reserve(res.kept);
    dispatchPass<false>(depth, color, x_n, y_n, tf, options, VoxelSetup(), out, again);
    stats.points_out = out.size();
    stats.voxel_grid_skipped = true;
    return DepthFrontEndPath::kOnePass;
  }
  // columnVoxelGrid's centroids and truncated mean colours, leaves in first-hit order.
  const std::vector<LeafSum>& leaves = tl_window.leaves;
  out.xyz.resize(leaves.size());
  if (has_color) out.rgb.resize(leaves.size());
  for (std::size_t j = 0; j < leaves.size(); ++j) {
    const LeafSum& l = leaves[j];
    const auto fc = static_cast<float>(l.count);
    out.xyz[j] = Point3(l.sx / fc, l.sy / fc, l.sz / fc);
    if (has_color) {
      std::array<uint8_t, 3>& c = out.rgb[j];
      c[0] = static_cast<uint8_t>(l.sr / fc);
      c[1] = static_cast<uint8_t>(l.sg / fc);
      c[2] = static_cast<uint8_t>(l.sb / fc);
    }
  }
  stats.points_out = out.size();
  return DepthFrontEndPath::kOnePass;
}

}  // namespace uav_mapping
