// The map server's core without ROS: filters a cloud, builds the frame's voxel updates, applies them to the
// selected backend, keeps the 2D layers up to date, and handles persistence and evaluation export.
#pragma once

#include <uav_mapping/cloud_filter.h>
#include <uav_mapping/column_layers.h>
#include <uav_mapping/frame_update.h>
#include <uav_mapping/voxel_map.h>

#include <array>
#include <functional>
#include <memory>
#include <string>
#include <vector>

namespace uav_mapping {

struct MapperConfig {
  Backend backend = Backend::kOctomap;
  double resolution_m = 0.5;
  SensorModel sensor;
  double max_range_m = -1.0;  // sensor_model/max_range (OctoMap semantics, see RayOptions)
  InsertMode mode = InsertMode::kFull;
  double truncation_m = 3.0;
  FilterOptions filter;
  int threads = 1;
  bool prune = true;
  double color_blend = 0.5;

  /// Throws std::invalid_argument naming the first invalid field.
  void validate() const;
};

struct InsertStats {
  FilterStats filter;
  std::size_t points_inserted = 0;
  std::size_t points_out_of_map = 0;
  std::size_t rays = 0;
  std::size_t hits = 0;    // voxels updated as occupied
  std::size_t misses = 0;  // voxels updated as free
  double filter_ms = 0.0;
  double raycast_ms = 0.0;  // key computation, ray casting, deduplication, sorting
  double update_ms = 0.0;   // backend update
  double layers_ms = 0.0;
  double total_ms = 0.0;
};

class Mapper {
 public:
  explicit Mapper(const MapperConfig& config);

  const MapperConfig& config() const { return config_; }

  /// Full pipeline for a sensor-frame cloud: transform, filters, voxel grid, insertion at stamp_s.
  InsertStats insert(const ColoredPoints& sensor_points, const RigidTransform& map_from_sensor, double stamp_s);
  /// Insertion of points a front end has already transformed, filtered and downsampled with config().filter
  /// (e.g. filterDepthImage, which fuses those steps for depth images): `filter` and `filter_ms` are reported
  /// as the frame's, exactly as insert() reports its own.
  InsertStats insertFiltered(const ColoredPoints& map_points, const FilterStats& filter, double filter_ms,
                             const Point3& origin, double stamp_s);
  /// Insertion only, for points already in the map frame (no filters): what the benchmark times.
  InsertStats insertMapPoints(const ColoredPoints& map_points, const Point3& origin, double stamp_s);

  /// The 2D layers, coarsened by `factor` map cells per layer cell.
  LayersSnapshot layers(int factor = 1) const;
  const ColumnLayers& columnLayers() const { return layers_; }

  /// Forgets everything (map, layers and time origin).
  void reset();
  /// octomap_server's clear_bbx on the metric box [min_m, max_m]; returns voxels changed.
  std::size_t clearBox(const std::array<double, 3>& min_m, const std::array<double, 3>& max_m);

  void save(const std::string& path) const;
  /// Background-capable save: captures now, writes when the returned function runs (see VoxelMap).
  std::function<void()> prepareSave(const std::string& path) const;
  /// Replaces map and layers by the file's content; throws MapIoError and keeps the map on failure.
  void load(const std::string& path);

  /// Occupied voxels as integer cells (i, j, k) of size `resolution_m` (cell = [i*res, (i+1)*res) etc.), sorted
  /// and unique. res >= map resolution: the cell containing each occupied voxel's centre; finer: every cell
  /// whose centre lies in an occupied voxel.
  std::vector<std::array<int32_t, 3>> occupiedCells(double resolution_m) const;
  /// Writes occupiedCells() as a NumPy .npy (int32, shape (N, 3)) plus a JSON sidecar path + ".json";
  /// returns N. Throws MapIoError.
  std::size_t exportOccupied(const std::string& path, double resolution_m, const std::string& frame_id) const;

  VoxelMap& map() { return *map_; }
  const VoxelMap& map() const { return *map_; }
  /// Seconds added to the stored (float, relative) voxel times; NaN until the first insertion or load.
  double timeOrigin() const { return time_origin_s_; }
  std::size_t framesInserted() const { return frames_; }

 private:
  float relativeTime(double stamp_s);
  void applyFrame(float time_s, InsertStats& stats);

  MapperConfig config_;
  std::unique_ptr<VoxelMap> map_;
  FrameUpdateBuilder builder_;
  ColumnLayers layers_;
  FrameUpdate frame_;
  std::vector<uint8_t> transitions_;
  ColoredPoints filtered_;
  double time_origin_s_;
  std::size_t frames_ = 0;
};

/// Writes a little-endian NumPy .npy file holding an int32 array of shape (rows, 3); throws MapIoError.
void writeNpyInt32x3(const std::string& path, const std::vector<std::array<int32_t, 3>>& rows);

}  // namespace uav_mapping
