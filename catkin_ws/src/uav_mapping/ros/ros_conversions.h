// The only place where ROS messages meet the map core's types.
#pragma once

#include <uav_mapping/column_layers.h>
#include <uav_mapping/depth_filter.h>
#include <uav_mapping/mapper.h>
#include <uav_mapping/octree_map.h>

#include <geometry_msgs/TransformStamped.h>
#include <nav_msgs/OccupancyGrid.h>
#include <octomap_msgs/Octomap.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/PointCloud2.h>
#include <std_msgs/ColorRGBA.h>
#include <uav_msgs/GridLayers.h>
#include <visualization_msgs/MarkerArray.h>

#include <string>

namespace uav_mapping {
namespace ros_conv {

enum class CloudError { kNone, kEmpty, kBadLayout, kTooLarge };
const char* toString(CloudError e);

/// Parses an unorganised or organised PointCloud2 with float32 x, y, z and optional rgb/rgba (float32 or uint32,
/// 0x00RRGGBB) into `out` (sensor frame). Non-finite points are kept (the core filter counts and drops them).
/// Returns the reason a cloud cannot be used; `detail` says what exactly is wrong.
CloudError parseCloud(const sensor_msgs::PointCloud2& msg, std::size_t max_points, ColoredPoints& out,
                      std::string& detail);

/// A depth frame's images as views into the messages (valid while the messages live) and its intrinsics.
struct DepthInput {
  DepthImageView depth;
  ColorImageView color;  // data == nullptr: no colour
  PinholeIntrinsics k;
};

/// Checks a z-depth image (32FC1 metres, or 16UC1 millimetres with 0 = no return), its optional registered
/// `color` image (rgb8, bgr8, rgba8 or bgra8 of the same size; nullptr: no colour) and the pinhole K of `info`,
/// and returns views of them for the core's depth front end (depth_filter.h: filterDepthImage, or
/// depthToOpticalPoints for the points themselves). Returns the reason a frame cannot be used;
/// `detail` says what exactly is wrong and what to publish instead.
CloudError depthImageViews(const sensor_msgs::Image& depth, const sensor_msgs::Image* color,
                           const sensor_msgs::CameraInfo& info, std::size_t max_points, DepthInput& out,
                           std::string& detail);

RigidTransform fromMsg(const geometry_msgs::TransformStamped& tf);

/// uav_msgs/GridLayers with layers elevation_m, last_seen_s, observed.
uav_msgs::GridLayers layersToMsg(const LayersSnapshot& layers, const std::string& frame_id, const ros::Time& stamp);

/// octomap_msgs/Octomap of an OctoMap tree: binary (id OcTree, writeBinaryData) or full (id ColorOcTree, write()).
octomap_msgs::Octomap octomapToMsg(const UavOcTree& tree, bool binary, const std::string& frame_id,
                                   const ros::Time& stamp);

struct MarkerStyle {
  bool height_map = true;   // colour by height (octomap_server's height_map)
  bool colored_map = false; // colour by voxel colour (octomap_server's colored_map); wins over height_map
  double color_factor = 0.8;
  std_msgs::ColorRGBA color;  // fixed colour when neither
};
/// occupied_cells_vis_array: one CUBE_LIST per node size (octomap_server's layout: id = tree depth).
visualization_msgs::MarkerArray occupiedMarkers(const VoxelMap& map, const MarkerStyle& style,
                                                const std::string& frame_id, const ros::Time& stamp);

/// projected_map: 100 where a column has an occupied voxel with z in [min_z, max_z], 0 where it has only free
/// ones there, -1 unknown; over the map's observed columns.
nav_msgs::OccupancyGrid projectedMap(const VoxelMap& map, const ColumnLayers& columns, double min_z_m, double max_z_m,
                                     const std::string& frame_id, const ros::Time& stamp);

/// octomap_point_cloud_centers: centres of occupied leaves, x y z rgb (float32, rgb packed as in PCL).
sensor_msgs::PointCloud2 occupiedCenters(const VoxelMap& map, const std::string& frame_id, const ros::Time& stamp);

}  // namespace ros_conv
}  // namespace uav_mapping
