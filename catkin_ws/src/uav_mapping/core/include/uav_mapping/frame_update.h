// Turning one point cloud (already in the map frame) into the set of voxel updates of that frame.
//
// The result is backend-independent: a Morton-sorted list of unique voxels, each either a hit (occupied
// endpoint, with the mean colour of its points) or a miss (free space crossed by a ray). Both backends
// apply the same list, which is why they agree on the occupied set.
//
// Full ray clearing reproduces OctoMap's OccupancyOcTreeBase::computeUpdate exactly (same DDA arithmetic,
// same max-range handling, occupied endpoints win over free cells), but deduplicates the ray keys in a
// dense byte map over the frame's key box instead of a hash set, and can run the rays on several threads.
#pragma once

#include <uav_mapping/keys.h>

#include <array>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

namespace uav_mapping {

enum class InsertMode { kFull, kTruncated, kSurface };

std::string toString(InsertMode mode);
/// Parses "full", "truncated" or "surface"; throws std::invalid_argument otherwise.
InsertMode insertModeFromString(const std::string& name);

/// Points in the map frame with optional per-point colour (rgb empty = no colour).
struct ColoredPoints {
  std::vector<Point3> xyz;
  std::vector<std::array<uint8_t, 3>> rgb;

  std::size_t size() const { return xyz.size(); }
  bool hasColor() const { return !rgb.empty(); }
  void clear() {
    xyz.clear();
    rgb.clear();
  }
};

struct RayOptions {
  InsertMode mode = InsertMode::kFull;
  /// OctoMap semantics: < 0 unlimited; a longer ray clears free space up to this range and adds no hit
  /// (full mode); truncated and surface modes ignore such points.
  double max_range_m = -1.0;
  /// Truncated mode: free space is cleared only along the last `truncation_m` before each hit.
  double truncation_m = 3.0;
  int threads = 1;
};

/// One voxel of a frame's update. 16 bytes.
struct VoxelUpdate {
  uint64_t morton;
  uint8_t hit;        // 1 = occupied endpoint, 0 = free (miss)
  uint8_t has_color;  // hit with coloured points
  uint8_t r, g, b;
  uint8_t pad[3];
};

struct FrameUpdate {
  std::vector<VoxelUpdate> updates;  // unique, sorted by Morton code
  KeyBox box;                        // key box of `updates`
  std::size_t hits = 0;
  std::size_t misses = 0;
  std::size_t rays = 0;                // rays traced (points in range or clipped at max range)
  std::size_t points_out_of_map = 0;   // endpoints or rays outside the addressable key cube
  bool used_byte_map = false;          // false when the frame's key box was too large (sort fallback)

  void clear() {
    updates.clear();
    box = KeyBox();
    hits = misses = rays = points_out_of_map = 0;
    used_byte_map = false;
  }
};

/// Builds FrameUpdates; keeps its scratch buffers between frames (not thread-safe; one per map).
class FrameUpdateBuilder {
 public:
  explicit FrameUpdateBuilder(double resolution_m, std::size_t max_byte_map_bytes = std::size_t(512) << 20);
  ~FrameUpdateBuilder();
  FrameUpdateBuilder(FrameUpdateBuilder&&) noexcept;
  FrameUpdateBuilder& operator=(FrameUpdateBuilder&&) noexcept;

  void build(const ColoredPoints& points, const Point3& origin, const RayOptions& options, FrameUpdate& out);

  double resolution() const { return grid_.resolution(); }

 private:
  struct Impl;
  KeyGrid grid_;
  std::size_t max_byte_map_bytes_;
  std::unique_ptr<Impl> impl_;
};

/// Sorts (morton, payload) pairs by morton with an LSD radix sort (skips digits that are constant).
struct MortonItem {
  uint64_t morton;
  uint32_t index;  // first point of a run of consecutive points in the same voxel
  uint32_t count;  // points in the run
};
void radixSortByMorton(std::vector<MortonItem>& items, std::vector<MortonItem>& scratch);

}  // namespace uav_mapping
