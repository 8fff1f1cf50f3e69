#include <uav_mapping/frame_update.h>

#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <stdexcept>

namespace uav_mapping {

std::string toString(InsertMode mode) {
  switch (mode) {
    case InsertMode::kFull:
      return "full";
    case InsertMode::kTruncated:
      return "truncated";
    case InsertMode::kSurface:
      return "surface";
  }
  return "?";
}

InsertMode insertModeFromString(const std::string& name) {
  if (name == "full") return InsertMode::kFull;
  if (name == "truncated") return InsertMode::kTruncated;
  if (name == "surface") return InsertMode::kSurface;
  throw std::invalid_argument("insert mode must be full, truncated or surface, got '" + name + "'");
}

void radixSortByMorton(std::vector<MortonItem>& items, std::vector<MortonItem>& scratch) {
  constexpr int kDigits = 6;  // 48-bit Morton codes, 8 bits per pass
  const std::size_t n = items.size();
  if (n < 2) return;
  if (n < 256) {
    std::sort(items.begin(), items.end(), [](const MortonItem& a, const MortonItem& b) { return a.morton < b.morton; });
    return;
  }
  std::vector<std::array<std::size_t, 256>> hist(kDigits);
  for (auto& h : hist) h.fill(0);
  for (const MortonItem& it : items) {
    for (int d = 0; d < kDigits; ++d) ++hist[d][(it.morton >> (8 * d)) & 0xFF];
  }
  scratch.resize(n);
  std::vector<MortonItem>* src = &items;
  std::vector<MortonItem>* dst = &scratch;
  for (int d = 0; d < kDigits; ++d) {
    auto& h = hist[d];
    if (std::any_of(h.begin(), h.end(), [n](std::size_t c) { return c == n; })) continue;  // constant digit
    std::size_t sum = 0;
    for (auto& c : h) {
      const std::size_t c0 = c;
      c = sum;
      sum += c0;
    }
    for (const MortonItem& it : *src) (*dst)[h[(it.morton >> (8 * d)) & 0xFF]++] = it;
    std::swap(src, dst);
  }
  if (src != &items) items.swap(scratch);
}

namespace {

/// One axis of the DDA's start (OctoMap's computeRayKeys arithmetic, float rounding of the half step
/// included): the step direction, the ray parameter of the first voxel border and of one voxel.
inline void initDdaAxis(const KeyGrid& grid, uint16_t key, double origin, double direction, double res, int& step,
                        double& t_max, double& t_delta) {
  if (direction > 0.0)
    step = 1;
  else if (direction < 0.0)
    step = -1;
  else
    step = 0;
  if (step != 0) {
    double voxel_border = grid.toCoord(key);
    voxel_border += static_cast<float>(step * res * 0.5);
    t_max = (voxel_border - origin) / direction;
    t_delta = res / std::fabs(direction);
  } else {
    t_max = std::numeric_limits<double>::max();
    t_delta = std::numeric_limits<double>::max();
  }
}

/// OctoMap's computeRayKeys (OcTreeBaseImpl.hxx, Amanatides & Woo DDA) with the same arithmetic, calling
/// visit(key) for every free key: the origin's key first, the end's key excluded. Returns false if either
/// end is outside the addressable key cube (OctoMap then adds nothing).
template <class Visit>
inline bool traceRay(const KeyGrid& grid, const Point3& origin, const Point3& end, Visit&& visit) {
  Key key_origin;
  Key key_end;
  if (!grid.toKey(origin, key_origin) || !grid.toKey(end, key_end)) return false;
  if (key_origin == key_end) return true;
  visit(key_origin);

  Point3 direction = (end - origin);
  const float length = static_cast<float>(direction.norm());
  direction /= length;

  int step[3];
  double t_max[3];
  double t_delta[3];
  Key current = key_origin;
  const double res = grid.resolution();
  for (unsigned i = 0; i < 3; ++i) {
    initDdaAxis(grid, current[i], origin(i), direction(i), res, step[i], t_max[i], t_delta[i]);
  }
  while (true) {
    unsigned dim;
    if (t_max[0] < t_max[1])
      dim = (t_max[0] < t_max[2]) ? 0 : 2;
    else
      dim = (t_max[1] < t_max[2]) ? 1 : 2;
    current[dim] = static_cast<uint16_t>(current[dim] + step[dim]);
    t_max[dim] += t_delta[dim];
    if (current == key_end) break;
    const double dist_from_origin = std::min(std::min(t_max[0], t_max[1]), t_max[2]);
    if (dist_from_origin > length) break;
    visit(current);
  }
  return true;
}

/// Dense byte per voxel over the frame's key box (x fastest). The box is aligned to the global 8^3 brick grid,
/// so every 8 consecutive x cells of a row are one aligned 64-bit word of a brick; scan() walks the non-empty
/// bricks in Morton order and emits keys already in global Morton order.
struct ByteMap {
  int k0[3] = {0, 0, 0};  // first key per axis (multiple of 8)
  int n[3] = {0, 0, 0};   // cells per axis (multiples of 8)
  std::size_t stride[3] = {1, 0, 0};
  std::vector<uint8_t> cells;  // zero between frames
  /// Per 8^3 brick: 1 if it may hold set cells. Empty: scan() reads every brick. Truncated rays end at their hit,
  /// so only the bricks near the hits can be touched (restrictToHits).
  std::vector<uint8_t> brick_flags;

  static std::size_t bytesFor(const KeyBox& box) {
    std::size_t bytes = 1;
    for (int i = 0; i < 3; ++i) bytes *= static_cast<std::size_t>(((box.max[i] >> 3) - (box.min[i] >> 3) + 1) * 8);
    return bytes;
  }

  void setBox(const KeyBox& box) {
    for (int i = 0; i < 3; ++i) {
      k0[i] = (box.min[i] >> 3) << 3;
      n[i] = ((box.max[i] >> 3) - (box.min[i] >> 3) + 1) * 8;
    }
    stride[0] = 1;
    stride[1] = static_cast<std::size_t>(n[0]);
    stride[2] = static_cast<std::size_t>(n[0]) * n[1];
    const std::size_t need = stride[2] * n[2];
    if (cells.size() < need) cells.assign(need, 0);  // stays zero: scan() clears what it reads
    brick_flags.clear();
  }

  /// Limits the next scan() to the bricks within `radius` bricks (per axis) of a brick holding one of `keys`.
  /// Every cell set before that scan must lie in one of them, or it is never cleared.
  void restrictToHits(const std::vector<Key>& keys, int radius) {
    const int nb[3] = {n[0] / 8, n[1] / 8, n[2] / 8};
    const std::size_t sy = static_cast<std::size_t>(nb[0]);
    const std::size_t sz = sy * static_cast<std::size_t>(nb[1]);
    brick_flags.assign(sz * static_cast<std::size_t>(nb[2]), 0);
    for (const Key& k : keys) {
      if (!inside(k)) continue;
      brick_flags[static_cast<std::size_t>((k[0] - k0[0]) >> 3) + static_cast<std::size_t>((k[1] - k0[1]) >> 3) * sy +
                  static_cast<std::size_t>((k[2] - k0[2]) >> 3) * sz] = 1;
    }
    // Separable dilation: `radius` passes along each axis.
    const std::size_t strides[3] = {1, sy, sz};
    std::vector<uint8_t> prev;
    for (int axis = 0; axis < 3; ++axis) {
      for (int pass = 0; pass < radius; ++pass) {
        prev = brick_flags;
        const std::size_t st = strides[axis];
        for (std::size_t i = 0; i < prev.size(); ++i) {
          if (prev[i] == 0) continue;
          const int c = static_cast<int>((i / st) % static_cast<std::size_t>(nb[axis]));
          if (c > 0) brick_flags[i - st] = 1;
          if (c + 1 < nb[axis]) brick_flags[i + st] = 1;
        }
      }
    }
  }

  bool inside(const Key& k) const {
    return static_cast<unsigned>(k[0] - k0[0]) < static_cast<unsigned>(n[0]) &&
           static_cast<unsigned>(k[1] - k0[1]) < static_cast<unsigned>(n[1]) &&
           static_cast<unsigned>(k[2] - k0[2]) < static_cast<unsigned>(n[2]);
  }
  std::size_t index(const Key& k) const {
    return static_cast<std::size_t>(k[0] - k0[0]) + static_cast<std::size_t>(k[1] - k0[1]) * stride[1] +
           static_cast<std::size_t>(k[2] - k0[2]) * stride[2];
  }
  void set(const Key& k, uint8_t v) { cells[index(k)] = v; }

  /// Appends the Morton codes of all cells equal to 1, in Morton order, and zeroes the map.
  ///
  /// One pass over the box reads each brick's 64 rows of 8 cells as words; the set cells of a brick go into a
  /// 512-bit mask indexed by their Morton code within the brick, so emitting them in Morton order is a walk
  /// over set bits (no per-cell loop over the 512 cells of every non-empty brick).
  void scan(std::vector<uint64_t>& out) {
    struct BrickRef {
      uint64_t morton;
      uint64_t bits[8];  // bit l: the cell with Morton code l within the brick is set
    };
    std::vector<BrickRef> bricks;
    unsigned spread[8];
    for (unsigned i = 0; i < 8; ++i) spread[i] = static_cast<unsigned>(spreadBits3(i));
    const int nb[3] = {n[0] / 8, n[1] / 8, n[2] / 8};
    const uint8_t* flags = brick_flags.empty() ? nullptr : brick_flags.data();
    std::size_t brick = 0;
    for (int bz = 0; bz < nb[2]; ++bz) {
      for (int by = 0; by < nb[1]; ++by) {
        for (int bx = 0; bx < nb[0]; ++bx, ++brick) {
          if (flags != nullptr && flags[brick] == 0) continue;
          const std::size_t base = static_cast<std::size_t>(bx) * 8 + static_cast<std::size_t>(by) * 8 * stride[1] +
                                   static_cast<std::size_t>(bz) * 8 * stride[2];
          BrickRef br{};
          bool any = false;
          for (unsigned z = 0; z < 8; ++z) {
            for (unsigned y = 0; y < 8; ++y) {
              uint8_t* row = &cells[base + y * stride[1] + z * stride[2]];
              uint64_t w;
              std::memcpy(&w, row, 8);
              if (w == 0) continue;
              std::memset(row, 0, 8);
              any = true;
              uint64_t m = w & 0x0101010101010101ULL;  // cells equal to 1 (hits were reset to 0)
              const unsigned yz = (spread[y] << 1) | (spread[z] << 2);
              while (m != 0) {
                const unsigned l = spread[static_cast<unsigned>(__builtin_ctzll(m)) >> 3] | yz;
                br.bits[l >> 6] |= 1ULL << (l & 63U);
                m &= m - 1;
              }
            }
          }
          if (!any) continue;
          const Key bk(static_cast<uint16_t>((k0[0] >> 3) + bx), static_cast<uint16_t>((k0[1] >> 3) + by),
                       static_cast<uint16_t>((k0[2] >> 3) + bz));
          br.morton = mortonOf(bk);
          bricks.push_back(br);
        }
      }
    }
    std::sort(bricks.begin(), bricks.end(), [](const BrickRef& a, const BrickRef& b) { return a.morton < b.morton; });
    for (const BrickRef& br : bricks) {
      const uint64_t top = br.morton << 9;
      for (unsigned k = 0; k < 8; ++k) {
        uint64_t b = br.bits[k];
        while (b != 0) {
          out.push_back(top | (static_cast<uint64_t>(k) << 6) | static_cast<uint64_t>(__builtin_ctzll(b)));
          b &= b - 1;
        }
      }
    }
  }
};

/// traceRay() specialised for marking a ByteMap: the same DDA arithmetic and termination, with the cell index
/// stepped incrementally and branch-free axis selection. Keys outside the map go to `spill`.
inline bool markRay(const KeyGrid& grid, const Point3& origin, const Point3& end, ByteMap& bm,
                    std::vector<uint64_t>& spill) {
  Key key_origin;
  Key key_end;
  if (!grid.toKey(origin, key_origin) || !grid.toKey(end, key_end)) return false;
  if (key_origin == key_end) return true;

  Point3 direction = (end - origin);
  const float length = static_cast<float>(direction.norm());
  direction /= length;

  int step[3];
  double t_max[3];
  double t_delta[3];
  const double res = grid.resolution();
  int cur[3];
  int endk[3];
  std::ptrdiff_t delta[3];  // cell index change of one step along each axis
  for (unsigned i = 0; i < 3; ++i) {
    initDdaAxis(grid, key_origin[i], origin(i), direction(i), res, step[i], t_max[i], t_delta[i]);
    cur[i] = key_origin[i];
    endk[i] = key_end[i];
    delta[i] = static_cast<std::ptrdiff_t>(step[i]) * static_cast<std::ptrdiff_t>(bm.stride[i]);
  }
  // Everything the loop touches lives in scalars (registers): indexed arrays would put the loop-carried
  // dependency through store-to-load forwarding.
  const unsigned ex = static_cast<unsigned>(bm.n[0]);
  const unsigned ey = static_cast<unsigned>(bm.n[1]);
  const unsigned ez = static_cast<unsigned>(bm.n[2]);
  const int bx = bm.k0[0];
  const int by = bm.k0[1];
  const int bz = bm.k0[2];
  double t0 = t_max[0], t1 = t_max[1], t2 = t_max[2];
  const double d0 = t_delta[0], d1 = t_delta[1], d2 = t_delta[2];
  int c0 = cur[0], c1 = cur[1], c2 = cur[2];
  const int s0 = step[0], s1 = step[1], s2 = step[2];
  const int e0 = endk[0], e1 = endk[1], e2 = endk[2];
  const std::ptrdiff_t i0 = delta[0], i1 = delta[1], i2 = delta[2];
  uint8_t* cells = bm.cells.data();
  std::ptrdiff_t idx = static_cast<std::ptrdiff_t>(c0 - bx) +
                       static_cast<std::ptrdiff_t>(c1 - by) * static_cast<std::ptrdiff_t>(bm.stride[1]) +
                       static_cast<std::ptrdiff_t>(c2 - bz) * static_cast<std::ptrdiff_t>(bm.stride[2]);
  auto emit = [&]() {
    if (static_cast<unsigned>(c0 - bx) < ex && static_cast<unsigned>(c1 - by) < ey &&
        static_cast<unsigned>(c2 - bz) < ez) {
      __atomic_store_n(&cells[idx], static_cast<uint8_t>(1), __ATOMIC_RELAXED);
    } else {
      spill.push_back(
          mortonOf(Key(static_cast<uint16_t>(c0), static_cast<uint16_t>(c1), static_cast<uint16_t>(c2))));
    }
  };
  emit();  // the origin's key
  while (true) {
    // OctoMap: if (t0 < t1) dim = (t0 < t2) ? 0 : 2; else dim = (t1 < t2) ? 1 : 2;
    const bool a01 = t0 < t1;
    const bool x = a01 & (t0 < t2);
    const bool y = !a01 & (t1 < t2);
    const bool z = !(x | y);
    c0 = (c0 + (x ? s0 : 0)) & 0xFFFF;  // uint16 key arithmetic, as OctoMap
    c1 = (c1 + (y ? s1 : 0)) & 0xFFFF;
    c2 = (c2 + (z ? s2 : 0)) & 0xFFFF;
    idx += (x ? i0 : 0) + (y ? i1 : 0) + (z ? i2 : 0);
    t0 = x ? t0 + d0 : t0;
    t1 = y ? t1 + d1 : t1;
    t2 = z ? t2 + d2 : t2;
    if ((c0 == e0) & (c1 == e1) & (c2 == e2)) break;
    const double dist_from_origin = std::min(std::min(t0, t1), t2);
    if (dist_from_origin > length) break;
    emit();
  }
  return true;
}

inline std::array<uint8_t, 3> meanColor(const uint32_t sum[3], uint32_t count) {
  return {static_cast<uint8_t>((sum[0] + count / 2) / count), static_cast<uint8_t>((sum[1] + count / 2) / count),
          static_cast<uint8_t>((sum[2] + count / 2) / count)};
}

}  // namespace

struct FrameUpdateBuilder::Impl {
  std::vector<Point3> ray_start;
  std::vector<Point3> ray_end;
  std::vector<uint8_t> has_ray;
  std::vector<MortonItem> hits;
  std::vector<MortonItem> sort_scratch;
  std::vector<uint64_t> free_keys;
  std::vector<Key> hit_keys;
  ByteMap byte_map;
};

FrameUpdateBuilder::FrameUpdateBuilder(double resolution_m, std::size_t max_byte_map_bytes)
    : grid_(resolution_m), max_byte_map_bytes_(max_byte_map_bytes), impl_(std::make_unique<Impl>()) {}

FrameUpdateBuilder::~FrameUpdateBuilder() = default;
FrameUpdateBuilder::FrameUpdateBuilder(FrameUpdateBuilder&&) noexcept = default;
FrameUpdateBuilder& FrameUpdateBuilder::operator=(FrameUpdateBuilder&&) noexcept = default;

void FrameUpdateBuilder::build(const ColoredPoints& points, const Point3& origin, const RayOptions& options,
                               FrameUpdate& out) {
  out.clear();
  Impl& s = *impl_;
  const std::size_t n = points.size();
  const bool rays_wanted = options.mode != InsertMode::kSurface;
  const bool color = points.hasColor();
  const double max_range = options.max_range_m;
  const auto trunc = static_cast<float>(options.truncation_m);

  // Pass 1 (parallel over chunks of points): per point, the free-space ray (if any) and the hit key (if any).
  s.ray_start.resize(rays_wanted ? n : 0);
  s.ray_end.resize(rays_wanted ? n : 0);
  s.has_ray.assign(rays_wanted ? n : 0, 0);
  Key origin_key;
  const bool origin_ok = grid_.toKey(origin, origin_key);
  constexpr std::size_t kChunk = 16384;
  const std::size_t n_chunks = (n + kChunk - 1) / kChunk;
  struct ChunkResult {
    std::vector<MortonItem> hits;
    KeyBox ray_box;
    std::size_t rays = 0;
    std::size_t out_of_map = 0;
  };
  std::vector<ChunkResult> chunks(n_chunks);
  auto pass1 = [&](std::size_t chunk) {
    ChunkResult& cr = chunks[chunk];
    cr.hits.reserve(kChunk / 2);
    Key last_hit_key(0, 0, 0);
    bool last_hit_valid = false;
    const std::size_t end_i = std::min(n, (chunk + 1) * kChunk);
    for (std::size_t i = chunk * kChunk; i < end_i; ++i) {
      const Point3& p = points.xyz[i];
      const bool in_range = (max_range < 0.0) || ((p - origin).norm() <= max_range);
      bool outside = false;  // the point (or its ray) lies outside the addressable key cube
      if (in_range) {
        Key k;
        if (grid_.toKey(p, k)) {
          // Neighbouring pixels mostly share a voxel: extend the current run instead of sorting every point.
          if (last_hit_valid && k == last_hit_key && cr.hits.back().index + cr.hits.back().count == i) {
            ++cr.hits.back().count;
          } else {
            cr.hits.push_back({mortonOf(k), static_cast<uint32_t>(i), 1});
            last_hit_key = k;
            last_hit_valid = true;
          }
        } else {
          outside = true;
        }
      }
      if (rays_wanted && (in_range || options.mode == InsertMode::kFull)) {
        Point3 start = origin;
        Point3 end = p;
        if (options.mode == InsertMode::kFull) {
          if (!in_range) {
            const Point3 direction = (p - origin).normalized();
            end = origin + direction * static_cast<float>(max_range);
          }
        } else {  // truncated: only the last `trunc` metres before a hit
          const Point3 d = p - origin;
          const double dist = d.norm();
          if (dist > trunc) start = p - d * static_cast<float>(trunc / dist);
        }
        Key ks;
        Key ke;
        if ((options.mode == InsertMode::kFull ? origin_ok : grid_.toKey(start, ks)) && grid_.toKey(end, ke)) {
          s.ray_start[i] = start;
          s.ray_end[i] = end;
          s.has_ray[i] = 1;
          cr.ray_box.add(options.mode == InsertMode::kFull ? origin_key : ks);
          cr.ray_box.add(ke);
          ++cr.rays;
        } else {
          outside = true;
        }
      }
      if (outside) ++cr.out_of_map;
    }
  };
  tbb::task_arena arena(std::max(1, options.threads));
  arena.execute([&] {
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n_chunks, 1), [&](const tbb::blocked_range<std::size_t>& r) {
      for (std::size_t c = r.begin(); c < r.end(); ++c) pass1(c);
    });
  });
  s.hits.clear();
  KeyBox ray_box;
  for (const ChunkResult& cr : chunks) {
    s.hits.insert(s.hits.end(), cr.hits.begin(), cr.hits.end());
    ray_box.merge(cr.ray_box);
    out.rays += cr.rays;
    out.points_out_of_map += cr.out_of_map;
  }

  // Hits: sort by voxel, average colours.
  radixSortByMorton(s.hits, s.sort_scratch);
  std::vector<VoxelUpdate> hit_updates;
  hit_updates.reserve(s.hits.size() / 4 + 16);
  for (std::size_t a = 0; a < s.hits.size();) {
    std::size_t b = a;
    uint32_t sum[3] = {0, 0, 0};
    uint32_t count = 0;
    while (b < s.hits.size() && s.hits[b].morton == s.hits[a].morton) {
      if (color) {
        for (uint32_t j = s.hits[b].index; j < s.hits[b].index + s.hits[b].count; ++j) {
          const auto& c = points.rgb[j];
          sum[0] += c[0];
          sum[1] += c[1];
          sum[2] += c[2];
        }
      }
      count += s.hits[b].count;
      ++b;
    }
    VoxelUpdate u{};
    u.morton = s.hits[a].morton;
    u.hit = 1;
    if (color) {
      const auto m = meanColor(sum, count);
      u.has_color = 1;
      u.r = m[0];
      u.g = m[1];
      u.b = m[2];
    }
    hit_updates.push_back(u);
    out.box.add(keyOfMorton(u.morton));
    a = b;
  }
  out.hits = hit_updates.size();

  // Free space.
  s.free_keys.clear();
  if (rays_wanted && !ray_box.empty()) {
    KeyBox padded = ray_box;  // DDA round-off may step one voxel past the end key's box
    for (int i = 0; i < 3; ++i) {
      padded.min[i] = std::max(0, padded.min[i] - 1);
      padded.max[i] = std::min(2 * kKeyOffset - 1, padded.max[i] + 1);
    }
    tbb::enumerable_thread_specific<std::vector<uint64_t>> spill;
    const bool dense = ByteMap::bytesFor(padded) <= max_byte_map_bytes_;
    out.used_byte_map = dense;
    if (dense) s.byte_map.setBox(padded);
    ByteMap& bm = s.byte_map;
    if (dense && options.mode == InsertMode::kTruncated) {
      // A truncated ray's keys lie within ceil(truncation / res) + 1 keys of its end (its hit) per axis, and the
      // DDA may step one key past: within `margin` keys, i.e. `radius` bricks of the hit's brick.
      const double margin = std::ceil(options.truncation_m / grid_.resolution()) + 2.0;
      const int radius = static_cast<int>(std::ceil(margin / 8.0));
      if (radius <= 2) {
        s.hit_keys.clear();
        for (const VoxelUpdate& h : hit_updates) s.hit_keys.push_back(keyOfMorton(h.morton));
        bm.restrictToHits(s.hit_keys, radius);
      }
    }
    arena.execute([&] {
      tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n, 4096), [&](const tbb::blocked_range<std::size_t>& r) {
        std::vector<uint64_t>& local = spill.local();
        for (std::size_t i = r.begin(); i < r.end(); ++i) {
          if (!s.has_ray[i]) continue;
          if (dense) {
            markRay(grid_, s.ray_start[i], s.ray_end[i], bm, local);
          } else {
            traceRay(grid_, s.ray_start[i], s.ray_end[i], [&](const Key& k) { local.push_back(mortonOf(k)); });
          }
        }
      });
    });
    std::vector<MortonItem> spilled;
    for (auto& v : spill) {
      for (uint64_t m : v) spilled.push_back({m, 0, 1});
    }
    if (dense) {
      for (const VoxelUpdate& h : hit_updates) {  // occupied endpoints win over free cells
        const Key k = keyOfMorton(h.morton);
        if (bm.inside(k)) bm.set(k, 0);
      }
      bm.scan(s.free_keys);
      out.box.merge(padded);
    }
    if (!spilled.empty()) {
      radixSortByMorton(spilled, s.sort_scratch);
      std::vector<uint64_t> merged;
      merged.reserve(s.free_keys.size() + spilled.size());
      std::size_t a = 0;
      uint64_t last = ~0ULL;
      for (const MortonItem& it : spilled) {
        while (a < s.free_keys.size() && s.free_keys[a] < it.morton) merged.push_back(s.free_keys[a++]);
        if (it.morton != last && (a >= s.free_keys.size() || s.free_keys[a] != it.morton)) {
          merged.push_back(it.morton);
          out.box.add(keyOfMorton(it.morton));
        }
        last = it.morton;
      }
      while (a < s.free_keys.size()) merged.push_back(s.free_keys[a++]);
      // drop hits (only the spilled keys can still contain them)
      std::vector<uint64_t> filtered;
      filtered.reserve(merged.size());
      std::size_t h = 0;
      for (uint64_t m : merged) {
        while (h < hit_updates.size() && hit_updates[h].morton < m) ++h;
        if (h < hit_updates.size() && hit_updates[h].morton == m) continue;
        filtered.push_back(m);
      }
      s.free_keys.swap(filtered);
    }
  }
  out.misses = s.free_keys.size();

  // Merge the two sorted, disjoint lists.
  out.updates.resize(hit_updates.size() + s.free_keys.size());
  std::size_t a = 0;
  std::size_t b = 0;
  std::size_t o = 0;
  while (a < hit_updates.size() || b < s.free_keys.size()) {
    if (b >= s.free_keys.size() || (a < hit_updates.size() && hit_updates[a].morton < s.free_keys[b])) {
      out.updates[o++] = hit_updates[a++];
    } else {
      VoxelUpdate u{};
      u.morton = s.free_keys[b++];
      out.updates[o++] = u;
    }
  }
}

}  // namespace uav_mapping
