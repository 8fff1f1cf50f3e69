#include <uav_mapping/depth_filter.h>

#include <array>
#include <cmath>
#include <cstring>
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

}  // namespace uav_mapping
