// Voxel keys shared by both backends.
//
// A key is OctoMap's 16-bit-per-axis address at the finest tree level: key = floor(coord / res) + 32768,
// so voxel key k spans [(k - 32768) * res, (k - 32768 + 1) * res) along each axis of the map frame. The
// OpenVDB backend uses index coordinates i = k - 32768 (same voxels). Morton codes interleave the key
// bits in OctoMap's child order (bit 0 = x, bit 1 = y, bit 2 = z at each level, root level first), so
// sorting by Morton code is a depth-first order of the octree.
#pragma once

#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <vector>

// OcTreeKey.h is not self-contained: it needs <cstdint>/<vector> and octomap_types.h first.
#include <octomap/octomap_types.h>
#include <octomap/OcTreeKey.h>

namespace uav_mapping {

using Key = octomap::OcTreeKey;
using Point3 = octomap::point3d;  // float x, y, z in the map frame (metres), as OctoMap uses

constexpr int kTreeDepth = 16;
constexpr int kKeyOffset = 32768;  // OctoMap's tree_max_val

/// Spread the 16 low bits of v so that bit i moves to bit 3 * i.
inline uint64_t spreadBits3(uint64_t v) {
  v &= 0xFFFFULL;
  v = (v | (v << 16)) & 0x0000FF0000FFULL;
  v = (v | (v << 8)) & 0x00F00F00F00FULL;
  v = (v | (v << 4)) & 0x0C30C30C30C3ULL;
  v = (v | (v << 2)) & 0x249249249249ULL;
  return v;
}

inline uint64_t compactBits3(uint64_t v) {
  v &= 0x249249249249ULL;
  v = (v | (v >> 2)) & 0x0C30C30C30C3ULL;
  v = (v | (v >> 4)) & 0x00F00F00F00FULL;
  v = (v | (v >> 8)) & 0x0000FF0000FFULL;
  v = (v | (v >> 16)) & 0xFFFFULL;
  return v;
}

/// 48-bit Morton code of a key; the top 3 bits are the child index at depth 0 (OctoMap order).
inline uint64_t mortonOf(const Key& k) {
  return spreadBits3(k[0]) | (spreadBits3(k[1]) << 1) | (spreadBits3(k[2]) << 2);
}

inline Key keyOfMorton(uint64_t m) {
  return Key(static_cast<uint16_t>(compactBits3(m)), static_cast<uint16_t>(compactBits3(m >> 1)),
             static_cast<uint16_t>(compactBits3(m >> 2)));
}

/// Child index (0..7) of the node at `depth` (0 = root) on the path to the voxel with Morton code m.
inline unsigned childIndexAt(uint64_t morton, int depth) {
  return static_cast<unsigned>((morton >> (3 * (kTreeDepth - 1 - depth))) & 7U);
}

/// Key <-> metric conversions with exactly OctoMap's arithmetic (so keys agree bit for bit).
class KeyGrid {
 public:
  explicit KeyGrid(double resolution_m) : res_m_(resolution_m), inv_res_(1.0 / resolution_m) {}

  double resolution() const { return res_m_; }

  /// OctoMap coordToKeyChecked for one axis; false if outside the addressable cube.
  bool toKey(double coord_m, uint16_t& key) const {
    const double scaled = inv_res_ * coord_m;
    if (!(scaled >= -kKeyOffset && scaled < kKeyOffset)) return false;  // also rejects NaN
    // floor() without a libm call (x86-64 has no SSE4.1 round by default); exact for |scaled| < 2^31.
    int i = static_cast<int>(scaled);
    i -= static_cast<int>(scaled < static_cast<double>(i));
    key = static_cast<uint16_t>(i + kKeyOffset);
    return true;
  }

  bool toKey(const Point3& p, Key& key) const { return toKey(p(0), key[0]) && toKey(p(1), key[1]) && toKey(p(2), key[2]); }

  /// Centre of voxel key k along one axis (OctoMap keyToCoord).
  double toCoord(uint16_t k) const { return (static_cast<double>(static_cast<int>(k) - kKeyOffset) + 0.5) * res_m_; }
  /// Lower face of voxel key k along one axis.
  double lowerFace(uint16_t k) const { return static_cast<double>(static_cast<int>(k) - kKeyOffset) * res_m_; }

 private:
  double res_m_;
  double inv_res_;
};

/// Inclusive axis-aligned box of keys (as ints so that it can be empty or padded past the key range).
struct KeyBox {
  std::array<int, 3> min{std::numeric_limits<int>::max(), std::numeric_limits<int>::max(),
                         std::numeric_limits<int>::max()};
  std::array<int, 3> max{std::numeric_limits<int>::min(), std::numeric_limits<int>::min(),
                         std::numeric_limits<int>::min()};

  bool empty() const { return min[0] > max[0]; }
  void add(const Key& k) {
    for (int i = 0; i < 3; ++i) {
      if (k[i] < min[i]) min[i] = k[i];
      if (k[i] > max[i]) max[i] = k[i];
    }
  }
  void merge(const KeyBox& o) {
    for (int i = 0; i < 3; ++i) {
      if (o.min[i] < min[i]) min[i] = o.min[i];
      if (o.max[i] > max[i]) max[i] = o.max[i];
    }
  }
  bool contains(const Key& k) const {
    return k[0] >= min[0] && k[0] <= max[0] && k[1] >= min[1] && k[1] <= max[1] && k[2] >= min[2] && k[2] <= max[2];
  }
  int64_t extent(int axis) const { return empty() ? 0 : static_cast<int64_t>(max[axis]) - min[axis] + 1; }
  int64_t volume() const { return extent(0) * extent(1) * extent(2); }
};

}  // namespace uav_mapping
