// The backend-independent voxel map interface (OctoMap octree or OpenVDB grids behind it).
#pragma once

#include <uav_mapping/frame_update.h>
#include <uav_mapping/keys.h>

#include <cstdint>
#include <functional>
#include <limits>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

namespace uav_mapping {

/// Failures of map file I/O (bad path, wrong format, corrupt file); the map is unchanged when thrown.
class MapIoError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// octomap_server's sensor model, as probabilities (sensor_model/{hit,miss,min,max}).
struct SensorModel {
  double hit = 0.7;
  double miss = 0.4;
  double clamp_min = 0.12;
  double clamp_max = 0.97;
  double occupancy_threshold = 0.5;
};

/// The same model in float log-odds, computed exactly as OctoMap does (octomap::logodds).
struct LogOddsModel {
  float hit;
  float miss;
  float clamp_min;
  float clamp_max;
  float occupied;  // a voxel is occupied iff log_odds >= occupied
  explicit LogOddsModel(const SensorModel& m);
};

/// Sentinel time of voxels whose observation time is unknown (loaded from a file without times).
constexpr float kNoTime = -std::numeric_limits<float>::infinity();

/// Per-update result flags written by VoxelMap::apply, parallel to FrameUpdate::updates.
enum TransitionBits : uint8_t { kWasKnown = 1, kWasOccupied = 2, kIsOccupied = 4 };

struct VoxelState {
  float log_odds = 0.0f;
  float time_s = kNoTime;  // relative to the map's time origin
  bool color_set = false;
  uint8_t r = 0, g = 0, b = 0;
};

/// A stored leaf: `size` voxels per axis starting at `key` (size > 1 for pruned octree nodes and VDB tiles).
struct Leaf {
  Key key;
  unsigned size = 1;
  VoxelState state;
};
using LeafVisitor = std::function<void(const Leaf&)>;

class VoxelMap {
 public:
  VoxelMap(double resolution_m, const SensorModel& model) : resolution_m_(resolution_m), model_(model), logodds_(model) {}
  virtual ~VoxelMap() = default;
  VoxelMap(const VoxelMap&) = delete;
  VoxelMap& operator=(const VoxelMap&) = delete;

  virtual std::string backendName() const = 0;
  /// File extensions save()/load() accept (with the dot).
  virtual std::vector<std::string> fileExtensions() const = 0;

  double resolution() const { return resolution_m_; }
  const SensorModel& sensorModel() const { return model_; }
  const LogOddsModel& logOdds() const { return logodds_; }
  bool isOccupied(float log_odds) const { return log_odds >= logodds_.occupied; }
  /// Weight of a new observation when blending voxel colours (1 = replace, 0.5 = OctoMap-like average).
  void setColorBlend(double weight) {
    const double w = weight < 0.0 ? 0.0 : (weight > 1.0 ? 1.0 : weight);
    color_weight_q8_ = static_cast<unsigned>(w * 256.0 + 0.5);
  }

  /// Applies one frame: each update adds hit or miss log-odds (clamped), stamps `time_s`, blends the hit
  /// colour; `transitions[i]` receives TransitionBits for updates[i].
  virtual void apply(const FrameUpdate& frame, float time_s, std::vector<uint8_t>& transitions) = 0;
  /// Removes everything.
  virtual void clear() = 0;
  /// Sets every known voxel inside the inclusive key box to free (clamping minimum), like octomap_server's
  /// clear_bbx; unknown voxels stay unknown. Returns the number of voxels changed.
  virtual std::size_t clearBox(const KeyBox& box) = 0;
  virtual void forEachLeaf(const LeafVisitor& visit, bool occupied_only) const = 0;
  virtual bool query(const Key& key, VoxelState& state) const = 0;
  /// Highest occupied key z in [kz_lo, kz_hi] of column (kx, ky), or -1.
  virtual int topOccupiedZ(uint16_t kx, uint16_t ky, int kz_hi, int kz_lo) const = 0;
  /// Stored leaves (pruned nodes / tiles count once) and the memory they use.
  virtual std::size_t leafCount() const = 0;
  virtual std::size_t memoryBytes() const = 0;
  /// Captures the map now and returns the file writing as a separate step (so that autosave can write in a
  /// background thread while insertion goes on). The step writes `path` atomically (temporary file + rename)
  /// and throws MapIoError. Throws MapIoError at once for an unsupported extension.
  virtual std::function<void()> prepareSave(const std::string& path, double time_origin_s) const = 0;
  /// Writes the map to `path` (format by extension); throws MapIoError.
  void save(const std::string& path, double time_origin_s) const { prepareSave(path, time_origin_s)(); }
  /// Replaces the map by the file's content; returns the file's time origin (NaN if it has none). Throws
  /// MapIoError and leaves the map unchanged on failure.
  virtual double load(const std::string& path) = 0;

 protected:
  double resolution_m_;
  SensorModel model_;
  LogOddsModel logodds_;
  unsigned color_weight_q8_ = 128;
};

enum class Backend { kOctomap, kOpenVdb };
std::string toString(Backend backend);
/// Parses "octomap" or "openvdb"; throws std::invalid_argument otherwise.
Backend backendFromString(const std::string& name);

std::unique_ptr<VoxelMap> makeVoxelMap(Backend backend, double resolution_m, const SensorModel& model);

/// Blends an observed colour into a stored one: weight_q8 / 256 of the observation (256 = replace).
inline uint8_t blendChannel(uint8_t stored, uint8_t observed, unsigned weight_q8) {
  return static_cast<uint8_t>((stored * (256U - weight_q8) + observed * weight_q8 + 128U) >> 8);
}

/// Writes bytes to path + ".tmp", then renames it to path; throws MapIoError.
void writeFileAtomically(const std::string& path, const std::string& bytes);

/// Lower-case file extension with the dot ("" if none).
std::string fileExtension(const std::string& path);

}  // namespace uav_mapping
