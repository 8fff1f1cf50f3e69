#include <uav_mapping/depth_filter.h>

#include "voxel_leaf.h"

#if defined(__SSE2__)
#include <emmintrin.h>  // SSE2, part of baseline x86-64; other CPUs take the scalar loop (same results)
#endif

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
// Leaf indices floor(p / leaf) of at most 2^29 in magnitude fit the pass's int32 leaf arithmetic and keep the
// three-stage path's (min_b, div_b) far from overflow; clouds reaching further are left to it.
constexpr float kMaxLeafIndex = 536870912.0f;  // 2^29

/// A voxel-grid leaf of the fused pass: columnVoxelGrid's float coordinate sums, in pixel order, and integer
/// colour sums. Colour sums of uint8 values are whole numbers, which float adds exactly while they stay below
/// 2^24: then they equal columnVoxelGrid's float sums (checked at the end; larger ones take the three stages).
struct FusedLeaf {
  int32_t iz;
  uint32_t next;  // the column's next leaf + 1 (0: none)
  uint32_t count;
  float sx, sy, sz;
  uint32_t sr, sg, sb;
};
constexpr uint32_t kExactColorSum = 1U << 24;

/// The window's column heads and the frame's leaves. head[column] is the column's newest leaf + 1 (0: none),
/// so that the heads can come from calloc: the OS hands out zero pages lazily and a frame only ever touches
/// (and keeps resident) the window rows its footprint covers.
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

  std::vector<FusedLeaf> leaves;
  std::vector<uint32_t> leaf_column;  // column of each leaf, to reset the heads

 private:
  uint32_t* head_ = nullptr;
};

// What the first phase of a row says about each pixel (flags), as bits.
constexpr uint32_t kReturn = 1;      // finite positive depth: a point of depthToOpticalPoints
constexpr uint32_t kFinite = 2;      // x, y finite (z * x_n can overflow)
constexpr uint32_t kFar = 4;         // not closer than min_range
constexpr uint32_t kInBox = 8;       // inside the pass-through box
constexpr uint32_t kIndexable = 16;  // leaf indices within kMaxLeafIndex
constexpr uint32_t kKept = kReturn | kFinite | kFar | kInBox;

/// One image row after the first phase: per pixel the map-frame point, its voxel-grid leaf and its flags.
struct RowBuffer {
  std::vector<float> px, py, pz;
  std::vector<int32_t> ix, iy, iz;
  std::vector<uint32_t> flags;
  void resize(std::size_t n) {
    for (auto* v : {&px, &py, &pz}) v->resize(n);
    for (auto* v : {&ix, &iy, &iz}) v->resize(n);
    flags.resize(n);
  }
};

thread_local LeafWindow tl_window;
thread_local RowBuffer tl_row;
thread_local std::vector<float> tl_x_n;
thread_local std::vector<float> tl_y_n;
thread_local ColoredPoints tl_optical;

/// The transform and filters, as the first phase uses them.
struct PassSetup {
  double r[3][3];
  double t[3];
  double box_lo[3], box_hi[3];
  double min_range_sq;  // <= 0: off
  float inv;            // 1 / leaf in float, as voxelGridFilter computes it (0 without a voxel grid)

  PassSetup(const RigidTransform& tf, const FilterOptions& o, float inv_leaf)
      : box_lo{o.min_x_m, o.min_y_m, o.min_z_m},
        box_hi{o.max_x_m, o.max_y_m, o.max_z_m},
        min_range_sq(o.min_range_m > 0.0 ? o.min_range_m * o.min_range_m : -1.0),
        inv(inv_leaf) {
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 3; ++j) r[i][j] = tf.r[i][j];
      t[i] = tf.t[i];
    }
  }
};

/// Running bounding box of the kept points (voxelGridFilter's lo / hi; it only decides whether PCL's index
/// overflows, which the order of the min / max operations cannot change).
struct Bounds {
  float lo[3] = {std::numeric_limits<float>::max(), std::numeric_limits<float>::max(),
                 std::numeric_limits<float>::max()};
  float hi[3] = {std::numeric_limits<float>::lowest(), std::numeric_limits<float>::lowest(),
                 std::numeric_limits<float>::lowest()};
};

/// First phase, one pixel, scalar (the row tails): depthToOpticalPoints' and transformAndFilter's arithmetic
/// verbatim, then the leaf index floor(p * inv).
template <bool kMetres>
inline void pixelScalar(const uint8_t* row, uint32_t u, float xn, float yv, const PassSetup& c, RowBuffer& b,
                        Bounds& bounds) {
  uint32_t f = 0;
  const float z = depthAt<kMetres>(row, u);
  if (z > 0.0f && std::isfinite(z)) f |= kReturn;
  const float xs = z * xn;
  const float ys = z * yv;
  const double x = xs;
  const double y = ys;
  const double zd = z;
  if (std::isfinite(x) && std::isfinite(y)) f |= kFinite;
  if (!(c.min_range_sq > 0.0 && x * x + y * y + zd * zd < c.min_range_sq)) f |= kFar;
  const double mx = c.r[0][0] * x + c.r[0][1] * y + c.r[0][2] * zd + c.t[0];
  const double my = c.r[1][0] * x + c.r[1][1] * y + c.r[1][2] * zd + c.t[1];
  const double mz = c.r[2][0] * x + c.r[2][1] * y + c.r[2][2] * zd + c.t[2];
  if (!(mx < c.box_lo[0] || mx > c.box_hi[0] || my < c.box_lo[1] || my > c.box_hi[1] || mz < c.box_lo[2] ||
        mz > c.box_hi[2]))
    f |= kInBox;
  const float p[3] = {static_cast<float>(mx), static_cast<float>(my), static_cast<float>(mz)};
  const float q[3] = {p[0] * c.inv, p[1] * c.inv, p[2] * c.inv};
  int32_t idx[3] = {0, 0, 0};
  if (std::fabs(q[0]) < kMaxLeafIndex && std::fabs(q[1]) < kMaxLeafIndex && std::fabs(q[2]) < kMaxLeafIndex) {
    f |= kIndexable;
    for (int a = 0; a < 3; ++a) idx[a] = static_cast<int32_t>(floorToInt(q[a]));
  }
  b.px[u] = p[0];
  b.py[u] = p[1];
  b.pz[u] = p[2];
  b.ix[u] = idx[0];
  b.iy[u] = idx[1];
  b.iz[u] = idx[2];
  b.flags[u] = f;
  if ((f & kKept) == kKept) {
    for (int a = 0; a < 3; ++a) {
      bounds.lo[a] = std::min(bounds.lo[a], p[a]);
      bounds.hi[a] = std::max(bounds.hi[a], p[a]);
    }
  }
}

#if defined(__SSE2__)
/// 4 lanes of 32-bit masks from two 2-lane 64-bit masks.
inline __m128 narrowMask(__m128d lo, __m128d hi) {
  return _mm_shuffle_ps(_mm_castpd_ps(lo), _mm_castpd_ps(hi), _MM_SHUFFLE(2, 0, 2, 0));
}

/// First phase of a row: every pixel's point, leaf and flags, four pixels at a time in SSE2 (baseline x86-64).
/// Packed SSE2 operations round exactly like the scalar ones and nothing here is contracted into an FMA
/// (-ffp-contract=off), so each lane computes pixelScalar's values bit for bit: the same products and sums in
/// the same order (mx = ((r00 x + r01 y) + r02 z) + t0), the same conversions, NaN-safe comparisons that
/// filter exactly as the scalar conditions do. The lanes of pixels without a return compute garbage that the
/// flags discard.
template <bool kMetres>
void rowFirstPhase(const uint8_t* row, uint32_t width, const float* x_n, float yv, const PassSetup& c,
                   RowBuffer& b, Bounds& bounds) {
  const __m128 zero = _mm_setzero_ps();
  const __m128 flt_max = _mm_set1_ps(std::numeric_limits<float>::max());
  const __m128 abs_mask = _mm_castsi128_ps(_mm_set1_epi32(0x7fffffff));
  const __m128 max_index = _mm_set1_ps(kMaxLeafIndex);
  const __m128 inv = _mm_set1_ps(c.inv);
  const __m128 yv4 = _mm_set1_ps(yv);
  const __m128d min_range_sq = _mm_set1_pd(c.min_range_sq);
  const bool min_range = c.min_range_sq > 0.0;
  __m128d r[3][3], t[3], box_lo[3], box_hi[3];
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) r[i][j] = _mm_set1_pd(c.r[i][j]);
    t[i] = _mm_set1_pd(c.t[i]);
    box_lo[i] = _mm_set1_pd(c.box_lo[i]);
    box_hi[i] = _mm_set1_pd(c.box_hi[i]);
  }
  const __m128i bit_return = _mm_set1_epi32(kReturn);
  const __m128i bit_finite = _mm_set1_epi32(kFinite);
  const __m128i bit_far = _mm_set1_epi32(kFar);
  const __m128i bit_in_box = _mm_set1_epi32(kInBox);
  const __m128i bit_indexable = _mm_set1_epi32(kIndexable);
  __m128 lo[3], hi[3];
  for (int a = 0; a < 3; ++a) {
    lo[a] = _mm_set1_ps(std::numeric_limits<float>::max());
    hi[a] = _mm_set1_ps(std::numeric_limits<float>::lowest());
  }
  uint32_t u = 0;
  for (; u + 4 <= width; u += 4) {
    __m128 z;
    if (kMetres) {
      z = _mm_loadu_ps(reinterpret_cast<const float*>(row + 4 * static_cast<std::size_t>(u)));
    } else {  // float(mm) * 0.001f, which is 0 for mm == 0 as depthAt's special case
      const __m128i mm = _mm_loadl_epi64(reinterpret_cast<const __m128i*>(row + 2 * static_cast<std::size_t>(u)));
      z = _mm_mul_ps(_mm_cvtepi32_ps(_mm_unpacklo_epi16(mm, _mm_setzero_si128())), _mm_set1_ps(0.001f));
    }
    const __m128 has_return = _mm_and_ps(_mm_cmpgt_ps(z, zero), _mm_cmple_ps(z, flt_max));  // NaN: false
    const __m128 xs = _mm_mul_ps(z, _mm_loadu_ps(x_n + u));
    const __m128 ys = _mm_mul_ps(z, yv4);
    const __m128 finite = _mm_and_ps(_mm_cmple_ps(_mm_and_ps(xs, abs_mask), flt_max),
                                     _mm_cmple_ps(_mm_and_ps(ys, abs_mask), flt_max));
    __m128d far[2], in_box[2], m[3][2];
    for (int h = 0; h < 2; ++h) {
      const __m128d x = _mm_cvtps_pd(h == 0 ? xs : _mm_movehl_ps(xs, xs));
      const __m128d y = _mm_cvtps_pd(h == 0 ? ys : _mm_movehl_ps(ys, ys));
      const __m128d zd = _mm_cvtps_pd(h == 0 ? z : _mm_movehl_ps(z, z));
      if (min_range) {
        const __m128d r2 = _mm_add_pd(_mm_add_pd(_mm_mul_pd(x, x), _mm_mul_pd(y, y)), _mm_mul_pd(zd, zd));
        far[h] = _mm_cmpnlt_pd(r2, min_range_sq);
      } else {
        far[h] = _mm_castsi128_pd(_mm_set1_epi32(-1));
      }
      __m128d inside = _mm_castsi128_pd(_mm_set1_epi32(-1));
      for (int i = 0; i < 3; ++i) {
        m[i][h] = _mm_add_pd(
            _mm_add_pd(_mm_add_pd(_mm_mul_pd(r[i][0], x), _mm_mul_pd(r[i][1], y)), _mm_mul_pd(r[i][2], zd)), t[i]);
        // !(m < lo) && !(m > hi): true for NaN, as the scalar `m < lo || m > hi` is false for it
        inside = _mm_and_pd(inside, _mm_and_pd(_mm_cmpnlt_pd(m[i][h], box_lo[i]), _mm_cmpngt_pd(m[i][h], box_hi[i])));
      }
      in_box[h] = inside;
    }
    __m128 p[3];
    __m128 indexable = _mm_castsi128_ps(_mm_set1_epi32(-1));
    __m128i idx[3];
    for (int i = 0; i < 3; ++i) {
      p[i] = _mm_movelh_ps(_mm_cvtpd_ps(m[i][0]), _mm_cvtpd_ps(m[i][1]));
      const __m128 q = _mm_mul_ps(p[i], inv);
      indexable = _mm_and_ps(indexable, _mm_cmplt_ps(_mm_and_ps(q, abs_mask), max_index));  // NaN: false
      // floorToInt: truncate, then one less where that rounded up (the mask is -1 there)
      const __m128i trunc = _mm_cvttps_epi32(q);
      idx[i] = _mm_add_epi32(trunc, _mm_castps_si128(_mm_cmplt_ps(q, _mm_cvtepi32_ps(trunc))));
    }
    const __m128 far4 = narrowMask(far[0], far[1]);
    const __m128 in_box4 = narrowMask(in_box[0], in_box[1]);
    __m128i flags = _mm_and_si128(_mm_castps_si128(has_return), bit_return);
    flags = _mm_or_si128(flags, _mm_and_si128(_mm_castps_si128(finite), bit_finite));
    flags = _mm_or_si128(flags, _mm_and_si128(_mm_castps_si128(far4), bit_far));
    flags = _mm_or_si128(flags, _mm_and_si128(_mm_castps_si128(in_box4), bit_in_box));
    flags = _mm_or_si128(flags, _mm_and_si128(_mm_castps_si128(indexable), bit_indexable));
    _mm_storeu_ps(b.px.data() + u, p[0]);
    _mm_storeu_ps(b.py.data() + u, p[1]);
    _mm_storeu_ps(b.pz.data() + u, p[2]);
    _mm_storeu_si128(reinterpret_cast<__m128i*>(b.ix.data() + u), idx[0]);
    _mm_storeu_si128(reinterpret_cast<__m128i*>(b.iy.data() + u), idx[1]);
    _mm_storeu_si128(reinterpret_cast<__m128i*>(b.iz.data() + u), idx[2]);
    _mm_storeu_si128(reinterpret_cast<__m128i*>(b.flags.data() + u), flags);
    const __m128 kept = _mm_and_ps(_mm_and_ps(has_return, finite), _mm_and_ps(far4, in_box4));
    for (int i = 0; i < 3; ++i) {
      lo[i] = _mm_min_ps(_mm_or_ps(_mm_and_ps(kept, p[i]), _mm_andnot_ps(kept, lo[i])), lo[i]);
      hi[i] = _mm_max_ps(_mm_or_ps(_mm_and_ps(kept, p[i]), _mm_andnot_ps(kept, hi[i])), hi[i]);
    }
  }
  for (int i = 0; i < 3; ++i) {
    float l[4], h[4];
    _mm_storeu_ps(l, lo[i]);
    _mm_storeu_ps(h, hi[i]);
    for (int k = 0; k < 4; ++k) {
      bounds.lo[i] = std::min(bounds.lo[i], l[k]);
      bounds.hi[i] = std::max(bounds.hi[i], h[k]);
    }
  }
  for (; u < width; ++u) pixelScalar<kMetres>(row, u, x_n[u], yv, c, b, bounds);
}
#else
/// First phase of a row without SSE2: pixelScalar for every pixel (the SSE2 lanes compute exactly its values).
template <bool kMetres>
void rowFirstPhase(const uint8_t* row, uint32_t width, const float* x_n, float yv, const PassSetup& c,
                   RowBuffer& b, Bounds& bounds) {
  for (uint32_t u = 0; u < width; ++u) pixelScalar<kMetres>(row, u, x_n[u], yv, c, b, bounds);
}
#endif

/// What one pass over the pixels found besides its output.
struct PassResult {
  FilterStats stats;     // this pass's counts (merged into the caller's only when the pass is used)
  std::size_t kept = 0;  // points through the filters, i.e. the three-stage path's filtered cloud size
  Bounds bounds;         // of the kept points
  Point3 first;          // the first kept point and colour (the whole cloud when only one is kept)
  std::array<uint8_t, 3> first_rgb{};
  bool color_sums_exact = true;  // every leaf's integer colour sums below kExactColorSum
};

struct VoxelSetup {
  float inv = 0.0f;          // 1 / leaf in float, as voxelGridFilter computes it
  int64_t col0[2] = {0, 0};  // leaf index of the window's first column along x and y
  LeafWindow* window = nullptr;
};

/// One pass over the pixels, row by row: the first phase (rowFirstPhase), then, in pixel order, the filter
/// counts and either (kVoxel) columnVoxelGrid's leaf sums of the kept points or the kept points appended to
/// `out`. kVoxel returns false as soon as a kept point's leaf is beyond kMaxLeafIndex or the window.
/// kChannels: 0 (no colour), 3 or 4.
template <bool kMetres, int kChannels, bool kVoxel>
bool fusedPass(const DepthImageView& depth, const ColorImageView& color, const float* x_n, const float* y_n,
               const RigidTransform& tf, const FilterOptions& options, const VoxelSetup& vs, ColoredPoints& out,
               PassResult& res) {
  const bool bgr = isBgr(color.encoding);
  const std::size_t ci_r = bgr ? 2 : 0;
  const std::size_t ci_b = bgr ? 0 : 2;
  const PassSetup setup(tf, options, vs.inv);
  RowBuffer& b = tl_row;
  b.resize(depth.width);
  // The voxel pass's leaves (without kVoxel, nothing below touches them).
  LeafWindow& window = kVoxel ? *vs.window : tl_window;
  uint32_t* const head = kVoxel ? window.heads() : nullptr;
  std::vector<FusedLeaf>& leaves = window.leaves;
  std::vector<uint32_t>& leaf_column = window.leaf_column;
  const float* const px = b.px.data();
  const float* const py = b.py.data();
  const float* const pz = b.pz.data();
  const int32_t* const bix = b.ix.data();
  const int32_t* const biy = b.iy.data();
  const int32_t* const biz = b.iz.data();
  const uint32_t* const flags = b.flags.data();
  // The current leaf (the previous kept point's: a camera's neighbouring pixels mostly share it, and then need
  // no lookup) and its sums, held in registers until the next point falls into another leaf. They are the
  // leaf's own sums moved, not partial sums: each addition is the one columnVoxelGrid makes, in its order.
  int32_t last_ix = std::numeric_limits<int32_t>::min();  // never a leaf index (|index| < 2^29)
  int32_t last_iy = 0;
  int32_t last_iz = 0;
  uint32_t cur = 0;  // leaf + 1, 0: none yet
  float sx = 0.0f, sy = 0.0f, sz = 0.0f;
  uint32_t sr = 0, sg = 0, sb = 0, count = 0;
  std::size_t nonfinite = 0, too_close = 0, outside_box = 0, points_in = 0, kept = 0;
  for (uint32_t v = 0; v < depth.height; ++v) {
    const uint8_t* row = depth.data + static_cast<std::size_t>(v) * depth.step_bytes;
    const uint8_t* crow = kChannels != 0 ? color.data + static_cast<std::size_t>(v) * color.step_bytes : nullptr;
    rowFirstPhase<kMetres>(row, depth.width, x_n, y_n[v], setup, b, res.bounds);
    for (uint32_t u = 0; u < depth.width; ++u) {
      const uint32_t f = flags[u];
      if ((f & kKept) != kKept) {  // transformAndFilter's order: non-finite, then too close, then the box
        if (f & kReturn) {
          ++points_in;
          if (!(f & kFinite))
            ++nonfinite;
          else if (!(f & kFar))
            ++too_close;
          else
            ++outside_box;
        }
        continue;
      }
      ++points_in;
      std::array<uint8_t, 3> rgb{};
      if (kChannels != 0) {
        const uint8_t* c = crow + static_cast<std::size_t>(kChannels) * u;
        rgb = {c[ci_r], c[1], c[ci_b]};
      }
      if (++kept == 1) {
        res.first = Point3(px[u], py[u], pz[u]);
        res.first_rgb = rgb;
      }
      if constexpr (!kVoxel) {
        out.xyz.emplace_back(px[u], py[u], pz[u]);
        if (kChannels != 0) out.rgb.push_back(rgb);
      } else {
        if (!(f & kIndexable)) return false;
        const int32_t ix = bix[u];
        const int32_t iy = biy[u];
        const int32_t iz = biz[u];
        if (ix != last_ix || iy != last_iy || iz != last_iz) {
          const auto wx = static_cast<uint64_t>(static_cast<int64_t>(ix) - vs.col0[0]);
          const auto wy = static_cast<uint64_t>(static_cast<int64_t>(iy) - vs.col0[1]);
          if (wx >= static_cast<uint64_t>(kWindowSide) || wy >= static_cast<uint64_t>(kWindowSide)) return false;
          if (cur != 0) {
            FusedLeaf& l = leaves[cur - 1];
            l.sx = sx, l.sy = sy, l.sz = sz, l.sr = sr, l.sg = sg, l.sb = sb, l.count = count;
          }
          const auto col = static_cast<uint32_t>(wx + wy * static_cast<uint64_t>(kWindowSide));
          uint32_t e = head[col];
          while (e != 0 && leaves[e - 1].iz != iz) e = leaves[e - 1].next;
          if (e == 0) {
            leaves.push_back({iz, head[col], 0, 0.0f, 0.0f, 0.0f, 0, 0, 0});
            leaf_column.push_back(col);
            e = static_cast<uint32_t>(leaves.size());
            head[col] = e;
          }
          cur = e;
          const FusedLeaf& l = leaves[cur - 1];
          sx = l.sx, sy = l.sy, sz = l.sz, sr = l.sr, sg = l.sg, sb = l.sb, count = l.count;
          last_ix = ix;
          last_iy = iy;
          last_iz = iz;
        }
        sx += px[u];
        sy += py[u];
        sz += pz[u];
        if (kChannels != 0) {
          sr += rgb[0];
          sg += rgb[1];
          sb += rgb[2];
        }
        ++count;
      }
    }
  }
  if constexpr (kVoxel) {
    if (cur != 0) {
      FusedLeaf& l = leaves[cur - 1];
      l.sx = sx, l.sy = sy, l.sz = sz, l.sr = sr, l.sg = sg, l.sb = sb, l.count = count;
    }
  }
  if constexpr (kVoxel) {
    if (kChannels != 0) {
      for (const FusedLeaf& l : leaves) {
        if (l.sr >= kExactColorSum || l.sg >= kExactColorSum || l.sb >= kExactColorSum) {
          res.color_sums_exact = false;
          break;
        }
      }
    }
  }
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
  if (!dispatchPass<true>(depth, color, x_n, y_n, tf, options, vs, out, res) || !res.color_sums_exact) {
    return threeStages(depth, color, k, tf, options, out, stats);
  }
  addStats(stats, res.stats);
  out.clear();
  const bool has_color = color.data != nullptr;
  if (res.kept < 2) {  // voxelGridFilter leaves clouds of fewer than two points alone
    if (res.kept == 1) {
      out.xyz.push_back(res.first);
      if (has_color) out.rgb.push_back(res.first_rgb);
    }
    stats.points_out = out.size();
    return DepthFrontEndPath::kOnePass;
  }
  if (voxel_leaf::voxelIndexOverflows(res.bounds.lo, res.bounds.hi, options.voxel_leaf_m)) {
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
  const std::vector<FusedLeaf>& leaves = tl_window.leaves;
  out.xyz.resize(leaves.size());
  if (has_color) out.rgb.resize(leaves.size());
  for (std::size_t j = 0; j < leaves.size(); ++j) {
    const FusedLeaf& l = leaves[j];
    const auto fc = static_cast<float>(l.count);
    out.xyz[j] = Point3(l.sx / fc, l.sy / fc, l.sz / fc);
    if (has_color) {
      std::array<uint8_t, 3>& c = out.rgb[j];
      c[0] = static_cast<uint8_t>(static_cast<float>(l.sr) / fc);  // exact: below kExactColorSum
      c[1] = static_cast<uint8_t>(static_cast<float>(l.sg) / fc);
      c[2] = static_cast<uint8_t>(static_cast<float>(l.sb) / fc);
    }
  }
  stats.points_out = out.size();
  return DepthFrontEndPath::kOnePass;
}

}  // namespace uav_mapping
