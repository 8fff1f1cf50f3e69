#include "synthetic_world.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>

namespace uav_mapping {
namespace synthetic {

double World::terrain(double x, double y) {
  return 4.0 * std::sin(x / 61.0) * std::cos(y / 47.0) + 1.5 * std::sin((x + 2.0 * y) / 23.0) +
         0.4 * std::sin(x / 5.3) * std::sin(y / 6.1);
}

World::World(const WorldOptions& options) : opt_(options) {
  n_ = static_cast<int>(std::ceil(2.0 * opt_.half_size_m / opt_.raster_m));
  const std::size_t cells = static_cast<std::size_t>(n_) * n_;
  height_.resize(cells);
  rgb_.resize(cells * 3);
  for (int j = 0; j < n_; ++j) {
    const double y = -opt_.half_size_m + (j + 0.5) * opt_.raster_m;
    for (int i = 0; i < n_; ++i) {
      const double x = -opt_.half_size_m + (i + 0.5) * opt_.raster_m;
      const std::size_t c = static_cast<std::size_t>(j) * n_ + i;
      const double h = terrain(x, y);
      height_[c] = static_cast<float>(h);
      const double shade = 0.5 + 0.5 * std::sin(x / 9.0) * std::cos(y / 7.0);
      rgb_[3 * c] = static_cast<uint8_t>(70 + 50 * shade);
      rgb_[3 * c + 1] = static_cast<uint8_t>(110 + 40 * shade + 4 * h);
      rgb_[3 * c + 2] = static_cast<uint8_t>(50 + 20 * shade);
    }
  }
  std::mt19937 rng(opt_.seed);
  const double area = 4.0 * opt_.half_size_m * opt_.half_size_m;
  auto stamp = [&](double cx, double cy, double hx, double hy, double top, const uint8_t col[3], bool round) {
    const int i0 = std::max(0, static_cast<int>((cx - hx + opt_.half_size_m) / opt_.raster_m));
    const int i1 = std::min(n_ - 1, static_cast<int>((cx + hx + opt_.half_size_m) / opt_.raster_m));
    const int j0 = std::max(0, static_cast<int>((cy - hy + opt_.half_size_m) / opt_.raster_m));
    const int j1 = std::min(n_ - 1, static_cast<int>((cy + hy + opt_.half_size_m) / opt_.raster_m));
    for (int j = j0; j <= j1; ++j) {
      for (int i = i0; i <= i1; ++i) {
        const double x = -opt_.half_size_m + (i + 0.5) * opt_.raster_m;
        const double y = -opt_.half_size_m + (j + 0.5) * opt_.raster_m;
        double h = top;
        if (round) {
          const double r = std::hypot((x - cx) / hx, (y - cy) / hy);
          if (r > 1.0) continue;
          h = top - 2.0 * r * r;  // rounded crown
        }
        const std::size_t c = static_cast<std::size_t>(j) * n_ + i;
        if (h > height_[c]) {
          height_[c] = static_cast<float>(h);
          rgb_[3 * c] = col[0];
          rgb_[3 * c + 1] = col[1];
          rgb_[3 * c + 2] = col[2];
        }
      }
    }
  };
  std::uniform_real_distribution<double> pos(-opt_.half_size_m, opt_.half_size_m);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  const int buildings = static_cast<int>(opt_.building_density * area / 1e4);
  for (int b = 0; b < buildings; ++b) {
    const double cx = pos(rng);
    const double cy = pos(rng);
    if (std::hypot(cx, cy) < 20.0) continue;  // keep the home pad clear, as the real world generator does
    const double hx = 4.0 + 8.0 * unit(rng);
    const double hy = 4.0 + 8.0 * unit(rng);
    const double top = terrain(cx, cy) + 5.0 + 15.0 * unit(rng);
    const uint8_t roof[3] = {static_cast<uint8_t>(120 + 100 * unit(rng)), 80, static_cast<uint8_t>(60 + 40 * unit(rng))};
    stamp(cx, cy, hx, hy, top, roof, false);
  }
  const int trees = static_cast<int>(opt_.tree_density * area / 1e4);
  for (int t = 0; t < trees; ++t) {
    const double cx = pos(rng);
    const double cy = pos(rng);
    if (std::hypot(cx, cy) < 20.0) continue;
    const double r = 1.5 + 2.0 * unit(rng);
    const double top = terrain(cx, cy) + 6.0 + 6.0 * unit(rng);
    const uint8_t leaf[3] = {30, static_cast<uint8_t>(90 + 60 * unit(rng)), 35};
    stamp(cx, cy, r, r, top, leaf, true);
  }
}

std::size_t World::cell(double x, double y, bool& inside) const {
  const int i = static_cast<int>(std::floor((x + opt_.half_size_m) / opt_.raster_m));
  const int j = static_cast<int>(std::floor((y + opt_.half_size_m) / opt_.raster_m));
  inside = i >= 0 && j >= 0 && i < n_ && j < n_;
  return inside ? static_cast<std::size_t>(j) * n_ + i : 0;
}

float World::height(double x, double y) const {
  bool inside;
  const std::size_t c = cell(x, y, inside);
  return inside ? height_[c] : static_cast<float>(terrain(x, y));
}

void World::color(double x, double y, uint8_t rgb[3]) const {
  bool inside;
  const std::size_t c = cell(x, y, inside);
  if (!inside) {
    rgb[0] = 90;
    rgb[1] = 120;
    rgb[2] = 60;
    return;
  }
  rgb[0] = rgb_[3 * c];
  rgb[1] = rgb_[3 * c + 1];
  rgb[2] = rgb_[3 * c + 2];
}

RigidTransform nadirPose(const World& world, double x, double y, double agl_m) {
  RigidTransform t;
  // optical x = east, y = south, z = down
  t.r[0][0] = 1;
  t.r[0][1] = 0;
  t.r[0][2] = 0;
  t.r[1][0] = 0;
  t.r[1][1] = -1;
  t.r[1][2] = 0;
  t.r[2][0] = 0;
  t.r[2][1] = 0;
  t.r[2][2] = -1;
  t.t[0] = x;
  t.t[1] = y;
  t.t[2] = world.height(x, y) + agl_m;
  return t;
}

RigidTransform tiltedPose(const World& world, double x, double y, double agl_m, double tilt_deg) {
  const double c = std::cos(tilt_deg * M_PI / 180.0);
  const double s = std::sin(tilt_deg * M_PI / 180.0);
  RigidTransform t;  // columns: optical x = east, y = (0, -c, -s), z = (0, s, -c)
  t.r[0][0] = 1;
  t.r[0][1] = 0;
  t.r[0][2] = 0;
  t.r[1][0] = 0;
  t.r[1][1] = -c;
  t.r[1][2] = s;
  t.r[2][0] = 0;
  t.r[2][1] = -s;
  t.r[2][2] = -c;
  t.t[0] = x;
  t.t[1] = y;
  t.t[2] = world.height(x, y) + agl_m;
  return t;
}

namespace {

/// Ray marches every pixel: z-depth (-1 where nothing is hit within range) and colour, row-major.
void march(const World& world, const Camera& cam, const RigidTransform& tf, int threads, std::vector<float>& depth,
           std::vector<std::array<uint8_t, 3>>& col) {
  const double f = 0.5 * cam.width / std::tan(0.5 * cam.hfov_deg * M_PI / 180.0);
  const double cx = 0.5 * cam.width;
  const double cy = 0.5 * cam.height;
  const std::size_t n = static_cast<std::size_t>(cam.width) * cam.height;
  depth.assign(n, -1.0f);
  col.assign(n, {0, 0, 0});
  tbb::task_arena arena(std::max(1, threads));
  arena.execute([&] {
    tbb::parallel_for(tbb::blocked_range<int>(0, cam.height), [&](const tbb::blocked_range<int>& rows) {
      for (int v = rows.begin(); v < rows.end(); ++v) {
        for (int u = 0; u < cam.width; ++u) {
          // Ray in the optical frame (z = 1), then in the map frame.
          const double ox = (u + 0.5 - cx) / f;
          const double oy = (v + 0.5 - cy) / f;
          const double dx = tf.r[0][0] * ox + tf.r[0][1] * oy + tf.r[0][2];
          const double dy = tf.r[1][0] * ox + tf.r[1][1] * oy + tf.r[1][2];
          const double dz = tf.r[2][0] * ox + tf.r[2][1] * oy + tf.r[2][2];
          const double len = std::sqrt(dx * dx + dy * dy + dz * dz);
          const double t_max = cam.max_range_m * len;  // z-depth limit along the unnormalised ray
          double t_prev = 0.0;
          double t = 0.0;
          bool hit = false;
          while (t < t_max) {
            const double gap = (tf.t[2] + dz * t) - world.height(tf.t[0] + dx * t, tf.t[1] + dy * t);
            if (gap <= 0.0) {
              hit = true;
              break;
            }
            t_prev = t;
            t += std::clamp(0.5 * gap / len, 0.05 / len, 1.0 / len);
          }
          if (!hit) continue;
          for (int it = 0; it < 12; ++it) {  // bisection to ~1 mm
            const double tm = 0.5 * (t_prev + t);
            const double gap = (tf.t[2] + dz * tm) - world.height(tf.t[0] + dx * tm, tf.t[1] + dy * tm);
            if (gap <= 0.0)
              t = tm;
            else
              t_prev = tm;
          }
          const std::size_t i = static_cast<std::size_t>(v) * cam.width + u;
          depth[i] = static_cast<float>(t);  // optical z of the hit (the ray has z = 1)
          uint8_t rgb[3];
          world.color(tf.t[0] + dx * t, tf.t[1] + dy * t, rgb);
          col[i] = {rgb[0], rgb[1], rgb[2]};
        }
      }
    });
  });
}

}  // namespace

DepthFrame renderDepth(const World& world, const Camera& cam, const RigidTransform& tf, int threads) {
  std::vector<float> depth;
  std::vector<std::array<uint8_t, 3>> col;
  march(world, cam, tf, threads, depth, col);
  DepthFrame frame;
  frame.width = static_cast<uint32_t>(cam.width);
  frame.height = static_cast<uint32_t>(cam.height);
  frame.depth_m.resize(depth.size());
  frame.rgb.resize(3 * depth.size());
  for (std::size_t i = 0; i < depth.size(); ++i) {
    frame.depth_m[i] = depth[i] < 0.0f ? std::numeric_limits<float>::quiet_NaN() : depth[i];
    for (int c = 0; c < 3; ++c) frame.rgb[3 * i + c] = col[i][c];
  }
  // march's ray of pixel u is (u + 0.5 - width / 2) / f: the centre of pixel u, at u in K's convention.
  const double f = 0.5 * cam.width / std::tan(0.5 * cam.hfov_deg * M_PI / 180.0);
  frame.k = PinholeIntrinsics{f, f, 0.5 * cam.width - 0.5, 0.5 * cam.height - 0.5};
  return frame;
}

ColoredPoints render(const World& world, const Camera& cam, const RigidTransform& tf, int threads) {
  const double f = 0.5 * cam.width / std::tan(0.5 * cam.hfov_deg * M_PI / 180.0);
  const double cx = 0.5 * cam.width;
  const double cy = 0.5 * cam.height;
  const std::size_t n = static_cast<std::size_t>(cam.width) * cam.height;
  std::vector<float> depth;
  std::vector<std::array<uint8_t, 3>> col;
  march(world, cam, tf, threads, depth, col);
  ColoredPoints out;
  out.xyz.reserve(n);
  out.rgb.reserve(n);
  for (int v = 0; v < cam.height; ++v) {
    for (int u = 0; u < cam.width; ++u) {
      const std::size_t i = static_cast<std::size_t>(v) * cam.width + u;
      if (depth[i] < 0.0f) continue;
      const double z = depth[i];
      out.xyz.emplace_back(static_cast<float>((u + 0.5 - cx) / f * z), static_cast<float>((v + 0.5 - cy) / f * z),
                           static_cast<float>(z));
      out.rgb.push_back(col[i]);
    }
  }
  return out;
}

ColoredPoints toMap(const ColoredPoints& optical, const RigidTransform& tf) {
  ColoredPoints out;
  FilterStats stats;
  transformAndFilter(optical, tf, FilterOptions(), out, stats);
  return out;
}

}  // namespace synthetic
}  // namespace uav_mapping
