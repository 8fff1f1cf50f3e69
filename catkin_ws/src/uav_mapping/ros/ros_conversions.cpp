#include "ros_conversions.h"

#include <uav_mapping/octree_map.h>

#include <sensor_msgs/PointField.h>

#include <algorithm>
#include <cmath>
#include <array>
#include <cstring>
#include <limits>
#include <sstream>

namespace uav_mapping {
namespace ros_conv {

const char* toString(CloudError e) {
  switch (e) {
    case CloudError::kNone:
      return "";
    case CloudError::kEmpty:
      return "empty";
    case CloudError::kBadLayout:
      return "bad_layout";
    case CloudError::kTooLarge:
      return "too_large";
  }
  return "?";
}

namespace {
const sensor_msgs::PointField* findField(const sensor_msgs::PointCloud2& msg, const char* name) {
  for (const auto& f : msg.fields) {
    if (f.name == name) return &f;
  }
  return nullptr;
}
}  // namespace

CloudError parseCloud(const sensor_msgs::PointCloud2& msg, std::size_t max_points, ColoredPoints& out,
                      std::string& detail) {
  out.clear();
  const uint64_t n = static_cast<uint64_t>(msg.width) * msg.height;
  if (n > max_points) {
    detail = std::to_string(msg.width) + " x " + std::to_string(msg.height) + " points exceed max_points " +
             std::to_string(max_points);
    return CloudError::kTooLarge;
  }
  const sensor_msgs::PointField* fx = findField(msg, "x");
  const sensor_msgs::PointField* fy = findField(msg, "y");
  const sensor_msgs::PointField* fz = findField(msg, "z");
  if (fx == nullptr || fy == nullptr || fz == nullptr) {
    detail = "no x, y and z fields";
    return CloudError::kBadLayout;
  }
  for (const sensor_msgs::PointField* f : {fx, fy, fz}) {
    if (f->datatype != sensor_msgs::PointField::FLOAT32 || f->count < 1 ||
        static_cast<uint64_t>(f->offset) + 4 > msg.point_step) {
      detail = "field " + f->name + " must be float32 within point_step";
      return CloudError::kBadLayout;
    }
  }
  const sensor_msgs::PointField* fc = findField(msg, "rgb");
  if (fc == nullptr) fc = findField(msg, "rgba");
  if (fc != nullptr && ((fc->datatype != sensor_msgs::PointField::FLOAT32 &&
                         fc->datatype != sensor_msgs::PointField::UINT32) ||
                        static_cast<uint64_t>(fc->offset) + 4 > msg.point_step)) {
    detail = "field " + fc->name + " must be a packed float32 or uint32 within point_step";
    return CloudError::kBadLayout;
  }
  if (msg.is_bigendian) {
    detail = "big-endian clouds are not supported";
    return CloudError::kBadLayout;
  }
  if (static_cast<uint64_t>(msg.row_step) < static_cast<uint64_t>(msg.width) * msg.point_step ||
      static_cast<uint64_t>(msg.data.size()) < static_cast<uint64_t>(msg.row_step) * msg.height) {
    std::ostringstream os;
    os << "data (" << msg.data.size() << " bytes) does not hold " << msg.height << " rows of " << msg.row_step
       << " bytes (width " << msg.width << ", point_step " << msg.point_step << ")";
    detail = os.str();
    return CloudError::kBadLayout;
  }
  if (n == 0) {
    detail = "no points";
    return CloudError::kEmpty;
  }
  out.xyz.resize(n);
  if (fc != nullptr) out.rgb.resize(n);
  std::size_t i = 0;
  for (uint32_t row = 0; row < msg.height; ++row) {
    const uint8_t* p = msg.data.data() + static_cast<std::size_t>(row) * msg.row_step;
    for (uint32_t col = 0; col < msg.width; ++col, p += msg.point_step, ++i) {
      float x, y, z;
      std::memcpy(&x, p + fx->offset, 4);
      std::memcpy(&y, p + fy->offset, 4);
      std::memcpy(&z, p + fz->offset, 4);
      out.xyz[i] = Point3(x, y, z);
      if (fc != nullptr) {
        uint32_t rgb;
        std::memcpy(&rgb, p + fc->offset, 4);
        out.rgb[i] = {static_cast<uint8_t>((rgb >> 16) & 0xFF), static_cast<uint8_t>((rgb >> 8) & 0xFF),
                      static_cast<uint8_t>(rgb & 0xFF)};
      }
    }
  }
  detail.clear();
  return CloudError::kNone;
}

namespace {
/// Why an image cannot be read as `rows` rows of `cols` pixels of `bytes_per_pixel`; empty when it can.
std::string imageLayoutProblem(const sensor_msgs::Image& img, uint32_t bytes_per_pixel) {
  if (img.is_bigendian) return "big-endian images are not supported";
  if (static_cast<uint64_t>(img.step) < static_cast<uint64_t>(img.width) * bytes_per_pixel)
    return "step " + std::to_string(img.step) + " is shorter than width " + std::to_string(img.width) + " x " +
           std::to_string(bytes_per_pixel) + " bytes";
  if (static_cast<uint64_t>(img.data.size()) < static_cast<uint64_t>(img.step) * img.height)
    return "data (" + std::to_string(img.data.size()) + " bytes) does not hold " + std::to_string(img.height) +
           " rows of " + std::to_string(img.step) + " bytes";
  return "";
}
}  // namespace

CloudError depthImageViews(const sensor_msgs::Image& depth, const sensor_msgs::Image* color,
                           const sensor_msgs::CameraInfo& info, std::size_t max_points, DepthInput& out,
                           std::string& detail) {
  out = DepthInput();
  const bool metres = depth.encoding == "32FC1";
  if (!metres && depth.encoding != "16UC1") {
    detail = "depth encoding '" + depth.encoding + "' is not supported; publish 32FC1 (metres) or 16UC1 (mm)";
    return CloudError::kBadLayout;
  }
  std::string problem = imageLayoutProblem(depth, metres ? 4 : 2);
  if (!problem.empty()) {
    detail = "depth image: " + problem;
    return CloudError::kBadLayout;
  }
  const uint64_t n = static_cast<uint64_t>(depth.width) * depth.height;
  if (n > max_points) {
    detail = std::to_string(depth.width) + " x " + std::to_string(depth.height) + " pixels exceed max_points " +
             std::to_string(max_points);
    return CloudError::kTooLarge;
  }
  const double fx = info.K[0];
  const double fy = info.K[4];
  const double cx = info.K[2];
  const double cy = info.K[5];
  if (!(fx > 0.0 && fy > 0.0 && std::isfinite(fx) && std::isfinite(fy) && std::isfinite(cx) && std::isfinite(cy))) {
    detail = "camera_info K has no positive finite focal lengths (fx " + std::to_string(fx) + ", fy " +
             std::to_string(fy) + "); is camera_info_in the depth camera's?";
    return CloudError::kBadLayout;
  }
  if ((info.width != 0 || info.height != 0) && (info.width != depth.width || info.height != depth.height)) {
    detail = "camera_info is " + std::to_string(info.width) + " x " + std::to_string(info.height) +
             " but the depth image " + std::to_string(depth.width) + " x " + std::to_string(depth.height);
    return CloudError::kBadLayout;
  }
  ColorImageView color_view;
  if (color != nullptr) {
    const std::string& e = color->encoding;
    if (e == "rgb8") {
      color_view.encoding = ColorEncoding::kRgb8;
    } else if (e == "bgr8") {
      color_view.encoding = ColorEncoding::kBgr8;
    } else if (e == "rgba8") {
      color_view.encoding = ColorEncoding::kRgba8;
    } else if (e == "bgra8") {
      color_view.encoding = ColorEncoding::kBgra8;
    } else {
      detail = "color encoding '" + e + "' is not supported; publish rgb8, bgr8, rgba8 or bgra8";
      return CloudError::kBadLayout;
    }
    const uint32_t channels = (e == "rgb8" || e == "bgr8") ? 3 : 4;
    if (color->width != depth.width || color->height != depth.height) {
      detail = "the color image is " + std::to_string(color->width) + " x " + std::to_string(color->height) +
               " but the depth image " + std::to_string(depth.width) + " x " + std::to_string(depth.height) +
               " (register depth to color, or set ~rgbd_color false)";
      return CloudError::kBadLayout;
    }
    problem = imageLayoutProblem(*color, channels);
    if (!problem.empty()) {
      detail = "color image: " + problem;
      return CloudError::kBadLayout;
    }
    color_view.data = color->data.data();
    color_view.step_bytes = color->step;
  }
  out.depth.data = depth.data.data();
  out.depth.width = depth.width;
  out.depth.height = depth.height;
  out.depth.step_bytes = depth.step;
  out.depth.encoding = metres ? DepthEncoding::kFloat32Metres : DepthEncoding::kUint16Millimetres;
  out.color = color_view;
  out.k = PinholeIntrinsics{fx, fy, cx, cy};
  detail.clear();
  return CloudError::kNone;
}

RigidTransform fromMsg(const geometry_msgs::TransformStamped& tf) {
  const auto& q = tf.transform.rotation;
  const auto& p = tf.transform.translation;
  return RigidTransform::fromQuaternion(q.w, q.x, q.y, q.z, p.x, p.y, p.z);
}

uav_msgs::GridLayers layersToMsg(const LayersSnapshot& l, const std::string& frame_id, const ros::Time& stamp) {
  uav_msgs::GridLayers msg;
  msg.header.frame_id = frame_id;
  msg.header.stamp = stamp;
  msg.resolution_m = l.resolution_m;
  msg.origin_x_m = l.origin_x_m;
  msg.origin_y_m = l.origin_y_m;
  msg.width = l.width;
  msg.height = l.height;
  msg.names = {"elevation_m", "last_seen_s", "observed"};
  const std::size_t n = static_cast<std::size_t>(l.width) * l.height;
  msg.data.resize(3 * n);
  std::copy(l.elevation_m.begin(), l.elevation_m.end(), msg.data.begin());
  std::copy(l.last_seen_s.begin(), l.last_seen_s.end(), msg.data.begin() + n);
  std::copy(l.observed.begin(), l.observed.end(), msg.data.begin() + 2 * n);
  return msg;
}

octomap_msgs::Octomap octomapToMsg(const UavOcTree& tree, bool binary, const std::string& frame_id,
                                   const ros::Time& stamp) {
  octomap_msgs::Octomap msg;
  msg.header.frame_id = frame_id;
  msg.header.stamp = stamp;
  msg.binary = binary;
  msg.resolution = tree.getResolution();
  msg.id = binary ? "OcTree" : "ColorOcTree";  // binary data is node-type independent; full data is ColorOcTree's
  std::stringstream ss(std::ios::in | std::ios::out | std::ios::binary);
  if (binary)
    tree.writeBinaryData(ss);
  else
    tree.writeData(ss);
  const std::string bytes = ss.str();
  msg.data.assign(bytes.begin(), bytes.end());
  return msg;
}

namespace {

std_msgs::ColorRGBA hsvColor(double h) {  // h in [0, 1), full saturation and value
  std_msgs::ColorRGBA c;
  c.a = 1.0;
  h = (h - std::floor(h)) * 6.0;
  const int i = static_cast<int>(std::floor(h));
  const double f = h - i;
  const double q = 1.0 - f;
  switch (i % 6) {
    case 0:
      c.r = 1, c.g = f, c.b = 0;
      break;
    case 1:
      c.r = q, c.g = 1, c.b = 0;
      break;
    case 2:
      c.r = 0, c.g = 1, c.b = f;
      break;
    case 3:
      c.r = 0, c.g = q, c.b = 1;
      break;
    case 4:
      c.r = f, c.g = 0, c.b = 1;
      break;
    default:
      c.r = 1, c.g = 0, c.b = q;
      break;
  }
  return c;
}

}  // namespace

visualization_msgs::MarkerArray occupiedMarkers(const VoxelMap& map, const MarkerStyle& style,
                                                const std::string& frame_id, const ros::Time& stamp) {
  const double res = map.resolution();
  const KeyGrid grid(res);
  visualization_msgs::MarkerArray arr;
  arr.markers.resize(kTreeDepth + 1);
  double min_z = std::numeric_limits<double>::max();
  double max_z = std::numeric_limits<double>::lowest();
  map.forEachLeaf(
      [&](const Leaf& l) {
        const double z = grid.lowerFace(l.key[2]) + 0.5 * l.size * res;
        min_z = std::min(min_z, z);
        max_z = std::max(max_z, z);
      },
      true);
  map.forEachLeaf(
      [&](const Leaf& l) {
        int depth = kTreeDepth;
        for (unsigned s = l.size; s > 1; s >>= 1) --depth;
        auto& m = arr.markers[static_cast<std::size_t>(depth)];
        geometry_msgs::Point p;
        p.x = grid.lowerFace(l.key[0]) + 0.5 * l.size * res;
        p.y = grid.lowerFace(l.key[1]) + 0.5 * l.size * res;
        p.z = grid.lowerFace(l.key[2]) + 0.5 * l.size * res;
        m.points.push_back(p);
        if (style.colored_map && l.state.color_set) {
          std_msgs::ColorRGBA c;
          c.r = l.state.r / 255.0f;
          c.g = l.state.g / 255.0f;
          c.b = l.state.b / 255.0f;
          c.a = 1.0f;
          m.colors.push_back(c);
        } else if (style.height_map || style.colored_map) {
          const double span = max_z > min_z ? max_z - min_z : 1.0;
          m.colors.push_back(hsvColor((1.0 - std::clamp((p.z - min_z) / span, 0.0, 1.0)) * style.color_factor));
        } else {
          m.colors.push_back(style.color);
        }
      },
      true);
  for (std::size_t d = 0; d < arr.markers.size(); ++d) {
    auto& m = arr.markers[d];
    m.header.frame_id = frame_id;
    m.header.stamp = stamp;
    m.ns = "map";
    m.id = static_cast<int>(d);
    m.type = visualization_msgs::Marker::CUBE_LIST;
    const double size = res * static_cast<double>(1U << (kTreeDepth - d));
    m.scale.x = m.scale.y = m.scale.z = size;
    m.pose.orientation.w = 1.0;
    m.color = style.color;
    m.frame_locked = true;
    m.action = m.points.empty() ? visualization_msgs::Marker::DELETE : visualization_msgs::Marker::ADD;
  }
  return arr;
}

nav_msgs::OccupancyGrid projectedMap(const VoxelMap& map, const ColumnLayers& columns, double min_z_m, double max_z_m,
                                     const std::string& frame_id, const ros::Time& stamp) {
  nav_msgs::OccupancyGrid grid_msg;
  grid_msg.header.frame_id = frame_id;
  grid_msg.header.stamp = stamp;
  const double res = map.resolution();
  grid_msg.info.resolution = static_cast<float>(res);
  grid_msg.info.map_load_time = stamp;
  grid_msg.info.origin.orientation.w = 1.0;
  const KeyBox& box = columns.observedBox();
  if (box.empty()) return grid_msg;
  const KeyGrid grid(res);
  const int w = box.max[0] - box.min[0] + 1;
  const int h = box.max[1] - box.min[1] + 1;
  grid_msg.info.width = static_cast<uint32_t>(w);
  grid_msg.info.height = static_cast<uint32_t>(h);
  grid_msg.info.origin.position.x = grid.lowerFace(static_cast<uint16_t>(box.min[0]));
  grid_msg.info.origin.position.y = grid.lowerFace(static_cast<uint16_t>(box.min[1]));
  grid_msg.data.assign(static_cast<std::size_t>(w) * h, -1);
  map.forEachLeaf(
      [&](const Leaf& l) {
        const double z0 = grid.lowerFace(l.key[2]);
        const double z1 = z0 + l.size * res;
        if (z1 <= min_z_m || z0 > max_z_m) return;
        const bool occupied = map.isOccupied(l.state.log_odds);
        for (unsigned dy = 0; dy < l.size; ++dy) {
          const int row = l.key[1] + static_cast<int>(dy) - box.min[1];
          if (row < 0 || row >= h) continue;
          for (unsigned dx = 0; dx < l.size; ++dx) {
            const int col = l.key[0] + static_cast<int>(dx) - box.min[0];
            if (col < 0 || col >= w) continue;
            int8_t& cell = grid_msg.data[static_cast<std::size_t>(row) * w + col];
            if (occupied)
              cell = 100;
            else if (cell < 0)
              cell = 0;
          }
        }
      },
      false);
  return grid_msg;
}

sensor_msgs::PointCloud2 occupiedCenters(const VoxelMap& map, const std::string& frame_id, const ros::Time& stamp) {
  sensor_msgs::PointCloud2 msg;
  msg.header.frame_id = frame_id;
  msg.header.stamp = stamp;
  msg.height = 1;
  msg.is_bigendian = false;
  msg.is_dense = true;
  msg.point_step = 16;
  const char* names[4] = {"x", "y", "z", "rgb"};
  for (int i = 0; i < 4; ++i) {
    sensor_msgs::PointField f;
    f.name = names[i];
    f.offset = static_cast<uint32_t>(4 * i);
    f.datatype = sensor_msgs::PointField::FLOAT32;
    f.count = 1;
    msg.fields.push_back(f);
  }
  const double res = map.resolution();
  const KeyGrid grid(res);
  map.forEachLeaf(
      [&](const Leaf& l) {
        const float xyz[3] = {static_cast<float>(grid.lowerFace(l.key[0]) + 0.5 * l.size * res),
                              static_cast<float>(grid.lowerFace(l.key[1]) + 0.5 * l.size * res),
                              static_cast<float>(grid.lowerFace(l.key[2]) + 0.5 * l.size * res)};
        const uint32_t rgb = l.state.color_set
                                 ? (static_cast<uint32_t>(l.state.r) << 16) | (static_cast<uint32_t>(l.state.g) << 8) | l.state.b
                                 : 0x808080U;
        const std::size_t o = msg.data.size();
        msg.data.resize(o + 16);
        std::memcpy(&msg.data[o], xyz, 12);
        std::memcpy(&msg.data[o + 12], &rgb, 4);
      },
      true);
  msg.width = static_cast<uint32_t>(msg.data.size() / 16);
  msg.row_step = msg.width * msg.point_step;
  return msg;
}

}  // namespace ros_conv
}  // namespace uav_mapping
