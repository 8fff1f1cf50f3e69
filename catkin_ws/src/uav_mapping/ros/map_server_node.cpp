// map_server: the roscpp node around uav_mapping::Mapper, a drop-in for octomap_server plus 2D layers.
//
// Subscribes   cloud_in (sensor_msgs/PointCloud2), transformed through tf to ~frame_id at the cloud's stamp;
//              or, with ~input rgbd, depth_in + color_in (sensor_msgs/Image) + camera_info_in
//              (sensor_msgs/CameraInfo) of one camera with equal stamps, back-projected here
// Publishes    octomap_binary, octomap_full (octomap_msgs/Octomap), occupied_cells_vis_array (MarkerArray),
//              projected_map (nav_msgs/OccupancyGrid), octomap_point_cloud_centers (PointCloud2),
//              ~layers (uav_msgs/GridLayers: elevation_m, last_seen_s, observed), ~insert_stats
//              (uav_msgs/MapInsertStats)
// Services     octomap_binary, octomap_full (octomap_msgs/GetOctomap), ~reset (std_srvs/Empty),
//              ~clear_bbx (octomap_msgs/BoundingBoxQuery), ~get_layers (uav_msgs/GetGridLayers),
//              ~save, ~load (uav_msgs/MapFile), ~export_occupied (uav_msgs/ExportVoxels)
// Parameters   see docs/map_server.md and config/map_server.yaml (unknown private parameters are errors)
//
// Threads: services and timers run in the main thread; incoming clouds are queued by their own spinner thread
// and inserted by a worker thread, so a slow insertion or a slow publish never stalls the others, and a full
// queue is counted, not silently lost.
//
// Causal lockstep (/lockstep/causal true, docs/lockstep.md and docs/map_server.md): the node is a participant
// (lockstep_participant.h). Its inputs (the frames, /tf, /tf_static) are counted and dispatched step by step in
// the main thread, which also inserts the frames whose transform is known, fires the layers and map timers in
// simulated time and applies service requests at step boundaries; there is no worker thread and no queue_full.
#include "lockstep_participant.h"
#include "ros_conversions.h"

#include <uav_mapping/depth_filter.h>
#include <uav_mapping/mapper.h>
#include <uav_mapping/octree_map.h>

#include <message_filters/subscriber.h>
#include <message_filters/time_synchronizer.h>
#include <octomap_msgs/BoundingBoxQuery.h>
#include <octomap_msgs/GetOctomap.h>
#include <ros/callback_queue.h>
#include <ros/ros.h>
#include <std_srvs/Empty.h>
#include <tf2_ros/buffer.h>
#include <tf2_ros/transform_listener.h>
#include <uav_msgs/ExportVoxels.h>
#include <uav_msgs/GetGridLayers.h>
#include <uav_msgs/MapFile.h>
#include <uav_msgs/MapInsertStats.h>

#include <sys/stat.h>

#include <atomic>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <cstdlib>
#include <deque>
#include <limits>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <set>
#include <string>
#include <thread>

namespace uav_mapping {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

/// Private parameters, read and validated once at start-up.
struct Params {
  MapperConfig mapper;
  std::string frame_id = "map";
  bool rgbd_input = false;  // ~input: cloud (cloud_in) | rgbd (depth_in, color_in, camera_info_in)
  bool rgbd_color = true;   // ~rgbd_color: also subscribe color_in (false: uncoloured points)
  bool latch = true;
  int queue_size = 5;
  double tf_wait_s = 0.5;
  std::size_t max_points = 4000000;
  double occupancy_min_z = -kInf;
  double occupancy_max_z = kInf;
  ros_conv::MarkerStyle markers;
  double map_publish_rate_hz = 1.0;  // 0: after every cloud (octomap_server's behaviour)
  double layers_rate_hz = 2.0;
  double layers_resolution_m = 0.0;  // 0: the map resolution
  double autosave_interval_s = 0.0;  // 0: off
  std::string autosave_path;
  bool autosave_resume = false;
};

/// Reads ~params, remembering every name it asked for so that unknown ones can be reported.
class ParamReader {
 public:
  explicit ParamReader(const ros::NodeHandle& pnh) : pnh_(pnh) {}

  template <class T>
  T get(const std::string& name, const T& def) {
    known_.insert(name);
    T value = def;
    if (pnh_.hasParam(name) && !pnh_.getParam(name, value))
      throw std::invalid_argument("parameter ~" + name + " has the wrong type");
    return value;
  }
  double getDouble(const std::string& name, double def) {  // accepts ints too
    known_.insert(name);
    XmlRpc::XmlRpcValue v;
    if (!pnh_.getParam(name, v)) return def;
    if (v.getType() == XmlRpc::XmlRpcValue::TypeDouble) return static_cast<double>(v);
    if (v.getType() == XmlRpc::XmlRpcValue::TypeInt) return static_cast<int>(v);
    throw std::invalid_argument("parameter ~" + name + " must be a number");
  }
  void accept(const std::string& name) { ignored_.insert(name); }

  /// Names under ~ that nobody asked for.
  std::vector<std::string> unknown() const {
    std::vector<std::string> all;
    ros::param::getParamNames(all);
    const std::string prefix = pnh_.getNamespace() + "/";
    std::vector<std::string> out;
    for (const std::string& full : all) {
      if (full.rfind(prefix, 0) != 0) continue;
      const std::string rel = full.substr(prefix.size());
      if (known_.count(rel) == 0 && ignored_.count(rel) == 0) out.push_back(rel);
    }
    return out;
  }
  std::vector<std::string> ignoredPresent() const {
    std::vector<std::string> out;
    for (const std::string& n : ignored_) {
      if (pnh_.hasParam(n)) out.push_back(n);
    }
    return out;
  }

 private:
  ros::NodeHandle pnh_;
  std::set<std::string> known_;
  std::set<std::string> ignored_;
};

std::string defaultAutosavePath(Backend backend) {
  const char* ros_home = std::getenv("ROS_HOME");
  const char* home = std::getenv("HOME");
  const std::string base = ros_home ? ros_home : (std::string(home ? home : "/tmp") + "/.ros");
  return base + "/map_server_autosave" + (backend == Backend::kOctomap ? ".ot" : ".vdb");
}

Params readParams(const ros::NodeHandle& pnh, std::vector<std::string>& warnings) {
  ParamReader r(pnh);
  Params p;
  MapperConfig& m = p.mapper;
  p.frame_id = r.get<std::string>("frame_id", "map");
  const std::string input = r.get<std::string>("input", "cloud");
  if (input != "cloud" && input != "rgbd")
    throw std::invalid_argument("input must be 'cloud' (cloud_in) or 'rgbd' (depth_in, color_in, camera_info_in), "
                                "got '" + input + "'");
  p.rgbd_input = input == "rgbd";
  p.rgbd_color = r.get<bool>("rgbd_color", true);
  m.resolution_m = r.getDouble("resolution", 0.05);
  m.backend = backendFromString(r.get<std::string>("backend", "octomap"));
  m.mode = insertModeFromString(r.get<std::string>("insert_mode", "full"));
  m.truncation_m = r.getDouble("truncation_m", 3.0);
  m.max_range_m = r.getDouble("sensor_model/max_range", -1.0);
  m.filter.min_range_m = r.getDouble("sensor_model/min_range", -1.0);
  m.sensor.hit = r.getDouble("sensor_model/hit", 0.7);
  m.sensor.miss = r.getDouble("sensor_model/miss", 0.4);
  m.sensor.clamp_min = r.getDouble("sensor_model/min", 0.12);
  m.sensor.clamp_max = r.getDouble("sensor_model/max", 0.97);
  m.filter.min_x_m = r.getDouble("pointcloud_min_x", -kInf);
  m.filter.max_x_m = r.getDouble("pointcloud_max_x", kInf);
  m.filter.min_y_m = r.getDouble("pointcloud_min_y", -kInf);
  m.filter.max_y_m = r.getDouble("pointcloud_max_y", kInf);
  m.filter.min_z_m = r.getDouble("pointcloud_min_z", -kInf);
  m.filter.max_z_m = r.getDouble("pointcloud_max_z", kInf);
  m.filter.voxel_leaf_m = r.getDouble("voxel_filter_leaf_m", 0.0);
  m.filter.voxel_impl = voxelFilterImplFromString(r.get<std::string>("voxel_filter", "fast"));
  m.threads = r.get<int>("threads", 2);
  m.prune = r.get<bool>("compress_map", true);
  m.color_blend = r.getDouble("color_blend", 0.5);
  p.latch = r.get<bool>("latch", true);
  p.queue_size = r.get<int>("queue_size", 5);
  p.tf_wait_s = r.getDouble("tf_wait_s", 0.5);
  p.max_points = static_cast<std::size_t>(r.get<int>("max_points", 4000000));
  p.occupancy_min_z = r.getDouble("occupancy_min_z", -kInf);
  p.occupancy_max_z = r.getDouble("occupancy_max_z", kInf);
  p.markers.height_map = r.get<bool>("height_map", true);
  p.markers.colored_map = r.get<bool>("colored_map", false);
  p.markers.color_factor = r.getDouble("color_factor", 0.8);
  p.markers.color.r = static_cast<float>(r.getDouble("color/r", 0.0));
  p.markers.color.g = static_cast<float>(r.getDouble("color/g", 0.0));
  p.markers.color.b = static_cast<float>(r.getDouble("color/b", 1.0));
  p.markers.color.a = static_cast<float>(r.getDouble("color/a", 1.0));
  p.map_publish_rate_hz = r.getDouble("map_publish_rate_hz", 1.0);
  p.layers_rate_hz = r.getDouble("layers/rate_hz", 2.0);
  p.layers_resolution_m = r.getDouble("layers/resolution_m", 0.0);
  p.autosave_interval_s = r.getDouble("autosave/interval_s", 0.0);
  p.autosave_path = r.get<std::string>("autosave/path", "");
  p.autosave_resume = r.get<bool>("autosave/resume", false);
  // octomap_server parameters without an effect here: accepted so that its launch files work unchanged.
  for (const char* name : {"base_frame_id", "filter_ground", "filter_speckles", "ground_filter/distance",
                           "ground_filter/angle", "ground_filter/plane_distance", "incremental_2D_projection",
                           "publish_free_space", "min_x_size", "min_y_size", "max_depth", "color_free/r",
                           "color_free/g", "color_free/b", "color_free/a"})
    r.accept(name);
  for (const std::string& n : r.ignoredPresent())
    warnings.push_back("~" + n + " is an octomap_server parameter without effect in this node; ignored");
  const auto unknown = r.unknown();
  if (!unknown.empty()) {
    std::string list;
    for (const auto& n : unknown) list += (list.empty() ? "~" : ", ~") + n;
    throw std::invalid_argument("unknown parameter(s) " + list + " (see docs/map_server.md)");
  }
  m.validate();
  auto require = [](bool ok, const std::string& what) {
    if (!ok) throw std::invalid_argument(what);
  };
  require(!p.frame_id.empty(), "frame_id must not be empty");
  require(p.queue_size >= 1, "queue_size must be >= 1");
  require(p.tf_wait_s >= 0.0, "tf_wait_s must be >= 0");
  require(p.max_points >= 1, "max_points must be >= 1");
  require(p.map_publish_rate_hz >= 0.0, "map_publish_rate_hz must be >= 0");
  require(p.layers_rate_hz > 0.0, "layers/rate_hz must be > 0");
  require(p.autosave_interval_s >= 0.0, "autosave/interval_s must be >= 0");
  require(p.layers_resolution_m >= 0.0, "layers/resolution_m must be >= 0");
  if (p.layers_resolution_m > 0.0) {
    const double f = p.layers_resolution_m / m.resolution_m;
    const double whole = std::max(1.0, std::round(f));
    if (std::fabs(f - whole) > 1e-6) {
      warnings.push_back("~layers/resolution_m " + std::to_string(p.layers_resolution_m) +
                         " is not a whole multiple of resolution; using " + std::to_string(whole * m.resolution_m));
    }
    p.layers_resolution_m = whole * m.resolution_m;
  }
  if (p.autosave_path.empty()) p.autosave_path = defaultAutosavePath(m.backend);
  return p;
}

double msBetween(std::chrono::steady_clock::time_point a, std::chrono::steady_clock::time_point b) {
  return std::chrono::duration<double, std::milli>(b - a).count();
}

class MapServerNode {
 public:
  MapServerNode(const ros::NodeHandle& nh, const ros::NodeHandle& pnh, const Params& params,
                const lockstep::Settings& lockstep)
      : nh_(nh),
        pnh_(pnh),
        p_(params),
        mapper_(params.mapper),
        lockstep_(lockstep),
        tf_listener_(lockstep_.causal() ? nullptr : std::make_unique<tf2_ros::TransformListener>(tf_buffer_)) {
    layers_factor_ = p_.layers_resolution_m > 0.0
                         ? static_cast<int>(std::lround(p_.layers_resolution_m / p_.mapper.resolution_m))
                         : 1;
    if (p_.autosave_resume) resume();
    // Without latch the map outputs go out when the map changed; a subscriber that connects after the last
    // change (e.g. a planner started late) gets the current map at the next publish tick.
    const ros::SubscriberStatusCallback on_connect = [this](const ros::SingleSubscriberPublisher&) {
      new_subscriber_ = true;
    };
    const ros::SubscriberStatusCallback none;
    // Counted by the lockstep (queue 0: never dropped) when causal; roscpp's own publishers otherwise.
    pub_binary_ = lockstep_.advertise<octomap_msgs::Octomap>(nh_, "octomap_binary", 1, p_.latch, on_connect);
    pub_full_ = lockstep_.advertise<octomap_msgs::Octomap>(nh_, "octomap_full", 1, p_.latch, on_connect);
    pub_markers_ =
        lockstep_.advertise<visualization_msgs::MarkerArray>(nh_, "occupied_cells_vis_array", 1, p_.latch, on_connect);
    pub_projected_ = lockstep_.advertise<nav_msgs::OccupancyGrid>(nh_, "projected_map", 5, p_.latch, on_connect);
    pub_centers_ =
        lockstep_.advertise<sensor_msgs::PointCloud2>(nh_, "octomap_point_cloud_centers", 1, p_.latch, on_connect);
    pub_layers_ = lockstep_.advertise<uav_msgs::GridLayers>(pnh_, "layers", 1, true);
    pub_stats_ = lockstep_.advertise<uav_msgs::MapInsertStats>(pnh_, "insert_stats", 50);
    // Applied at once, or at step boundaries when causal (the service thread waits for the step thread).
    srv_binary_ = advertiseService<octomap_msgs::GetOctomap>(nh_, "octomap_binary", &MapServerNode::onGetBinary);
    srv_full_ = advertiseService<octomap_msgs::GetOctomap>(nh_, "octomap_full", &MapServerNode::onGetFull);
    srv_reset_ = advertiseService<std_srvs::Empty>(pnh_, "reset", &MapServerNode::onReset);
    srv_clear_ = advertiseService<octomap_msgs::BoundingBoxQuery>(pnh_, "clear_bbx", &MapServerNode::onClearBbx);
    srv_layers_ = advertiseService<uav_msgs::GetGridLayers>(pnh_, "get_layers", &MapServerNode::onGetLayers);
    srv_save_ = advertiseService<uav_msgs::MapFile>(pnh_, "save", &MapServerNode::onSave);
    srv_load_ = advertiseService<uav_msgs::MapFile>(pnh_, "load", &MapServerNode::onLoad);
    srv_export_ = advertiseService<uav_msgs::ExportVoxels>(pnh_, "export_occupied", &MapServerNode::onExport);
    if (lockstep_.causal()) {
      // Simulated time, fired from the step (the timers of docs/lockstep.md).
      lockstep_.timer(1.0 / p_.layers_rate_hz, [this](double) { publishLayers(); }, "layers");
      if (p_.map_publish_rate_hz > 0.0)
        lockstep_.timer(1.0 / p_.map_publish_rate_hz, [this](double) { mapTick(false); }, "map");
    } else {
      timer_layers_ = nh_.createTimer(ros::Duration(1.0 / p_.layers_rate_hz), &MapServerNode::onLayersTimer, this);
      if (p_.map_publish_rate_hz > 0.0)
        timer_map_ =
            nh_.createWallTimer(ros::WallDuration(1.0 / p_.map_publish_rate_hz), &MapServerNode::onMapTimer, this);
    }
    // Autosave stays on the wall clock in every mode: it writes a file, nobody's input.
    if (p_.autosave_interval_s > 0.0)
      timer_autosave_ =
          nh_.createWallTimer(ros::WallDuration(p_.autosave_interval_s), &MapServerNode::onAutosaveTimer, this);
    if (lockstep_.causal()) {
      subscribeLockstepInputs();
      return;
    }
    worker_ = std::thread(&MapServerNode::workerLoop, this);
    // Clouds have their own callback queue and spinner thread: queueing a cloud never waits behind a timer or a
    // service of the main thread (e.g. building markers of a large map), so drops are counted, not silent.
    std::string inputs;
    if (p_.rgbd_input) {
      // Depth, colour and camera info of one frame carry one stamp (exact synchronisation). roscpp drops the
      // oldest message of a full subscription queue without a word, and a frame that lost one part then never
      // completes: the queues are deep enough for the spinner to fall behind by a second of 10 Hz frames (our own
      // queue_size decides, and counts, what insertion cannot keep up with), and a frame the synchroniser gives
      // up on is counted as `unsynchronized`.
      const ros::TransportHints hints;
      constexpr uint32_t kTopicQueue = 10;
      constexpr uint32_t kSyncQueue = 10;
      sub_depth_.subscribe(nh_, "depth_in", kTopicQueue, hints, &cloud_queue_);
      sub_info_.subscribe(nh_, "camera_info_in", kTopicQueue, hints, &cloud_queue_);
      if (p_.rgbd_color) {
        sub_color_.subscribe(nh_, "color_in", kTopicQueue, hints, &cloud_queue_);
        sync_rgbd_ = std::make_unique<RgbdSync>(sub_depth_, sub_color_, sub_info_, kSyncQueue);
      } else {
        sync_depth_ = std::make_unique<DepthSync>(sub_depth_, sub_info_, kSyncQueue);
      }
      connectSynchronizer();
      inputs = "depth_in " + sub_depth_.getTopic() + (p_.rgbd_color ? ", color_in " + sub_color_.getTopic() : "") +
               ", camera_info_in " + sub_info_.getTopic();
    } else {
      ros::SubscribeOptions opts = ros::SubscribeOptions::create<sensor_msgs::PointCloud2>(
          "cloud_in", 2, boost::bind(&MapServerNode::onCloud, this, boost::placeholders::_1), ros::VoidPtr(),
          &cloud_queue_);
      sub_cloud_ = nh_.subscribe(opts);
      inputs = "cloud_in " + sub_cloud_.getTopic();
    }
    cloud_spinner_ = std::make_unique<ros::AsyncSpinner>(1, &cloud_queue_);
    cloud_spinner_->start();
    logStart(inputs);
  }

  ~MapServerNode() {
    lockstep_.shutdown();
    if (cloud_spinner_) cloud_spinner_->stop();
    sub_cloud_.shutdown();
    sub_depth_.unsubscribe();
    sub_color_.unsubscribe();
    sub_info_.unsubscribe();
    {
      std::lock_guard<std::mutex> lock(queue_mutex_);
      stop_ = true;
    }
    queue_cv_.notify_all();
    if (worker_.joinable()) worker_.join();
    if (autosave_thread_.joinable()) autosave_thread_.join();
  }

  /// ros::spin(), or the causal lockstep's step loop (throws lockstep::LockstepError).
  void spin() { lockstep_.spin(); }

 private:
  void logStart(const std::string& inputs) const {
    std::string mode;
    if (lockstep_.causal())
      mode = " (causal lockstep, lookahead " + std::to_string(lockstep_.settings().lookahead_steps) + " steps)";
    ROS_INFO_STREAM("map_server: backend " << toString(p_.mapper.backend) << ", " << p_.mapper.resolution_m
                                           << " m, insert_mode " << toString(p_.mapper.mode) << ", " << inputs
                                           << " -> frame " << p_.frame_id << mode);
  }

  template <class Srv>
  ros::ServiceServer advertiseService(ros::NodeHandle& nh, const std::string& name,
                                      bool (MapServerNode::*handler)(typename Srv::Request&, typename Srv::Response&)) {
    using Req = typename Srv::Request;
    using Res = typename Srv::Response;
    return lockstep_.advertiseService<Req, Res>(nh, name,
                                                [this, handler](Req& req, Res& res) { return (this->*handler)(req, res); });
  }

  /// The synchroniser's outputs: complete frames, and frames it gave up on.
  void connectSynchronizer() {
    if (sync_rgbd_) {
      sync_rgbd_->registerCallback(boost::bind(&MapServerNode::onRgbd, this, boost::placeholders::_1,
                                               boost::placeholders::_2, boost::placeholders::_3));
      sync_rgbd_->registerDropCallback(boost::bind(&MapServerNode::onUnsynchronized, this, boost::placeholders::_1,
                                                   boost::placeholders::_2, boost::placeholders::_3));
    } else {
      sync_depth_->registerCallback(boost::bind(&MapServerNode::onRgbd, this, boost::placeholders::_1,
                                                sensor_msgs::ImageConstPtr(), boost::placeholders::_2));
      sync_depth_->registerDropCallback(boost::bind(&MapServerNode::onUnsynchronized, this, boost::placeholders::_1,
                                                    sensor_msgs::ImageConstPtr(), boost::placeholders::_2));
    }
  }

  /// Causal lockstep: the frames and tf are counted inputs, dispatched in the step thread in the fixed order
  /// (/tf_static, /tf, then the frames' topics as declared); depth, colour and camera info go through the
  /// synchroniser in that order. Frames wait in pending_ for insertPending(), the step hook.
  void subscribeLockstepInputs() {
    std::string inputs;
    if (p_.rgbd_input) {
      constexpr uint32_t kSyncQueue = 10;
      if (p_.rgbd_color) {
        sync_rgbd_ = std::make_unique<RgbdSync>(kSyncQueue);
        lockstep_.subscribe<sensor_msgs::Image>(nh_, "depth_in",
                                                [this](const sensor_msgs::ImageConstPtr& m) { sync_rgbd_->add0(m); });
        lockstep_.subscribe<sensor_msgs::Image>(nh_, "color_in",
                                                [this](const sensor_msgs::ImageConstPtr& m) { sync_rgbd_->add1(m); });
        lockstep_.subscribe<sensor_msgs::CameraInfo>(
            nh_, "camera_info_in", [this](const sensor_msgs::CameraInfoConstPtr& m) { sync_rgbd_->add2(m); });
      } else {
        sync_depth_ = std::make_unique<DepthSync>(kSyncQueue);
        lockstep_.subscribe<sensor_msgs::Image>(nh_, "depth_in",
                                                [this](const sensor_msgs::ImageConstPtr& m) { sync_depth_->add0(m); });
        lockstep_.subscribe<sensor_msgs::CameraInfo>(
            nh_, "camera_info_in", [this](const sensor_msgs::CameraInfoConstPtr& m) { sync_depth_->add1(m); });
      }
      connectSynchronizer();
      inputs = "depth_in " + nh_.resolveName("depth_in") +
               (p_.rgbd_color ? ", color_in " + nh_.resolveName("color_in") : "") + ", camera_info_in " +
               nh_.resolveName("camera_info_in");
    } else {
      lockstep_.subscribe<sensor_msgs::PointCloud2>(
          nh_, "cloud_in", [this](const sensor_msgs::PointCloud2ConstPtr& m) { onCloud(m); });
      inputs = "cloud_in " + nh_.resolveName("cloud_in");
    }
    lockstep_.feedTf(tf_buffer_);
    lockstep_.onStep([this](uint64_t, double) { insertPending(); });
    logStart(inputs);
  }

  /// One sensor frame waiting for its transform and insertion: a cloud, or a depth image (+ colour) and its
  /// camera info.
  struct Pending {
    uint64_t id = 0;
    std_msgs::Header header;
    sensor_msgs::PointCloud2ConstPtr cloud;
    sensor_msgs::ImageConstPtr depth;
    sensor_msgs::ImageConstPtr color;
    sensor_msgs::CameraInfoConstPtr info;
    std::chrono::steady_clock::time_point received;

    uint32_t points() const {
      if (cloud) return cloud->width * cloud->height;
      return depth ? depth->width * depth->height : 0;
    }
  };
  using RgbdSync = message_filters::TimeSynchronizer<sensor_msgs::Image, sensor_msgs::Image, sensor_msgs::CameraInfo>;
  using DepthSync = message_filters::TimeSynchronizer<sensor_msgs::Image, sensor_msgs::CameraInfo>;
  struct Totals {
    uint64_t inserted = 0, empty = 0, bad_layout = 0, too_large = 0, no_transform = 0, queue_full = 0;
    uint64_t unsynchronized = 0;
    uint64_t nonfinite = 0;
  };

  // ---------------------------------------------------------------------------------------------- clouds

  void onCloud(const sensor_msgs::PointCloud2ConstPtr& msg) {
    Pending item;
    item.header = msg->header;
    item.cloud = msg;
    enqueue(std::move(item));
  }

  void onRgbd(const sensor_msgs::ImageConstPtr& depth, const sensor_msgs::ImageConstPtr& color,
              const sensor_msgs::CameraInfoConstPtr& info) {
    Pending item;
    item.header = depth->header;
    item.depth = depth;
    item.color = color;
    item.info = info;
    enqueue(std::move(item));
  }

  /// A frame the synchroniser gave up on: some of its depth, colour and camera info never arrived (or came after
  /// a newer frame had been synchronised).
  void onUnsynchronized(const sensor_msgs::ImageConstPtr& depth, const sensor_msgs::ImageConstPtr& color,
                        const sensor_msgs::CameraInfoConstPtr& info) {
    Pending item;
    item.header = depth ? depth->header : color ? color->header : info ? info->header : std_msgs::Header();
    item.depth = depth;
    std::string missing;
    if (!depth) missing += " depth_in";
    if (p_.rgbd_color && !color) missing += " color_in";
    if (!info) missing += " camera_info_in";
    drop(item, "unsynchronized",
         "no" + missing + " with the stamp " + std::to_string(item.header.stamp.toSec()) +
             " (the publisher or this node's subscription lost it; the frame is incomplete)",
         0.0);
  }

  void enqueue(Pending item) {
    item.received = std::chrono::steady_clock::now();
    if (lockstep_.causal()) {  // the step thread; insertPending() takes it on from here
      item.id = ++next_id_;
      pending_.push_back(std::move(item));
      return;
    }
    std::unique_lock<std::mutex> lock(queue_mutex_);
    item.id = ++next_id_;
    if (queue_.size() >= static_cast<std::size_t>(p_.queue_size)) {
      Pending old = queue_.front();
      queue_.pop_front();
      lock.unlock();
      drop(old, "queue_full", "insertion is slower than the cloud rate; oldest cloud dropped", 0.0);
      lock.lock();
    }
    queue_.push_back(std::move(item));
    lock.unlock();
    queue_cv_.notify_one();
  }

  void workerLoop() {
    while (true) {
      Pending item;
      {
        std::unique_lock<std::mutex> lock(queue_mutex_);
        queue_cv_.wait(lock, [this] { return stop_ || !queue_.empty(); });
        if (stop_) return;
        item = queue_.front();
      }
      // Wait for the transform (clouds are processed in arrival order).
      const std::string& source = item.header.frame_id;
      geometry_msgs::TransformStamped tf;
      std::string error;
      bool have_tf = false;
      if (source.empty()) {
        error = "the cloud has an empty frame_id";
      } else {
        while (true) {
          if (tf_buffer_.canTransform(p_.frame_id, source, item.header.stamp, &error)) {
            try {
              tf = tf_buffer_.lookupTransform(p_.frame_id, source, item.header.stamp);
              have_tf = true;
            } catch (const tf2::TransformException& e) {
              error = e.what();
            }
            break;
          }
          if (msBetween(item.received, std::chrono::steady_clock::now()) > 1000.0 * p_.tf_wait_s) break;
          std::unique_lock<std::mutex> lock(queue_mutex_);
          queue_cv_.wait_for(lock, std::chrono::milliseconds(5), [this] { return stop_; });
          if (stop_) return;
        }
      }
      {
        std::lock_guard<std::mutex> lock(queue_mutex_);
        // The item may have been pushed out by onCloud meanwhile (then it was already counted as queue_full).
        if (queue_.empty() || queue_.front().id != item.id) continue;
        queue_.pop_front();
      }
      const double wait_ms = msBetween(item.received, std::chrono::steady_clock::now());
      if (!have_tf) {
        drop(item, "no_transform",
             "no transform " + p_.frame_id + " <- '" + source + "' at the cloud's stamp: " + error, wait_ms);
        continue;
      }
      insert(item, tf, wait_ms);
    }
  }

  /// Causal lockstep, once a step after its inputs and timers: insert the pending frames from the head while the
  /// transform at the frame's stamp is known. A head frame whose transform is not known yet waits for a later
  /// step, unless the step's time is more than tf_wait_s past its stamp (simulated time): then it is dropped
  /// (no_transform). Every decision is a function of the step, the same in every run.
  void insertPending() {
    const ros::Time now = lockstep_.now();
    const ros::Duration budget(p_.tf_wait_s);
    while (!pending_.empty()) {
      const Pending& head = pending_.front();
      const std::string source = head.header.frame_id;
      geometry_msgs::TransformStamped tf;
      std::string error;
      bool have_tf = false;
      if (source.empty()) {
        error = "the cloud has an empty frame_id";
      } else if (tf_buffer_.canTransform(p_.frame_id, source, head.header.stamp, &error)) {
        try {
          tf = tf_buffer_.lookupTransform(p_.frame_id, source, head.header.stamp);
          have_tf = true;
        } catch (const tf2::TransformException& e) {
          error = e.what();
        }
      } else if (now - head.header.stamp <= budget) {
        return;  // its transform may still come: this frame and those behind it wait for a later step
      }
      const Pending item = std::move(pending_.front());
      pending_.pop_front();
      const double wait_ms = msBetween(item.received, std::chrono::steady_clock::now());
      if (!have_tf) {
        drop(item, "no_transform",
             "no transform " + p_.frame_id + " <- '" + source + "' at the cloud's stamp within tf_wait_s (" +
                 std::to_string(p_.tf_wait_s) + " s of simulated time): " + error,
             wait_ms);
        continue;
      }
      insert(item, tf, wait_ms);
    }
  }

  void insert(const Pending& item, const geometry_msgs::TransformStamped& tf, double wait_ms) {
    std::string detail;
    const RigidTransform map_from_sensor = ros_conv::fromMsg(tf);
    const std_msgs::Header& hdr = item.header;
    InsertStats st;
    if (item.cloud) {
      const ros_conv::CloudError err = ros_conv::parseCloud(*item.cloud, p_.max_points, sensor_points_, detail);
      if (err != ros_conv::CloudError::kNone) {
        drop(item, ros_conv::toString(err), detail, wait_ms);
        return;
      }
      std::lock_guard<std::mutex> lock(map_mutex_);
      st = mapper_.insert(sensor_points_, map_from_sensor, hdr.stamp.toSec());
      markChanged();
    } else {
      // Depth images take the fused front end (back-projection, transform, filters and voxel grid in one pass
      // over the pixels; the same points as the cloud path would get), outside the map lock: it needs no map.
      ros_conv::DepthInput in;
      const ros_conv::CloudError err =
          ros_conv::depthImageViews(*item.depth, item.color.get(), *item.info, p_.max_points, in, detail);
      if (err != ros_conv::CloudError::kNone) {
        drop(item, ros_conv::toString(err), detail, wait_ms);
        return;
      }
      FilterStats filter;
      const auto t0 = std::chrono::steady_clock::now();
      filterDepthImage(in.depth, in.color, in.k, map_from_sensor, mapper_.config().filter, map_points_, filter);
      const double filter_ms = msBetween(t0, std::chrono::steady_clock::now());
      if (filter.points_in == 0) {
        drop(item, ros_conv::toString(ros_conv::CloudError::kEmpty), "no pixel with a valid depth", wait_ms);
        return;
      }
      std::lock_guard<std::mutex> lock(map_mutex_);
      st = mapper_.insertFiltered(map_points_, filter, filter_ms, map_from_sensor.origin(), hdr.stamp.toSec());
      markChanged();
    }
    if (st.filter.nonfinite > 0 && shouldWarn("nonfinite"))
      ROS_WARN("map_server: dropped %zu non-finite points of a cloud from '%s'", st.filter.nonfinite,
               hdr.frame_id.c_str());
    if (st.points_out_of_map > 0 && shouldWarn("out_of_map"))
      ROS_WARN("map_server: %zu points of a cloud from '%s' lie outside the map's addressable cube",
               st.points_out_of_map, hdr.frame_id.c_str());
    if (st.points_inserted == 0 && shouldWarn("no_points"))
      ROS_WARN("map_server: a cloud from '%s' had no usable point after filtering", hdr.frame_id.c_str());
    uav_msgs::MapInsertStats s;
    {
      std::lock_guard<std::mutex> lock(stats_mutex_);
      ++totals_.inserted;
      totals_.nonfinite += st.filter.nonfinite;
      fillStats(s, hdr);
    }
    s.inserted = true;
    s.points_in = static_cast<uint32_t>(st.filter.points_in);
    s.points_nonfinite = static_cast<uint32_t>(st.filter.nonfinite);
    s.points_filtered = static_cast<uint32_t>(st.filter.too_close + st.filter.outside_box);
    s.points_inserted = static_cast<uint32_t>(st.points_inserted);
    s.points_out_of_map = static_cast<uint32_t>(st.points_out_of_map);
    s.hits = static_cast<uint32_t>(st.hits);
    s.misses = static_cast<uint32_t>(st.misses);
    s.wait_ms = wait_ms;
    s.filter_ms = st.filter_ms;
    s.raycast_ms = st.raycast_ms;
    s.update_ms = st.update_ms;
    s.layers_ms = st.layers_ms;
    s.total_ms = st.total_ms;
    pub_stats_.publish(s);
    if (p_.map_publish_rate_hz == 0.0) publishMapOutputs();
  }

  void drop(const Pending& item, const std::string& reason, const std::string& detail, double wait_ms) {
    uav_msgs::MapInsertStats s;
    {
      std::lock_guard<std::mutex> lock(stats_mutex_);
      if (reason == "empty") ++totals_.empty;
      if (reason == "bad_layout") ++totals_.bad_layout;
      if (reason == "too_large") ++totals_.too_large;
      if (reason == "no_transform") ++totals_.no_transform;
      if (reason == "queue_full") ++totals_.queue_full;
      if (reason == "unsynchronized") ++totals_.unsynchronized;
      fillStats(s, item.header);
    }
    s.inserted = false;
    s.drop_reason = reason;
    s.points_in = item.points();
    s.wait_ms = wait_ms;
    pub_stats_.publish(s);
    if (shouldWarn("drop_" + reason))
      ROS_WARN("map_server: dropped a cloud (%s): %s", reason.c_str(), detail.c_str());
  }

  /// Throttles warnings per kind (one every kWarnPeriodS), unlike ROS_WARN_THROTTLE's per call site.
  bool shouldWarn(const std::string& kind) {
    std::lock_guard<std::mutex> lock(warn_mutex_);
    const auto now = std::chrono::steady_clock::now();
    auto it = last_warn_.find(kind);
    if (it != last_warn_.end() && msBetween(it->second, now) < 1000.0 * kWarnPeriodS) return false;
    last_warn_[kind] = now;
    return true;
  }

  /// Header, backend, mode and totals; call with stats_mutex_ held.
  void fillStats(uav_msgs::MapInsertStats& s, const std_msgs::Header& hdr) {
    s.header.stamp = hdr.stamp;
    s.header.frame_id = p_.frame_id;
    s.backend = toString(p_.mapper.backend);
    s.mode = toString(p_.mapper.mode);
    s.clouds_inserted = totals_.inserted;
    s.clouds_dropped_empty = totals_.empty;
    s.clouds_dropped_bad_layout = totals_.bad_layout;
    s.clouds_dropped_too_large = totals_.too_large;
    s.clouds_dropped_no_transform = totals_.no_transform;
    s.clouds_dropped_queue_full = totals_.queue_full;
    s.clouds_dropped_unsynchronized = totals_.unsynchronized;
    s.points_nonfinite_total = totals_.nonfinite;
    s.map_leaves = map_leaves_.load();
    s.map_memory_bytes = map_memory_.load();
  }

  // ---------------------------------------------------------------------------------------------- outputs

  void onLayersTimer(const ros::TimerEvent&) { publishLayers(); }

  /// The layers, when the map changed since they were last published.
  void publishLayers() {
    LayersSnapshot snap;
    {
      std::lock_guard<std::mutex> lock(map_mutex_);
      if (!layers_changed_) return;
      layers_changed_ = false;
      snap = mapper_.layers(layers_factor_);
    }
    pub_layers_.publish(ros_conv::layersToMsg(snap, p_.frame_id, lockstep_.now()));
  }

  void onMapTimer(const ros::WallTimerEvent&) { mapTick(true); }

  /// The map outputs, when the map changed; `late_subscribers`: also when an output got a subscriber since the
  /// last publish (latch off). Not in the causal lockstep: when a subscriber connects depends on timing, and what
  /// a participant publishes must not.
  void mapTick(bool late_subscribers) {
    bool changed;
    {
      std::lock_guard<std::mutex> lock(map_mutex_);
      changed = map_changed_;
    }
    // A late subscriber (latch off): resend the current map once something has been published.
    const bool late_subscriber = late_subscribers && !p_.latch && published_once_ && new_subscriber_.exchange(false);
    if (changed || late_subscriber) publishMapOutputs();
  }

  /// The octree to serialise: the map itself (octomap backend) or a conversion of the VDB grids.
  const UavOcTree& octreeFor(std::unique_ptr<UavOcTree>& converted) {
    if (const auto* octree = dynamic_cast<const OctreeMap*>(&mapper_.map())) return octree->tree();
    converted = std::make_unique<UavOcTree>(p_.mapper.resolution_m);
    copyLeavesToTree(mapper_.map(), *converted);
    return *converted;
  }

  void publishMapOutputs() {
    const ros::Time stamp = lockstep_.now();
    const bool all = p_.latch;
    const bool want_binary = all || pub_binary_.getNumSubscribers() > 0;
    const bool want_full = all || pub_full_.getNumSubscribers() > 0;
    const bool want_markers = all || pub_markers_.getNumSubscribers() > 0;
    const bool want_projected = all || pub_projected_.getNumSubscribers() > 0;
    const bool want_centers = all || pub_centers_.getNumSubscribers() > 0;
    octomap_msgs::Octomap binary;
    octomap_msgs::Octomap full;
    visualization_msgs::MarkerArray markers;
    nav_msgs::OccupancyGrid projected;
    sensor_msgs::PointCloud2 centers;
    published_once_ = true;
    new_subscriber_ = false;  // this publish reaches every current subscriber
    {
      std::lock_guard<std::mutex> lock(map_mutex_);
      map_changed_ = false;
      // Counting leaves walks the whole map: refresh these statistics at most every few seconds (of simulated
      // time in the causal lockstep, so that insert_stats read the same in every run).
      const auto now = std::chrono::steady_clock::now();
      const bool refresh = lockstep_.causal() ? !size_stats_stamp_ || stamp - *size_stats_stamp_ >= ros::Duration(5.0)
                                              : msBetween(size_stats_at_, now) > 5000.0;
      if (refresh) {
        map_leaves_ = mapper_.map().leafCount();
        map_memory_ = mapper_.map().memoryBytes();
        size_stats_at_ = now;
        size_stats_stamp_ = stamp;
      }
      if (want_binary || want_full) {
        std::unique_ptr<UavOcTree> converted;
        const UavOcTree& tree = octreeFor(converted);
        if (want_binary) binary = ros_conv::octomapToMsg(tree, true, p_.frame_id, stamp);
        if (want_full) full = ros_conv::octomapToMsg(tree, false, p_.frame_id, stamp);
      }
      if (want_markers) markers = ros_conv::occupiedMarkers(mapper_.map(), p_.markers, p_.frame_id, stamp);
      if (want_projected)
        projected = ros_conv::projectedMap(mapper_.map(), mapper_.columnLayers(), p_.occupancy_min_z,
                                           p_.occupancy_max_z, p_.frame_id, stamp);
      if (want_centers) centers = ros_conv::occupiedCenters(mapper_.map(), p_.frame_id, stamp);
    }
    if (want_binary) pub_binary_.publish(binary);
    if (want_full) pub_full_.publish(full);
    if (want_markers) pub_markers_.publish(markers);
    if (want_projected) pub_projected_.publish(projected);
    if (want_centers) pub_centers_.publish(centers);
  }

  /// Call with map_mutex_ held after any change of the map.
  void markChanged() {
    map_changed_ = true;
    layers_changed_ = true;
    ++map_version_;
  }

  // ---------------------------------------------------------------------------------------------- services

  bool onGetBinary(octomap_msgs::GetOctomap::Request&, octomap_msgs::GetOctomap::Response& res) {
    std::lock_guard<std::mutex> lock(map_mutex_);
    std::unique_ptr<UavOcTree> converted;
    res.map = ros_conv::octomapToMsg(octreeFor(converted), true, p_.frame_id, lockstep_.now());
    return true;
  }

  bool onGetFull(octomap_msgs::GetOctomap::Request&, octomap_msgs::GetOctomap::Response& res) {
    std::lock_guard<std::mutex> lock(map_mutex_);
    std::unique_ptr<UavOcTree> converted;
    res.map = ros_conv::octomapToMsg(octreeFor(converted), false, p_.frame_id, lockstep_.now());
    return true;
  }

  bool onReset(std_srvs::Empty::Request&, std_srvs::Empty::Response&) {
    {
      std::lock_guard<std::mutex> lock(map_mutex_);
      mapper_.reset();
      markChanged();
    }
    ROS_INFO("map_server: map reset");
    publishMapOutputs();
    return true;
  }

  bool onClearBbx(octomap_msgs::BoundingBoxQuery::Request& req, octomap_msgs::BoundingBoxQuery::Response&) {
    std::size_t changed;
    {
      std::lock_guard<std::mutex> lock(map_mutex_);
      changed = mapper_.clearBox({req.min.x, req.min.y, req.min.z}, {req.max.x, req.max.y, req.max.z});
      markChanged();
    }
    ROS_INFO("map_server: clear_bbx set %zu voxels free", changed);
    publishMapOutputs();
    return true;
  }

  bool onGetLayers(uav_msgs::GetGridLayers::Request&, uav_msgs::GetGridLayers::Response& res) {
    LayersSnapshot snap;
    {
      std::lock_guard<std::mutex> lock(map_mutex_);
      snap = mapper_.layers(layers_factor_);
    }
    res.layers = ros_conv::layersToMsg(snap, p_.frame_id, lockstep_.now());
    return true;
  }

  bool onSave(uav_msgs::MapFile::Request& req, uav_msgs::MapFile::Response& res) {
    res.path = req.path.empty() ? p_.autosave_path : req.path;
    try {
      std::function<void()> write;
      {
        std::lock_guard<std::mutex> lock(map_mutex_);
        write = mapper_.prepareSave(res.path);
      }
      write();
      res.success = true;
      res.message = "saved";
      ROS_INFO("map_server: saved the map to %s", res.path.c_str());
    } catch (const std::exception& e) {
      res.success = false;
      res.message = e.what();
      ROS_ERROR("map_server: save failed: %s", e.what());
    }
    return true;
  }

  bool onLoad(uav_msgs::MapFile::Request& req, uav_msgs::MapFile::Response& res) {
    res.path = req.path.empty() ? p_.autosave_path : req.path;
    try {
      {
        std::lock_guard<std::mutex> lock(map_mutex_);
        mapper_.load(res.path);
        markChanged();
      }
      res.success = true;
      res.message = "loaded";
      ROS_INFO("map_server: loaded the map from %s", res.path.c_str());
      publishMapOutputs();
    } catch (const std::exception& e) {
      res.success = false;
      res.message = e.what();
      ROS_ERROR("map_server: load failed (map unchanged): %s", e.what());
    }
    return true;
  }

  bool onExport(uav_msgs::ExportVoxels::Request& req, uav_msgs::ExportVoxels::Response& res) {
    res.resolution_m = req.resolution_m > 0.0 ? req.resolution_m : p_.mapper.resolution_m;
    try {
      if (req.path.empty()) throw std::invalid_argument("path must not be empty");
      std::lock_guard<std::mutex> lock(map_mutex_);
      res.count = mapper_.exportOccupied(req.path, res.resolution_m, p_.frame_id);
      res.success = true;
      res.message = "exported";
    } catch (const std::exception& e) {
      res.success = false;
      res.message = e.what();
      ROS_ERROR("map_server: export failed: %s", e.what());
    }
    return true;
  }

  // ---------------------------------------------------------------------------------------------- persistence

  void onAutosaveTimer(const ros::WallTimerEvent&) {
    if (autosave_busy_) {
      ROS_WARN_THROTTLE(60.0, "map_server: previous autosave still writing; skipping this one");
      return;
    }
    std::function<void()> write;
    {
      std::lock_guard<std::mutex> lock(map_mutex_);
      if (map_version_ == autosaved_version_) return;  // nothing new since the last autosave
      try {
        write = mapper_.prepareSave(p_.autosave_path);
      } catch (const std::exception& e) {
        ROS_ERROR_THROTTLE(60.0, "map_server: autosave failed: %s", e.what());
        return;
      }
      autosaved_version_ = map_version_;
    }
    if (autosave_thread_.joinable()) autosave_thread_.join();
    autosave_busy_ = true;
    const std::string path = p_.autosave_path;
    autosave_thread_ = std::thread([this, write, path] {
      try {
        ensureParentDir(path);
        write();
        ROS_DEBUG("map_server: autosaved to %s", path.c_str());
      } catch (const std::exception& e) {
        ROS_ERROR("map_server: autosave to %s failed: %s", path.c_str(), e.what());
      }
      autosave_busy_ = false;
    });
  }

  static void ensureParentDir(const std::string& path) {
    const auto slash = path.find_last_of('/');
    if (slash == std::string::npos || slash == 0) return;
    const std::string dir = path.substr(0, slash);
    std::string partial;
    for (std::size_t i = 0; i <= dir.size(); ++i) {
      if (i == dir.size() || dir[i] == '/') {
        if (!partial.empty()) ::mkdir(partial.c_str(), 0755);
      }
      if (i < dir.size()) partial.push_back(dir[i]);
    }
  }

  void resume() {
    struct stat st;
    if (::stat(p_.autosave_path.c_str(), &st) != 0) {
      ROS_WARN("map_server: autosave/resume is set but %s does not exist; starting with an empty map",
               p_.autosave_path.c_str());
      return;
    }
    try {
      mapper_.load(p_.autosave_path);
      markChanged();
      autosaved_version_ = map_version_;  // the file already holds this map
      ROS_INFO("map_server: resumed from the autosave %s (%zu leaves)", p_.autosave_path.c_str(),
               mapper_.map().leafCount());
    } catch (const std::exception& e) {
      ROS_ERROR("map_server: cannot resume from %s (%s); starting with an empty map", p_.autosave_path.c_str(),
                e.what());
    }
  }

  ros::NodeHandle nh_;
  ros::NodeHandle pnh_;
  Params p_;
  Mapper mapper_;
  int layers_factor_ = 1;
  lockstep::Participant lockstep_;  // before everything it counts or dispatches to
  tf2_ros::Buffer tf_buffer_;       // causal: fed by the dispatched /tf and /tf_static, no listener
  std::unique_ptr<tf2_ros::TransformListener> tf_listener_;
  std::deque<Pending> pending_;  // causal: frames waiting for their transform (step thread only)

  std::atomic<bool> new_subscriber_{false};  // a map output got a subscriber since the last publish
  std::atomic<bool> published_once_{false};
  std::mutex map_mutex_;  // guards mapper_ and the *_changed_ flags
  bool map_changed_ = true;
  bool layers_changed_ = true;
  uint64_t map_version_ = 0;        // bumped by every change of the map
  uint64_t autosaved_version_ = 0;  // the version the last autosave captured
  std::atomic<bool> autosave_busy_{false};
  std::thread autosave_thread_;

  std::mutex queue_mutex_;
  std::condition_variable queue_cv_;
  std::deque<Pending> queue_;
  uint64_t next_id_ = 0;
  bool stop_ = false;
  std::thread worker_;
  ColoredPoints sensor_points_;  // worker thread only
  ColoredPoints map_points_;     // worker thread only: a depth frame's filtered map-frame points

  std::mutex stats_mutex_;
  Totals totals_;
  static constexpr double kWarnPeriodS = 5.0;
  std::mutex warn_mutex_;
  std::map<std::string, std::chrono::steady_clock::time_point> last_warn_;
  std::atomic<uint64_t> map_leaves_{0};
  std::atomic<uint64_t> map_memory_{0};
  std::chrono::steady_clock::time_point size_stats_at_{};
  std::optional<ros::Time> size_stats_stamp_;  // causal: the step time of the last refresh

  ros::CallbackQueue cloud_queue_;
  std::unique_ptr<ros::AsyncSpinner> cloud_spinner_;
  ros::Subscriber sub_cloud_;
  message_filters::Subscriber<sensor_msgs::Image> sub_depth_;
  message_filters::Subscriber<sensor_msgs::Image> sub_color_;
  message_filters::Subscriber<sensor_msgs::CameraInfo> sub_info_;
  std::unique_ptr<RgbdSync> sync_rgbd_;
  std::unique_ptr<DepthSync> sync_depth_;
  lockstep::CountedPublisher pub_binary_, pub_full_, pub_markers_, pub_projected_, pub_centers_, pub_layers_,
      pub_stats_;
  ros::ServiceServer srv_binary_, srv_full_, srv_reset_, srv_clear_, srv_layers_, srv_save_, srv_load_, srv_export_;
  ros::Timer timer_layers_;
  ros::WallTimer timer_map_, timer_autosave_;
};

}  // namespace
}  // namespace uav_mapping

// Exit codes: the project's one convention (docs/architecture.md): 2 bad configuration or ~param,
// 1 a runtime failure.
constexpr int kExitFailure = 1;
constexpr int kExitConfig = 2;
/// The map server's lookahead in the causal lockstep (docs/lockstep.md): what it publishes while processing step
/// k is its consumers' input at step k + 3, so it may insert while the bridge simulates and renders two more steps.
constexpr int kLockstepLookaheadSteps = 3;

int main(int argc, char** argv) {
  // Line-buffered output, so that logs reach a pipe (roslaunch, test harnesses) even if the node is killed.
  std::setvbuf(stdout, nullptr, _IOLBF, 0);
  ros::init(argc, argv, "map_server");
  ros::NodeHandle nh;
  ros::NodeHandle pnh("~");
  uav_mapping::Params params;
  uav_mapping::lockstep::Settings lockstep;
  try {
    std::vector<std::string> warnings;
    params = uav_mapping::readParams(pnh, warnings);
    for (const auto& w : warnings) ROS_WARN("map_server: %s", w.c_str());
    // The global /lockstep/* parameters (docs/lockstep.md); the map server's default lookahead is 3 steps.
    lockstep = uav_mapping::lockstep::readSettings(ros::this_node::getName(), kLockstepLookaheadSteps);
  } catch (const std::exception& e) {
    ROS_FATAL("map_server: invalid configuration: %s", e.what());
    return kExitConfig;
  }
  try {
    uav_mapping::MapServerNode node(nh, pnh, params, lockstep);
    node.spin();
  } catch (const std::exception& e) {
    ROS_FATAL("map_server: %s", e.what());
    return kExitFailure;
  }
  return 0;
}
