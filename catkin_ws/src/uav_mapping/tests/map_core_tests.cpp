// Tests of the map server core without ROS, against the real liboctomap and OpenVDB.
//
//   map_core_tests --list          names of all tests
//   map_core_tests NAME [NAME...]  run the named tests (exit 1 if any fails)
//   map_core_tests --all           run every test
//   map_core_tests --write-sample DIR   write sample outputs for the Python readers' tests
//
// tests/unit/map_server/test_map_core_cpp.py runs each test as its own pytest case.
#include "synthetic_world.h"

#include <uav_mapping/column_layers.h>
#include <uav_mapping/depth_filter.h>
#include <uav_mapping/mapper.h>
#include <uav_mapping/octree_map.h>
#include <uav_mapping/vdb_map.h>

#include <octomap/ColorOcTree.h>
#include <octomap/OcTree.h>

#include <unistd.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <functional>
#include <iostream>
#include <map>
#include <random>
#include <set>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

using namespace uav_mapping;

namespace {

struct Failure : std::runtime_error {
  using std::runtime_error::runtime_error;
};

#define CHECK(cond)                                                                                   \
  do {                                                                                                \
    if (!(cond)) throw Failure(std::string(__FILE__) + ":" + std::to_string(__LINE__) + ": " #cond); \
  } while (0)

#define CHECK_MSG(cond, msg)                                                                             \
  do {                                                                                                   \
    if (!(cond)) {                                                                                       \
      std::ostringstream os_;                                                                            \
      os_ << __FILE__ << ":" << __LINE__ << ": " #cond " -- " << msg;                                    \
      throw Failure(os_.str());                                                                          \
    }                                                                                                    \
  } while (0)

template <class F>
void checkThrows(F&& f, const std::string& what) {
  try {
    f();
  } catch (const MapIoError&) {
    return;
  } catch (const std::invalid_argument&) {
    return;
  }
  throw Failure("expected an exception: " + what);
}

std::map<std::string, std::function<void()>>& registry() {
  static std::map<std::string, std::function<void()>> tests;
  return tests;
}
struct Register {
  Register(const char* name, std::function<void()> fn) { registry()[name] = std::move(fn); }
};
#define TEST(name)                                  \
  void test_##name();                               \
  const Register reg_##name(#name, &test_##name);   \
  void test_##name()

std::string tempPath(const std::string& name) {
  const char* base = std::getenv("MAP_TEST_TMP");
  std::string dir = base ? base : "/tmp";
  return dir + "/map_core_tests_" + std::to_string(getpid()) + "_" + name;
}

Point3 P(double x, double y, double z) {
  return Point3(static_cast<float>(x), static_cast<float>(y), static_cast<float>(z));
}

ColoredPoints cloud(const std::vector<Point3>& pts, const std::vector<std::array<uint8_t, 3>>& rgb = {}) {
  ColoredPoints c;
  c.xyz = pts;
  c.rgb = rgb;
  return c;
}

Key keyAt(double res, double x, double y, double z) {
  Key k;
  const bool ok = KeyGrid(res).toKey(P(x, y, z), k);
  if (!ok) throw Failure("key out of range");
  return k;
}

/// Every voxel of every leaf, expanded, keyed by Morton code.
std::map<uint64_t, VoxelState> voxels(const VoxelMap& map) {
  std::map<uint64_t, VoxelState> out;
  map.forEachLeaf(
      [&](const Leaf& l) {
        for (unsigned dz = 0; dz < l.size; ++dz)
          for (unsigned dy = 0; dy < l.size; ++dy)
            for (unsigned dx = 0; dx < l.size; ++dx)
              out[mortonOf(Key(static_cast<uint16_t>(l.key[0] + dx), static_cast<uint16_t>(l.key[1] + dy),
                               static_cast<uint16_t>(l.key[2] + dz)))] = l.state;
      },
      false);
  return out;
}

bool sameState(const VoxelState& a, const VoxelState& b) {
  return a.log_odds == b.log_odds && a.time_s == b.time_s && a.color_set == b.color_set &&
         (!a.color_set || (a.r == b.r && a.g == b.g && a.b == b.b));
}

void checkSameVoxels(const VoxelMap& a, const VoxelMap& b) {
  const auto va = voxels(a);
  const auto vb = voxels(b);
  CHECK_MSG(va.size() == vb.size(), va.size() << " vs " << vb.size() << " voxels");
  for (const auto& [m, s] : va) {
    auto it = vb.find(m);
    CHECK_MSG(it != vb.end(), "voxel missing in second map");
    CHECK_MSG(sameState(s, it->second), "state differs: log-odds " << s.log_odds << " vs " << it->second.log_odds
                                                                   << ", t " << s.time_s << " vs " << it->second.time_s);
  }
}

void checkSameLayers(const LayersSnapshot& a, const LayersSnapshot& b) {
  CHECK(a.width == b.width && a.height == b.height);
  CHECK(a.origin_x_m == b.origin_x_m && a.origin_y_m == b.origin_y_m && a.resolution_m == b.resolution_m);
  auto same = [](float x, float y) { return (std::isnan(x) && std::isnan(y)) || x == y; };
  for (std::size_t i = 0; i < a.observed.size(); ++i) {
    CHECK_MSG(same(a.elevation_m[i], b.elevation_m[i]), "elevation differs at " << i << ": " << a.elevation_m[i]
                                                                                 << " vs " << b.elevation_m[i]);
    CHECK_MSG(same(a.last_seen_s[i], b.last_seen_s[i]), "last seen differs at " << i);
    CHECK_MSG(a.observed[i] == b.observed[i], "observed differs at " << i);
  }
}

/// A few small synthetic nadir frames (64 x 48, 20 m above ground): the shared test input.
struct SmallFrames {
  std::vector<ColoredPoints> map_points;
  std::vector<RigidTransform> poses;
  std::vector<ColoredPoints> optical;
};
SmallFrames smallFrames(int n, double agl = 20.0, int width = 64, int height = 48) {
  static const synthetic::World world{synthetic::WorldOptions{120.0, 0.25, 3, 4.0, 20.0}};
  synthetic::Camera cam;
  cam.width = width;
  cam.height = height;
  SmallFrames f;
  for (int i = 0; i < n; ++i) {
    const RigidTransform pose = synthetic::nadirPose(world, 30.0 + 6.0 * i, 25.0 + 2.0 * i, agl);
    f.poses.push_back(pose);
    f.optical.push_back(synthetic::render(world, cam, pose, 1));
    f.map_points.push_back(synthetic::toMap(f.optical.back(), pose));
  }
  return f;
}

MapperConfig config(Backend backend, double res, InsertMode mode) {
  MapperConfig c;
  c.backend = backend;
  c.resolution_m = res;
  c.mode = mode;
  c.threads = 2;
  return c;
}

// ---------------------------------------------------------------------------------------------------------
// Keys and frame updates

TEST(keys_match_octomap) {
  std::mt19937 rng(1);
  std::uniform_real_distribution<double> u(-3000.0, 3000.0);
  for (double res : {0.05, 0.25, 0.5, 1.0, 0.3}) {
    octomap::OcTree tree(res);
    const KeyGrid grid(res);
    for (int i = 0; i < 20000; ++i) {
      const Point3 p = P(u(rng), u(rng), u(rng) / 10.0);
      octomap::OcTreeKey a(0, 0, 0);
      Key b(0, 0, 0);
      const bool ok_a = tree.coordToKeyChecked(p, a);
      const bool ok_b = grid.toKey(p, b);
      CHECK(ok_a == ok_b);
      if (!ok_a) continue;
      CHECK(a == b);
      CHECK(keyOfMorton(mortonOf(b)) == b);
      for (int depth = 0; depth < 16; ++depth)
        CHECK(childIndexAt(mortonOf(b), depth) == octomap::computeChildIdx(b, 15 - depth));
    }
    // Outside the addressable cube (+-32768 voxels) and non-finite coordinates are rejected.
    Key k;
    CHECK(!grid.toKey(P(40000.0 * res, 0, 0), k));
    CHECK(!grid.toKey(P(std::nan(""), 0, 0), k));
    CHECK(!grid.toKey(P(INFINITY, 0, 0), k));
  }
}

/// OctoMap's own computeUpdate sets (free without occupied, occupied), as stock insertPointCloud uses them.
void octomapSets(const ColoredPoints& pts, const Point3& origin, double res, double max_range, std::set<uint64_t>& free_set,
                 std::set<uint64_t>& occ_set) {
  octomap::OcTree tree(res);
  octomap::KeyRay ray;
  for (const Point3& p : pts.xyz) {
    if (max_range < 0.0 || (p - origin).norm() <= max_range) {
      if (tree.computeRayKeys(origin, p, ray))
        for (const auto& k : ray) free_set.insert(mortonOf(k));
      octomap::OcTreeKey k;
      if (tree.coordToKeyChecked(p, k)) occ_set.insert(mortonOf(k));
    } else {
      const Point3 end = origin + (p - origin).normalized() * static_cast<float>(max_range);
      if (tree.computeRayKeys(origin, end, ray))
        for (const auto& k : ray) free_set.insert(mortonOf(k));
    }
  }
  for (uint64_t m : occ_set) free_set.erase(m);
}

TEST(full_rays_equal_octomap_key_sets) {
  const SmallFrames f = smallFrames(1);
  for (double res : {0.1, 0.2, 0.5}) {
    for (double max_range : {-1.0, 15.0}) {
      for (int threads : {1, 2}) {
        for (std::size_t byte_map : {std::size_t(512) << 20, std::size_t(0)}) {  // dense and sort fallback paths
          FrameUpdateBuilder builder(res, byte_map);
          for (std::size_t i = 0; i < f.map_points.size(); ++i) {
            std::set<uint64_t> ref_free;
            std::set<uint64_t> ref_occ;
            octomapSets(f.map_points[i], f.poses[i].origin(), res, max_range, ref_free, ref_occ);
            FrameUpdate fu;
            RayOptions ro;
            ro.max_range_m = max_range;
            ro.threads = threads;
            builder.build(f.map_points[i], f.poses[i].origin(), ro, fu);
            CHECK(fu.used_byte_map == (byte_map > 0));
            std::set<uint64_t> free_set;
            std::set<uint64_t> occ_set;
            uint64_t last = 0;
            for (std::size_t j = 0; j < fu.updates.size(); ++j) {
              CHECK_MSG(j == 0 || fu.updates[j].morton > last, "updates not sorted/unique");
              last = fu.updates[j].morton;
              (fu.updates[j].hit ? occ_set : free_set).insert(last);
              CHECK(fu.box.contains(keyOfMorton(last)));
            }
            CHECK_MSG(occ_set == ref_occ, "occupied sets differ: " << occ_set.size() << " vs " << ref_occ.size());
            CHECK_MSG(free_set == ref_free, "free sets differ: " << free_set.size() << " vs " << ref_free.size());
            CHECK(fu.hits == occ_set.size() && fu.misses == free_set.size());
            CHECK(!free_set.empty() && (max_range > 0.0 || !occ_set.empty()));
          }
        }
      }
    }
  }
}

TEST(full_rays_match_stock_insert_point_cloud) {
  // Three overlapping frames, inserted twice (so that log-odds reach both clamping limits): every voxel's
  // log-odds after our insertion equals stock OctoMap's after OcTree::insertPointCloud (octomap_server's
  // update) with octomap_server's sensor model, in both backends.
  const SmallFrames f = smallFrames(3);
  const double res = 0.25;
  const SensorModel model;
  octomap::OcTree stock(res);
  stock.setProbHit(model.hit);
  stock.setProbMiss(model.miss);
  stock.setClampingThresMin(model.clamp_min);
  stock.setClampingThresMax(model.clamp_max);
  for (int pass = 0; pass < 2; ++pass) {
    for (std::size_t i = 0; i < f.map_points.size(); ++i) {
      octomap::Pointcloud pc;
      for (const Point3& p : f.map_points[i].xyz) pc.push_back(p);
      stock.insertPointCloud(pc, f.poses[i].origin(), -1.0, false, false);
    }
  }
  for (Backend b : {Backend::kOctomap, Backend::kOpenVdb}) {
    Mapper m(config(b, res, InsertMode::kFull));
    for (int pass = 0; pass < 2; ++pass) {
      for (std::size_t i = 0; i < f.map_points.size(); ++i)
        m.insertMapPoints(f.map_points[i], f.poses[i].origin(), 5.0 + i + 3 * pass);
    }
    std::size_t stock_voxels = 0;
    std::size_t occupied = 0;
    std::size_t at_max = 0;
    std::size_t at_min = 0;
    for (auto it = stock.begin_leafs(); it != stock.end_leafs(); ++it) {
      const unsigned size = 1U << (16 - it.getDepth());
      const int half = static_cast<int>(size / 2);
      for (unsigned dz = 0; dz < size; ++dz)
        for (unsigned dy = 0; dy < size; ++dy)
          for (unsigned dx = 0; dx < size; ++dx) {
            const Key k(static_cast<uint16_t>(it.getKey()[0] - half + dx), static_cast<uint16_t>(it.getKey()[1] - half + dy),
                        static_cast<uint16_t>(it.getKey()[2] - half + dz));
            VoxelState s;
            CHECK(m.map().query(k, s));
            CHECK_MSG(s.log_odds == it->getLogOdds(), "log-odds " << s.log_odds << " vs stock " << it->getLogOdds());
            ++stock_voxels;
            occupied += stock.isNodeOccupied(*it);
            at_max += it->getLogOdds() == m.map().logOdds().clamp_max;
            at_min += it->getLogOdds() == m.map().logOdds().clamp_min;
          }
    }
    CHECK(voxels(m.map()).size() == stock_voxels);
    CHECK(occupied > 100 && stock_voxels > 10 * occupied / 2);
    CHECK_MSG(at_max > 10 && at_min > 10, at_max << " voxels at the maximum, " << at_min << " at the minimum");
  }
}

TEST(truncated_rays_equal_octomap_key_sets) {
  // Truncated rays (the last `truncation` metres before each hit, OctoMap's own computeRayKeys) through one builder
  // frame after frame: the scan limited to bricks near the hits must find every free key and leave no cell set
  // behind for the next frame (a leftover would show up there as an extra free key).
  const SmallFrames f = smallFrames(4);
  for (double res : {0.1, 0.2, 0.5}) {
    for (double trunc : {0.3, 1.0, 2.0, 3.0}) {  // 0.1 m / 3 m: too far for the brick limit (every brick is read)
      for (double max_range : {-1.0, 23.0}) {
        FrameUpdateBuilder builder(res);
        octomap::OcTree tree(res);
        octomap::KeyRay ray;
        for (std::size_t i = 0; i < f.map_points.size(); ++i) {
          const Point3 origin = f.poses[i].origin();
          std::set<uint64_t> ref_free;
          std::set<uint64_t> ref_occ;
          for (const Point3& p : f.map_points[i].xyz) {
            const Point3 d = p - origin;
            const double dist = d.norm();
            if (max_range >= 0.0 && dist > max_range) continue;
            Point3 start = origin;
            const auto trunc_f = static_cast<float>(trunc);  // the builder's arithmetic
            if (dist > trunc_f) start = p - d * static_cast<float>(trunc_f / dist);
            if (tree.computeRayKeys(start, p, ray))
              for (const auto& k : ray) ref_free.insert(mortonOf(k));
            octomap::OcTreeKey k;
            if (tree.coordToKeyChecked(p, k)) ref_occ.insert(mortonOf(k));
          }
          for (uint64_t m : ref_occ) ref_free.erase(m);
          RayOptions ro;
          ro.mode = InsertMode::kTruncated;
          ro.truncation_m = trunc;
          ro.max_range_m = max_range;
          ro.threads = 2;
          FrameUpdate fu;
          builder.build(f.map_points[i], origin, ro, fu);
          CHECK(fu.used_byte_map);
          std::set<uint64_t> free_set;
          std::set<uint64_t> occ_set;
          for (const VoxelUpdate& u : fu.updates) (u.hit ? occ_set : free_set).insert(u.morton);
          CHECK_MSG(occ_set == ref_occ, "res " << res << " trunc " << trunc << " frame " << i << ": occupied sets differ");
          CHECK_MSG(free_set == ref_free, "res " << res << " trunc " << trunc << " frame " << i << ": free sets differ, "
                                                << free_set.size() << " vs " << ref_free.size());
          CHECK(!free_set.empty());
        }
      }
    }
  }
}

TEST(truncated_rays_clear_only_near_hits) {
  const double res = 0.5;
  Mapper m(config(Backend::kOctomap, res, InsertMode::kTruncated));
  // One vertical ray from 20 m down to a hit at z = 0.25 (voxel 0..0.5), truncation 3 m.
  m.insertMapPoints(cloud({P(0.25, 0.25, 0.25)}), P(0.25, 0.25, 20.0), 1.0);
  VoxelState s;
  CHECK(m.map().query(keyAt(res, 0.25, 0.25, 0.25), s) && m.map().isOccupied(s.log_odds));
  for (double z = 0.75; z < 3.25; z += 0.5) {
    CHECK_MSG(m.map().query(keyAt(res, 0.25, 0.25, z), s), "free voxel missing at z=" << z);
    CHECK(!m.map().isOccupied(s.log_odds));
  }
  for (double z = 3.75; z < 20.0; z += 0.5) CHECK_MSG(!m.map().query(keyAt(res, 0.25, 0.25, z), s), "z=" << z);
  CHECK(voxels(m.map()).size() == 7);  // hit + 6 free voxels (3 m / 0.5 m)
}

TEST(surface_mode_occupancy_color_and_time) {
  const double res = 0.5;
  for (Backend b : {Backend::kOctomap, Backend::kOpenVdb}) {
    Mapper m(config(b, res, InsertMode::kSurface));
    // Two points in one voxel (colours averaged), one point in another voxel.
    m.insertMapPoints(cloud({P(1.1, 2.1, 3.1), P(1.2, 2.2, 3.3), P(-4.0, 0.2, 0.1)},
                            {{100, 0, 10}, {200, 50, 30}, {7, 8, 9}}),
                      P(0, 0, 20), 100.25);
    CHECK(m.timeOrigin() == 100.0);
    CHECK(voxels(m.map()).size() == 2);  // no free space in surface mode
    VoxelState s;
    CHECK(m.map().query(keyAt(res, 1.1, 2.1, 3.1), s));
    CHECK(m.map().isOccupied(s.log_odds));
    CHECK(s.log_odds == m.map().logOdds().hit);
    CHECK(s.color_set && s.r == 150 && s.g == 25 && s.b == 20);
    CHECK(s.time_s == 0.25f);
    CHECK(m.map().query(keyAt(res, -4.0, 0.2, 0.1), s) && s.r == 7 && s.g == 8 && s.b == 9);
    // A later observation blends the colour (default weight 0.5) and moves the time.
    m.insertMapPoints(cloud({P(1.1, 2.1, 3.1)}, {{50, 25, 220}}), P(0, 0, 20), 101.5);
    CHECK(m.map().query(keyAt(res, 1.1, 2.1, 3.1), s));
    CHECK(s.r == 100 && s.g == 25 && s.b == 120);
    CHECK(s.time_s == 1.5f);
    CHECK(s.log_odds == std::min(2.0f * m.map().logOdds().hit, m.map().logOdds().clamp_max));
    // Points without colour leave the colour unset.
    m.insertMapPoints(cloud({P(9.0, 9.0, 1.0)}), P(0, 0, 20), 102.0);
    CHECK(m.map().query(keyAt(res, 9.0, 9.0, 1.0), s) && !s.color_set);
  }
}

TEST(log_odds_clamp_and_top_voxel_turning_free) {
  const double res = 0.5;
  for (Backend b : {Backend::kOctomap, Backend::kOpenVdb}) {
    Mapper m(config(b, res, InsertMode::kFull));
    const LogOddsModel& lo = m.map().logOdds();
    // A "roof" seen 10 times: clamps at the maximum; the column's elevation is the roof voxel's centre.
    for (int i = 0; i < 10; ++i) m.insertMapPoints(cloud({P(0.25, 0.25, 10.2)}), P(0.25, 0.25, 30.0), i);
    VoxelState s;
    CHECK(m.map().query(keyAt(res, 0.25, 0.25, 10.2), s) && s.log_odds == lo.clamp_max);
    LayersSnapshot layers = m.layers();
    CHECK(layers.width == 1 && layers.height == 1);
    CHECK(layers.elevation_m[0] == 10.25f);
    // The roof is gone: rays now pass through it to the ground at z = 0.2. After enough misses the roof voxel
    // is free and the elevation drops to the ground voxel.
    int frames = 0;
    while (true) {
      m.insertMapPoints(cloud({P(0.25, 0.25, 0.2)}), P(0.25, 0.25, 30.0), 20.0 + frames);
      ++frames;
      CHECK(m.map().query(keyAt(res, 0.25, 0.25, 10.2), s));
      if (!m.map().isOccupied(s.log_odds)) break;
      CHECK(frames < 20);
      CHECK(m.layers().elevation_m[0] == 10.25f);
    }
    // OctoMap's log-odds: clamp max, then `frames` misses until below the threshold.
    float expected = lo.clamp_max;
    for (int i = 0; i < frames; ++i) expected += lo.miss;
    CHECK(s.log_odds == expected);
    layers = m.layers();
    CHECK(layers.elevation_m[0] == 0.25f);
    CHECK(layers.last_seen_s[0] == 20.0f + frames - 1);
    // Many more misses clamp at the minimum.
    for (int i = 0; i < 30; ++i) m.insertMapPoints(cloud({P(0.25, 0.25, 0.2)}), P(0.25, 0.25, 30.0), 60.0 + i);
    CHECK(m.map().query(keyAt(res, 0.25, 0.25, 10.2), s) && s.log_odds == lo.clamp_min);
    CHECK(m.map().query(keyAt(res, 0.25, 0.25, 29.9), s) && s.log_odds == lo.clamp_min);  // just below the origin
  }
}

TEST(layers_values_nan_and_growth) {
  const double res = 0.5;
  Mapper m(config(Backend::kOctomap, res, InsertMode::kSurface));
  CHECK(m.layers().width == 0);
  m.insertMapPoints(cloud({P(0.1, 0.1, 1.1), P(0.1, 0.1, 2.6), P(1.6, 0.1, -0.3)}), P(0, 0, 20), 7.0);
  LayersSnapshot l = m.layers();
  CHECK(l.resolution_m == 0.5 && l.origin_x_m == 0.0 && l.origin_y_m == 0.0);
  CHECK(l.width == 4 && l.height == 1);  // x cells 0..3 (the observed box), one row
  CHECK(l.elevation_m[0] == 2.75f);      // max occupied z per column (voxel centre)
  CHECK(std::isnan(l.elevation_m[1]) && l.observed[1] == 0.0f && std::isnan(l.last_seen_s[1]));
  CHECK(l.elevation_m[3] == -0.25f && l.observed[3] == 1.0f && l.last_seen_s[3] == 7.0f);
  // The map grows west and north: the layers grow with it (origin moves).
  m.insertMapPoints(cloud({P(-100.2, 60.1, 0.0)}), P(0, 0, 20), 8.0);
  l = m.layers();
  CHECK(l.origin_x_m == -100.5 && l.origin_y_m == 0.0);
  CHECK(l.width == 205 && l.height == 121);
  const std::size_t row = 120;  // y = 60.1 -> row 120 (rows count northwards)
  CHECK(l.elevation_m[row * l.width + 0] == 0.25f && l.last_seen_s[row * l.width + 0] == 8.0f);
  CHECK(l.elevation_m[0 * l.width + 201] == 2.75f);  // the first column kept its values after the growth
  // Coarsened layers (factor 4): max elevation, max time, any observed.
  const LayersSnapshot c = m.layers(4);
  CHECK(c.resolution_m == 2.0 && c.origin_x_m == -102.0);
  const std::size_t col = static_cast<std::size_t>((0.1 - c.origin_x_m) / 2.0);
  CHECK(c.elevation_m[col] == 2.75f && c.observed[col] == 1.0f);
}

TEST(layers_incremental_equal_rebuild) {
  const SmallFrames f = smallFrames(4);
  for (Backend b : {Backend::kOctomap, Backend::kOpenVdb}) {
    for (InsertMode mode : {InsertMode::kFull, InsertMode::kTruncated, InsertMode::kSurface}) {
      Mapper m(config(b, 0.25, mode));
      for (std::size_t i = 0; i < f.map_points.size(); ++i) m.insertMapPoints(f.map_points[i], f.poses[i].origin(), 3.0 * i);
      ColumnLayers rebuilt(0.25);
      rebuilt.rebuild(m.map());
      checkSameLayers(m.layers(), rebuilt.snapshot(1, m.timeOrigin()));
      checkSameLayers(m.layers(3), rebuilt.snapshot(3, m.timeOrigin()));
      std::size_t known = 0;
      for (float e : m.layers().elevation_m) known += !std::isnan(e);
      CHECK(known > 500);
    }
  }
}

TEST(backends_agree) {
  const SmallFrames f = smallFrames(4);
  for (InsertMode mode : {InsertMode::kFull, InsertMode::kTruncated, InsertMode::kSurface}) {
    Mapper octo(config(Backend::kOctomap, 0.25, mode));
    Mapper vdb(config(Backend::kOpenVdb, 0.25, mode));
    for (std::size_t i = 0; i < f.map_points.size(); ++i) {
      octo.insertMapPoints(f.map_points[i], f.poses[i].origin(), 1.0 + i);
      vdb.insertMapPoints(f.map_points[i], f.poses[i].origin(), 1.0 + i);
    }
    checkSameVoxels(octo.map(), vdb.map());
    CHECK(octo.occupiedCells(0.25) == vdb.occupiedCells(0.25));
    checkSameLayers(octo.layers(), vdb.layers());
  }
}

TEST(pruning_keeps_values) {
  // A flat floor seen from above: large uniform free regions. Pruned and unpruned maps hold the same voxels;
  // the pruned ones store fewer leaves.
  std::vector<Point3> floor_pts;
  for (double x = -8; x < 8; x += 0.1)
    for (double y = -8; y < 8; y += 0.1) floor_pts.push_back(P(x, y, 0.05));
  for (Backend b : {Backend::kOctomap, Backend::kOpenVdb}) {
    MapperConfig c = config(b, 0.25, InsertMode::kFull);
    Mapper pruned(c);
    c.prune = false;
    Mapper plain(c);
    for (int i = 0; i < 2; ++i) {
      pruned.insertMapPoints(cloud(floor_pts), P(0.1, 0.1, 12.0), i);
      plain.insertMapPoints(cloud(floor_pts), P(0.1, 0.1, 12.0), i);
    }
    checkSameVoxels(pruned.map(), plain.map());
    CHECK_MSG(pruned.map().leafCount() * 5 < plain.map().leafCount() * 4,
              pruned.map().leafCount() << " vs " << plain.map().leafCount());
    CHECK(pruned.map().memoryBytes() < plain.map().memoryBytes());
  }
}

// ---------------------------------------------------------------------------------------------------------
// Persistence and serialisation

Mapper filledMapper(Backend b, InsertMode mode = InsertMode::kTruncated) {
  const SmallFrames f = smallFrames(3);
  Mapper m(config(b, 0.25, mode));
  for (std::size_t i = 0; i < f.map_points.size(); ++i) m.insertMapPoints(f.map_points[i], f.poses[i].origin(), 1000.5 + i);
  return m;
}

TEST(save_load_round_trip_ot) {
  Mapper a = filledMapper(Backend::kOctomap);
  const std::string path = tempPath("map.ot");
  a.save(path);
  Mapper b(config(Backend::kOctomap, 0.25, InsertMode::kTruncated));
  b.load(path);
  checkSameVoxels(a.map(), b.map());
  CHECK(b.timeOrigin() == a.timeOrigin());
  checkSameLayers(a.layers(), b.layers());
  // Standard OctoMap reads the same file as a ColorOcTree with the same log-odds and colours.
  std::unique_ptr<octomap::AbstractOcTree> generic(octomap::AbstractOcTree::read(path));
  CHECK(generic != nullptr);
  auto* color_tree = dynamic_cast<octomap::ColorOcTree*>(generic.get());
  CHECK(color_tree != nullptr);
  std::size_t checked = 0;
  for (auto it = color_tree->begin_leafs(); it != color_tree->end_leafs(); ++it) {
    VoxelState s;
    CHECK(a.map().query(it.getKey(), s));
    CHECK(s.log_odds == it->getLogOdds());
    if (s.color_set) CHECK(it->getColor() == octomap::ColorOcTreeNode::Color(s.r, s.g, s.b));
    ++checked;
  }
  CHECK(checked == a.map().leafCount());
  // Saving the loaded map again gives the identical file.
  const std::string path2 = tempPath("map2.ot");
  b.save(path2);
  std::ifstream f1(path, std::ios::binary);
  std::ifstream f2(path2, std::ios::binary);
  const std::string s1((std::istreambuf_iterator<char>(f1)), std::istreambuf_iterator<char>());
  const std::string s2((std::istreambuf_iterator<char>(f2)), std::istreambuf_iterator<char>());
  CHECK(s1 == s2 && !s1.empty());
  std::remove(path.c_str());
  std::remove(path2.c_str());
}

TEST(save_load_bt_is_standard_binary) {
  Mapper a = filledMapper(Backend::kOctomap);
  const std::string path = tempPath("map.bt");
  a.save(path);
  octomap::OcTree stock(0.1);
  CHECK(stock.readBinary(path));  // stock reader (checks the header id and node count)
  CHECK(stock.getResolution() == 0.25);
  Mapper b(config(Backend::kOctomap, 0.25, InsertMode::kTruncated));
  b.load(path);
  // .bt keeps only the maximum-likelihood occupancy: same occupied / free voxels, no colour or time.
  const auto va = voxels(a.map());
  const auto vb = voxels(b.map());
  CHECK(va.size() == vb.size());
  for (const auto& [k, s] : va) {
    const auto& t = vb.at(k);
    CHECK(a.map().isOccupied(s.log_odds) == b.map().isOccupied(t.log_odds));
    CHECK(t.time_s == kNoTime && !t.color_set);
    VoxelState st;
    octomap::OcTreeNode* n = stock.search(keyOfMorton(k));
    CHECK(n != nullptr && stock.isNodeOccupied(n) == a.map().isOccupied(s.log_odds));
    (void)st;
  }
  std::remove(path.c_str());
}

TEST(save_load_round_trip_vdb) {
  Mapper a = filledMapper(Backend::kOpenVdb);
  const std::string path = tempPath("map.vdb");
  a.save(path);
  Mapper b(config(Backend::kOpenVdb, 0.25, InsertMode::kTruncated));
  b.load(path);
  checkSameVoxels(a.map(), b.map());
  CHECK(b.timeOrigin() == a.timeOrigin());
  checkSameLayers(a.layers(), b.layers());
  // The same content as the octree after the same frames.
  Mapper o = filledMapper(Backend::kOctomap);
  checkSameVoxels(o.map(), b.map());
  std::remove(path.c_str());
}

TEST(load_errors_keep_the_map) {
  for (Backend backend : {Backend::kOctomap, Backend::kOpenVdb}) {
    Mapper a = filledMapper(backend, InsertMode::kSurface);
    const auto before = voxels(a.map());
    const std::string ext = backend == Backend::kOctomap ? ".ot" : ".vdb";
    checkThrows([&] { a.load(tempPath("does_not_exist") + ext); }, "missing file");
    checkThrows([&] { a.load(tempPath("x.txt")); }, "wrong extension");
    checkThrows([&] { a.save(tempPath("x.txt")); }, "wrong extension on save");
    checkThrows([&] { a.save("/nonexistent_dir/map" + ext); }, "unwritable path");
    const std::string garbage = tempPath("garbage") + ext;
    writeFileAtomically(garbage, "this is not a map\n");
    checkThrows([&] { a.load(garbage); }, "garbage file");
    // A truncated file.
    const std::string good = tempPath("good") + ext;
    a.save(good);
    std::ifstream in(good, std::ios::binary);
    std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    for (std::size_t cut : {bytes.size() / 10, bytes.size() / 2, bytes.size() * 9 / 10, bytes.size() - 1}) {
      writeFileAtomically(garbage, bytes.substr(0, cut));
      checkThrows([&] { a.load(garbage); }, "truncated file");
    }
    // Another resolution.
    Mapper other(config(backend, 0.5, InsertMode::kSurface));
    checkThrows([&] { other.load(good); }, "resolution mismatch");
    CHECK(voxels(a.map()).size() == before.size());
    std::remove(garbage.c_str());
    std::remove(good.c_str());
  }
}

TEST(octomap_message_payloads_are_standard) {
  Mapper a = filledMapper(Backend::kOctomap);
  const auto& map = dynamic_cast<const OctreeMap&>(a.map());
  // octomap_binary: OcTree binary data.
  std::stringstream bin;
  map.writeBinaryData(bin);
  octomap::OcTree tree(0.25);
  tree.readBinaryData(bin);
  CHECK(tree.size() == map.tree().size());
  // octomap_full: ColorOcTree data.
  std::stringstream full;
  map.writeFullData(full);
  octomap::ColorOcTree ctree(0.25);
  ctree.readData(full);
  CHECK(ctree.size() == map.tree().size());
  for (auto it = tree.begin_leafs(); it != tree.end_leafs(); ++it) {
    VoxelState s;
    CHECK(a.map().query(it.getKey(), s));
    CHECK(tree.isNodeOccupied(*it) == a.map().isOccupied(s.log_odds));
    CHECK(ctree.search(it.getKey())->getLogOdds() == s.log_odds);
  }
  // The OpenVDB map converts to the same tree.
  Mapper v = filledMapper(Backend::kOpenVdb);
  UavOcTree converted(0.25);
  copyLeavesToTree(v.map(), converted);
  std::stringstream vbin;
  converted.writeBinaryData(vbin);
  octomap::OcTree vtree(0.25);
  vtree.readBinaryData(vbin);
  std::size_t n = 0;
  for (auto it = vtree.begin_leafs(); it != vtree.end_leafs(); ++it) {
    VoxelState s;
    CHECK(a.map().query(it.getKey(), s));
    CHECK(vtree.isNodeOccupied(*it) == a.map().isOccupied(s.log_odds));
    ++n;
  }
  CHECK(n > 1000);
}

// ---------------------------------------------------------------------------------------------------------
// clear_bbx, reset, export

TEST(clear_box_frees_only_inside) {
  for (Backend b : {Backend::kOctomap, Backend::kOpenVdb}) {
    Mapper m = filledMapper(b, InsertMode::kFull);
    const auto before = voxels(m.map());
    const std::array<double, 3> lo{28.0, 20.0, -50.0};
    const std::array<double, 3> hi{32.0, 26.0, 50.0};
    const std::size_t changed = m.clearBox(lo, hi);
    CHECK(changed > 0);
    const auto after = voxels(m.map());
    CHECK(after.size() == before.size());  // known voxels stay known; unknown stay unknown
    // Like octomap_server: the voxels containing the box corners are included.
    const Key klo = keyAt(0.25, lo[0], lo[1], 0.0);
    const Key khi = keyAt(0.25, hi[0], hi[1], 0.0);
    std::size_t inside = 0;
    for (const auto& [k, s] : after) {
      const Key key = keyOfMorton(k);
      const bool in = key[0] >= klo[0] && key[0] <= khi[0] && key[1] >= klo[1] && key[1] <= khi[1];
      if (in) {
        CHECK(s.log_odds == m.map().logOdds().clamp_min);
        ++inside;
      } else {
        CHECK(sameState(s, before.at(k)));
      }
    }
    CHECK(inside > 100);
    // Elevation is unknown inside the box now, still known outside.
    const LayersSnapshot l = m.layers();
    const auto cell = [&](double x, double y) {
      return static_cast<std::size_t>((y - l.origin_y_m) / l.resolution_m) * l.width +
             static_cast<std::size_t>((x - l.origin_x_m) / l.resolution_m);
    };
    CHECK(std::isnan(l.elevation_m[cell(30.1, 23.1)]) && l.observed[cell(30.1, 23.1)] == 1.0f);
    CHECK(!std::isnan(l.elevation_m[cell(35.1, 23.1)]));
    ColumnLayers rebuilt(0.25);
    rebuilt.rebuild(m.map());
    checkSameLayers(l, rebuilt.snapshot(1, m.timeOrigin()));
  }
}

TEST(reset_forgets_everything) {
  for (Backend b : {Backend::kOctomap, Backend::kOpenVdb}) {
    Mapper m = filledMapper(b);
    CHECK(m.map().leafCount() > 0);
    m.reset();
    CHECK(m.map().leafCount() == 0 && voxels(m.map()).empty());
    CHECK(m.layers().width == 0 && std::isnan(m.timeOrigin()));
    m.insertMapPoints(cloud({P(1, 1, 1)}), P(0, 0, 10), 5.0);
    CHECK(m.timeOrigin() == 5.0 && m.map().leafCount() > 0);
  }
}

std::vector<std::array<int32_t, 3>> readNpy(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  CHECK(bytes.compare(0, 6, "\x93NUMPY") == 0);
  const std::size_t header_len = static_cast<uint8_t>(bytes[8]) | (static_cast<uint8_t>(bytes[9]) << 8);
  CHECK((10 + header_len) % 64 == 0);
  const std::string header = bytes.substr(10, header_len);
  CHECK(header.find("'descr': '<i4'") != std::string::npos);
  const std::size_t n = (bytes.size() - 10 - header_len) / 12;
  CHECK(header.find("'shape': (" + std::to_string(n) + ", 3)") != std::string::npos);
  std::vector<std::array<int32_t, 3>> rows(n);
  std::memcpy(rows.data(), bytes.data() + 10 + header_len, n * 12);
  return rows;
}

TEST(export_occupied_cells) {
  const double res = 0.5;
  Mapper m(config(Backend::kOctomap, res, InsertMode::kSurface));
  m.insertMapPoints(cloud({P(0.1, 0.1, 0.1), P(0.6, 0.1, 0.1), P(-0.2, 3.3, 1.6), P(10.0, 10.0, 10.0)}), P(0, 0, 50),
                    1.0);
  // At the map resolution: the voxel indices (key - 32768).
  const auto cells = m.occupiedCells(res);
  const std::vector<std::array<int32_t, 3>> expected = {{-1, 6, 3}, {0, 0, 0}, {1, 0, 0}, {20, 20, 20}};
  CHECK(cells == expected);
  // Coarser (1 m): voxel centres 0.25 and 0.75 share cell 0.
  const auto coarse = m.occupiedCells(1.0);
  const std::vector<std::array<int32_t, 3>> expected_coarse = {{-1, 3, 1}, {0, 0, 0}, {10, 10, 10}};
  CHECK(coarse == expected_coarse);
  // Finer (0.25 m): 8 cells per voxel.
  CHECK(m.occupiedCells(0.25).size() == 32);
  const std::string path = tempPath("occupied.npy");
  CHECK(m.exportOccupied(path, res, "map") == 4);
  CHECK(readNpy(path) == expected);
  std::ifstream json(path + ".json");
  std::string text((std::istreambuf_iterator<char>(json)), std::istreambuf_iterator<char>());
  CHECK(text.find("\"count\": 4") != std::string::npos && text.find("\"resolution_m\": 0.5") != std::string::npos);
  std::remove(path.c_str());
  std::remove((path + ".json").c_str());
  checkThrows([&] { m.occupiedCells(0.0); }, "zero resolution");
}

// ---------------------------------------------------------------------------------------------------------
// Filtering and bad input

TEST(filters_drop_bad_points_and_count_them) {
  MapperConfig c = config(Backend::kOctomap, 0.5, InsertMode::kSurface);
  c.filter.min_z_m = -1.0;
  c.filter.max_z_m = 30.0;
  c.filter.min_range_m = 1.0;
  Mapper m(c);
  RigidTransform tf;  // identity rotation, sensor at (0, 0, 10)
  tf.t[2] = 10.0;
  const float nan = std::nanf("");
  const float inf = INFINITY;
  ColoredPoints pts = cloud({P(0, 0, 5), P(nan, 0, 1), P(0, inf, 1), P(0, 0, 0.5), P(0, 0, -20), P(0, 0, 25), P(1e9, 0, 0)});
  const InsertStats st = m.insert(pts, tf, 1.0);
  CHECK(st.filter.points_in == 7);
  CHECK(st.filter.nonfinite == 2);
  CHECK(st.filter.too_close == 1);   // 0.5 m from the sensor
  CHECK(st.filter.outside_box == 2);  // z = -10 and z = 35 in the map frame
  CHECK(st.points_inserted == 2);
  CHECK(st.points_out_of_map == 1);  // x = 1e9 m is outside the key cube
  CHECK(voxels(m.map()).size() == 1);
  // An empty cloud is a no-op.
  const InsertStats empty = m.insert(ColoredPoints(), tf, 2.0);
  CHECK(empty.points_inserted == 0 && m.framesInserted() == 1);
}

TEST(points_outside_the_key_cube_count_once) {
  for (InsertMode mode : {InsertMode::kFull, InsertMode::kTruncated, InsertMode::kSurface}) {
    Mapper m(config(Backend::kOctomap, 0.5, mode));
    const InsertStats st = m.insertMapPoints(cloud({P(1e6, 0, 0), P(1.1, 1.1, 1.1), P(0, -3e5, 2)}), P(0, 0, 10), 1.0);
    CHECK_MSG(st.points_out_of_map == 2, toString(mode) << ": " << st.points_out_of_map);
    CHECK(st.hits == 1);
    CHECK(st.rays == (mode == InsertMode::kSurface ? 0U : 1U));
  }
}

TEST(voxel_grid_filter_downsamples) {
  ColoredPoints pts;
  for (int i = 0; i < 10; ++i) {
    pts.xyz.push_back(P(0.1 + 0.01 * i, 0.1, 0.1));
    pts.rgb.push_back({static_cast<uint8_t>(10 * i), 0, 200});
  }
  pts.xyz.push_back(P(5.1, 0.1, 0.1));
  pts.rgb.push_back({1, 2, 3});
  FilterStats st;
  voxelGridFilter(pts, 0.5, st);
  CHECK(pts.size() == 2 && st.points_out == 2);
  std::size_t first = pts.xyz[0](0) < 1.0 ? 0 : 1;
  CHECK(std::fabs(pts.xyz[first](0) - 0.145f) < 1e-4);
  CHECK(std::abs(pts.rgb[first][0] - 45) <= 1 && pts.rgb[first][2] == 200);
  // Extents that would overflow PCL's int32 voxel index are left alone (and reported).
  ColoredPoints huge = cloud({P(0, 0, 0), P(5000, 5000, 5000)});
  FilterStats st2;
  voxelGridFilter(huge, 0.01, st2);
  CHECK(st2.voxel_grid_skipped && huge.size() == 2);
  // So are clouds whose leaf indices do not fit int32 (a broken transform; this used to crash the column map).
  for (VoxelFilterImpl impl : {VoxelFilterImpl::kFast, VoxelFilterImpl::kPcl}) {
    ColoredPoints remote;
    for (int i = 0; i < 100; ++i) remote.xyz.push_back(P(1e9 + 64.0 * i, 0.0, 0.0));
    FilterStats st3;
    voxelGridFilter(remote, 0.25, st3, impl);
    CHECK(st3.voxel_grid_skipped && remote.size() == 100 && st3.points_out == 100);
  }
}

/// Points (one per voxel-grid leaf) in the leaf order of floor(p / leaf) by (z, y, x), as PCL orders its leaves.
void sortByLeaf(ColoredPoints& pts, double leaf) {
  std::vector<std::size_t> order(pts.size());
  for (std::size_t i = 0; i < order.size(); ++i) order[i] = i;
  const auto inv = static_cast<float>(1.0 / leaf);
  auto key = [&](std::size_t i) {
    const Point3& p = pts.xyz[i];
    return std::array<int64_t, 3>{static_cast<int64_t>(std::floor(p(2) * inv)),
                                  static_cast<int64_t>(std::floor(p(1) * inv)),
                                  static_cast<int64_t>(std::floor(p(0) * inv))};
  };
  std::sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) { return key(a) < key(b); });
  ColoredPoints out;
  for (std::size_t i : order) {
    out.xyz.push_back(pts.xyz[i]);
    if (pts.hasColor()) out.rgb.push_back(pts.rgb[i]);
  }
  pts = out;
}

TEST(fast_voxel_grid_reproduces_pcl_voxel_grid) {
  // Realistic frames (a nadir camera over buildings and trees; oblique too) at several leaf sizes: the same
  // leaves in the same order, centroids equal up to float summation order, colours within one level.
  const SmallFrames f = smallFrames(3, 25.0, 160, 120);
  std::size_t compared = 0;
  for (double leaf : {0.25, 0.5, 1.0}) {
    for (std::size_t i = 0; i < f.map_points.size(); ++i) {
      ColoredPoints fast = f.map_points[i];
      ColoredPoints ref = f.map_points[i];
      // shuffle part of the cloud so leaves are not only runs of neighbouring points
      std::reverse(fast.xyz.begin(), fast.xyz.begin() + fast.size() / 3);
      std::reverse(fast.rgb.begin(), fast.rgb.begin() + fast.size() / 3);
      std::reverse(ref.xyz.begin(), ref.xyz.begin() + ref.size() / 3);
      std::reverse(ref.rgb.begin(), ref.rgb.begin() + ref.size() / 3);
      FilterStats sf;
      FilterStats sr;
      voxelGridFilter(fast, leaf, sf, VoxelFilterImpl::kFast);
      voxelGridFilter(ref, leaf, sr, VoxelFilterImpl::kPcl);
      // kFast emits leaves in first-hit order, PCL in leaf index order: compare in leaf index order
      sortByLeaf(fast, leaf);
      sortByLeaf(ref, leaf);
      CHECK_MSG(fast.size() == ref.size() && sf.points_out == sr.points_out,
                "leaf " << leaf << ": " << fast.size() << " vs " << ref.size() << " points");
      CHECK(fast.size() < f.map_points[i].size() && fast.size() > 50);
      for (std::size_t k = 0; k < std::min(fast.size(), ref.size()); ++k) {
        const float d = (fast.xyz[k] - ref.xyz[k]).norm();
        CHECK_MSG(d < 1e-4f, "leaf " << leaf << " point " << k << " differs by " << d << " m");
        for (int c = 0; c < 3; ++c) CHECK(std::abs(int(fast.rgb[k][c]) - int(ref.rgb[k][c])) <= 1);
        ++compared;
      }
    }
  }
  CHECK(compared > 1000);
  // A cloud too wide for kFast's column map (two far returns make it 2.4 km across at 1 m leaves: 5.8 M columns)
  // takes its sorting variant: the same leaves again.
  ColoredPoints wide = f.map_points[0];
  for (float s : {-1200.0f, 1200.0f}) {
    wide.xyz.emplace_back(s, s, wide.xyz[0](2));
    wide.rgb.push_back({10, 20, 30});
  }
  ColoredPoints wide_ref = wide;
  FilterStats sw;
  FilterStats swr;
  voxelGridFilter(wide, 1.0, sw, VoxelFilterImpl::kFast);
  voxelGridFilter(wide_ref, 1.0, swr, VoxelFilterImpl::kPcl);
  CHECK(!sw.voxel_grid_skipped && wide.size() == wide_ref.size() && wide.size() > 100);
  sortByLeaf(wide, 1.0);
  sortByLeaf(wide_ref, 1.0);
  for (std::size_t k = 0; k < std::min(wide.size(), wide_ref.size()); ++k)
    CHECK_MSG((wide.xyz[k] - wide_ref.xyz[k]).norm() < 1e-4f, "wide cloud point " << k);
  CHECK(voxelFilterImplFromString("pcl") == VoxelFilterImpl::kPcl && toString(VoxelFilterImpl::kFast) == "fast");
  bool threw = false;
  try {
    voxelFilterImplFromString("quick");
  } catch (const std::invalid_argument&) {
    threw = true;
  }
  CHECK(threw);
}

TEST(pipeline_with_voxel_grid_matches_map_frame_insert) {
  // Mapper::insert on optical-frame points (transform + filters) equals inserting the transformed points.
  const SmallFrames f = smallFrames(2);
  Mapper a(config(Backend::kOctomap, 0.25, InsertMode::kFull));
  Mapper b(config(Backend::kOctomap, 0.25, InsertMode::kFull));
  for (std::size_t i = 0; i < 2; ++i) {
    a.insert(f.optical[i], f.poses[i], 1.0 + i);
    b.insertMapPoints(f.map_points[i], f.poses[i].origin(), 1.0 + i);
  }
  checkSameVoxels(a.map(), b.map());
  MapperConfig c = config(Backend::kOctomap, 0.25, InsertMode::kSurface);
  c.filter.voxel_leaf_m = 1.0;
  Mapper d(c);
  const InsertStats st = d.insert(f.optical[0], f.poses[0], 1.0);
  CHECK(st.points_inserted < st.filter.points_in && st.points_inserted > 100);
}

// ---------------------------------------------------------------------------------------------------------
// The fused depth-image front end against the three stages it replaces

/// The reference: back-projection, transform + filters, voxel grid, one after the other.
void threeStageFrontEnd(const DepthImageView& depth, const ColorImageView& color, const PinholeIntrinsics& k,
                        const RigidTransform& tf, const FilterOptions& options, ColoredPoints& out,
                        FilterStats& stats) {
  ColoredPoints optical;
  depthToOpticalPoints(depth, color, k, optical);
  transformAndFilter(optical, tf, options, out, stats);
  voxelGridFilter(out, options.voxel_leaf_m, stats, options.voxel_impl);
}

bool sameBits(float a, float b) { return std::memcmp(&a, &b, sizeof(float)) == 0; }

/// Fused == three stages: every float bit for bit (signed zeros included), colours, order and all stats.
/// Returns the fused result's size.
std::size_t checkFusedEqualsThreeStages(const DepthImageView& depth, const ColorImageView& color,
                                        const PinholeIntrinsics& k, const RigidTransform& tf,
                                        const FilterOptions& options, const std::string& what,
                                        FilterStats* stats_out = nullptr, DepthFrontEndPath* path_out = nullptr) {
  ColoredPoints ref;
  ColoredPoints fused;
  FilterStats sr;
  FilterStats sf;
  threeStageFrontEnd(depth, color, k, tf, options, ref, sr);
  fused.xyz.push_back(P(1, 2, 3));  // stale content must go
  const DepthFrontEndPath path = filterDepthImage(depth, color, k, tf, options, fused, sf);
  CHECK_MSG(sf.points_in == sr.points_in && sf.nonfinite == sr.nonfinite && sf.too_close == sr.too_close &&
                sf.outside_box == sr.outside_box && sf.points_out == sr.points_out &&
                sf.voxel_grid_skipped == sr.voxel_grid_skipped,
            what << ": stats in/nonfinite/close/box/out/skipped " << sf.points_in << "/" << sf.nonfinite << "/"
                 << sf.too_close << "/" << sf.outside_box << "/" << sf.points_out << "/" << sf.voxel_grid_skipped
                 << " vs " << sr.points_in << "/" << sr.nonfinite << "/" << sr.too_close << "/" << sr.outside_box
                 << "/" << sr.points_out << "/" << sr.voxel_grid_skipped);
  CHECK_MSG(fused.size() == ref.size() && fused.rgb.size() == ref.rgb.size(),
            what << ": " << fused.size() << " vs " << ref.size() << " points, " << fused.rgb.size() << " vs "
                 << ref.rgb.size() << " colours");
  for (std::size_t i = 0; i < ref.size(); ++i) {
    for (int a = 0; a < 3; ++a)
      CHECK_MSG(sameBits(fused.xyz[i](a), ref.xyz[i](a)),
                what << ": point " << i << " axis " << a << ": " << fused.xyz[i](a) << " vs " << ref.xyz[i](a));
    if (ref.hasColor()) CHECK_MSG(fused.rgb[i] == ref.rgb[i], what << ": colour of point " << i);
  }
  if (stats_out != nullptr) *stats_out = sf;
  if (path_out != nullptr) *path_out = path;
  return fused.size();
}

/// A depth image with padded rows (step > width x bytes) in either encoding, and a colour image of each kind.
struct TestImages {
  uint32_t width = 0;
  uint32_t height = 0;
  std::vector<uint8_t> depth;
  std::size_t depth_step = 0;
  DepthEncoding encoding = DepthEncoding::kFloat32Metres;
  std::vector<uint8_t> color;
  std::size_t color_step = 0;

  DepthImageView depthView() const { return DepthImageView{depth.data(), width, height, depth_step, encoding}; }
  ColorImageView colorView(ColorEncoding e) const { return ColorImageView{color.data(), color_step, e}; }

  void setDepth(uint32_t u, uint32_t v, float z) {
    uint8_t* px = depth.data() + v * depth_step;
    if (encoding == DepthEncoding::kFloat32Metres) {
      std::memcpy(px + 4 * u, &z, 4);
    } else {
      const uint16_t mm = std::isfinite(z) && z > 0.0f ? static_cast<uint16_t>(std::min(65535.0f, z * 1000.0f)) : 0;
      std::memcpy(px + 2 * u, &mm, 2);
    }
  }
};

TestImages testImages(uint32_t width, uint32_t height, DepthEncoding encoding, uint32_t seed, float typical_m) {
  TestImages im;
  im.width = width;
  im.height = height;
  im.encoding = encoding;
  im.depth_step = width * (encoding == DepthEncoding::kFloat32Metres ? 4 : 2) + 6;  // padded rows
  im.depth.assign(im.depth_step * height, 0xAB);
  im.color_step = width * 4 + 5;  // enough for 4 channels, padded
  im.color.resize(im.color_step * height);
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> unit(0.0f, 1.0f);
  for (auto& c : im.color) c = static_cast<uint8_t>(rng() & 0xFF);
  // (huge depths come only at the left and right edges below: kept ones would leave the fused pass's window)
  const float specials[] = {std::nanf(""), INFINITY, -INFINITY, 0.0f, -0.0f, -1.5f, 1e-40f};
  for (uint32_t v = 0; v < height; ++v) {
    for (uint32_t u = 0; u < width; ++u) {
      const float r = unit(rng);
      float z;
      if (r < 0.08f) {
        z = specials[rng() % (sizeof(specials) / sizeof(specials[0]))];
      } else if (r < 0.15f) {
        z = 0.05f + 2.0f * unit(rng);  // near: min_range
      } else {
        // a smooth surface with steps, so pixels share voxel-grid leaves as a camera's do
        z = typical_m * (1.0f + 0.2f * std::sin(0.05f * static_cast<float>(u)) + (((u / 16) + (v / 12)) % 3) * 0.05f) +
            0.01f * unit(rng);
      }
      im.setDepth(u, v, z);
    }
    // 3e38 m where |x_n| > 1.2: z * x_n overflows float, a non-finite point (32FC1 only; 16UC1 saturates)
    if (v % 5 == 0) {
      im.setDepth(0, v, 3e38f);
      im.setDepth(width - 1, v, 3e38f);
    }
  }
  return im;
}

/// A proper rotation from a random unit quaternion (fromMsg's formula) and a translation.
RigidTransform randomTransform(std::mt19937& rng, double t_scale_m) {
  std::normal_distribution<double> g(0.0, 1.0);
  const double w = g(rng), x = g(rng), y = g(rng), z = g(rng);
  const double tx = t_scale_m * g(rng), ty = t_scale_m * g(rng), tz = t_scale_m * g(rng);
  return RigidTransform::fromQuaternion(w, x, y, z, tx, ty, tz);
}

TEST(fused_depth_front_end_equals_three_stages_on_synthetic_images) {
  // NaN, +-inf, 0, -0, negative, denormal and overflowing depths (z * x_n = inf), 32FC1 and 16UC1, no colour
  // and all four colour encodings, padded rows, random rotations, min_range, a box, leaves 0 (off), 0.25, 0.5
  // and 1 m, and voxel_filter: pcl.
  std::mt19937 rng(11);
  std::size_t cases = 0;
  std::size_t points_out = 0;
  for (DepthEncoding enc : {DepthEncoding::kFloat32Metres, DepthEncoding::kUint16Millimetres}) {
    const TestImages im = testImages(97, 61, enc, 5 + static_cast<uint32_t>(enc), 12.0f);
    const PinholeIntrinsics k{30.0, 29.0, 48.3, 29.7};  // |x_n| up to 1.6
    for (int color = -1; color < 4; ++color) {
      const ColorImageView cv = color < 0 ? ColorImageView() : im.colorView(static_cast<ColorEncoding>(color));
      for (int variant = 0; variant < 6; ++variant) {
        const RigidTransform tf = variant == 0 ? RigidTransform() : randomTransform(rng, variant < 4 ? 20.0 : 400.0);
        FilterOptions o;
        if (variant % 2 == 1) o.min_range_m = 1.5;
        if (variant >= 2) {
          o.min_z_m = tf.t[2] - 6.0;
          o.max_z_m = tf.t[2] + 8.0;
          o.min_x_m = tf.t[0] - 9.0;
          o.max_y_m = tf.t[1] + 7.5;
        }
        for (double leaf : {0.0, 0.25, 0.5, 1.0}) {
          for (VoxelFilterImpl impl : {VoxelFilterImpl::kFast, VoxelFilterImpl::kPcl}) {
            if (impl == VoxelFilterImpl::kPcl && (leaf != 0.5 || variant > 2)) continue;  // PCL is slow to set up
            o.voxel_leaf_m = leaf;
            o.voxel_impl = impl;
            std::ostringstream what;
            what << (enc == DepthEncoding::kFloat32Metres ? "32FC1" : "16UC1") << " colour " << color << " variant "
                 << variant << " leaf " << leaf << " " << toString(impl);
            FilterStats st;
            DepthFrontEndPath path;
            points_out += checkFusedEqualsThreeStages(im.depthView(), cv, k, tf, o, what.str(), &st, &path);
            CHECK_MSG(st.points_in > 3000 && st.points_out > 0, what.str() << ": " << st.points_in);
            const bool one_pass = leaf > 0.0 && impl == VoxelFilterImpl::kFast;
            CHECK_MSG(path == (one_pass ? DepthFrontEndPath::kOnePass : DepthFrontEndPath::kOnePassThenVoxelGrid),
                      what.str() << ": took the three-stage fallback");
            if (enc == DepthEncoding::kFloat32Metres) CHECK_MSG(st.nonfinite > 0, what.str());
            if (variant % 2 == 1) CHECK_MSG(st.too_close > 0, what.str());
            if (variant >= 2) CHECK_MSG(st.outside_box > 0, what.str());
            ++cases;
          }
        }
      }
    }
  }
  CHECK(cases > 200 && points_out > 100000);
}

TEST(fused_depth_front_end_equals_three_stages_on_rendered_frames) {
  // Full-size 640 x 480 frames of the synthetic world with colour: nadir at 50 m (the benchmark's) and tilted
  // 35 and 65 degrees (returns up to the camera's 300 m), at several leaf sizes. At 0.1 m (window +-102 m) and
  // 0.25 m (+-256 m) the 65 degree frame reaches beyond the fused pass's window and takes the three stages.
  static const synthetic::World world{synthetic::WorldOptions{400.0, 0.25, 3, 4.0, 20.0}};
  synthetic::Camera cam;
  std::size_t frames = 0;
  std::size_t one_pass = 0;
  std::size_t three_stages = 0;
  for (double tilt : {0.0, 35.0, 65.0}) {
    const RigidTransform pose = tilt == 0.0 ? synthetic::nadirPose(world, 40.0, 35.0, 50.0)
                                            : synthetic::tiltedPose(world, -20.0, -60.0, 50.0, tilt);
    const synthetic::DepthFrame frame = synthetic::renderDepth(world, cam, pose, 2);
    for (double leaf : {0.1, 0.25, 0.5, 1.0}) {
      for (bool color : {true, false}) {
        FilterOptions o;
        o.voxel_leaf_m = leaf;
        o.min_z_m = -5.0;  // config/map_server.yaml's box
        o.max_z_m = 120.0;
        std::ostringstream what;
        what << "tilt " << tilt << " leaf " << leaf << (color ? " rgb8" : " no colour");
        FilterStats st;
        DepthFrontEndPath path;
        checkFusedEqualsThreeStages(frame.depthView(), color ? frame.colorView() : ColorImageView(), frame.k, pose,
                                    o, what.str(), &st, &path);
        CHECK_MSG(st.points_in > 200000 && st.points_out > 1000, what.str() << ": " << st.points_in);
        (path == DepthFrontEndPath::kOnePass ? one_pass : three_stages) += 1;
        ++frames;
      }
    }
  }
  CHECK_MSG(frames == 24 && one_pass >= 18 && three_stages >= 2, one_pass << " one-pass, " << three_stages
                                                                          << " three-stage frames");
}

TEST(fused_depth_front_end_edge_cases) {
  const PinholeIntrinsics k{40.0, 40.0, 7.5, 5.5};
  FilterOptions fast;
  fast.voxel_leaf_m = 0.5;
  auto blank = [](uint32_t w, uint32_t h) {
    TestImages im;
    im.width = w;
    im.height = h;
    im.depth_step = 4 * w;
    im.depth.resize(im.depth_step * h);
    for (uint32_t v = 0; v < h; ++v)
      for (uint32_t u = 0; u < w; ++u) im.setDepth(u, v, std::nanf(""));
    im.color_step = 4 * w;  // room for rgba
    im.color.assign(im.color_step * h, 77);
    return im;
  };
  const ColorImageView none;
  // No return at all, and a single one (voxelGridFilter leaves clouds under two points alone: a point whose
  // map x is -0.0 stays -0.0, where summing it into a leaf from +0.0 would give +0.0).
  TestImages im = blank(16, 12);
  FilterStats st;
  CHECK(checkFusedEqualsThreeStages(im.depthView(), none, k, RigidTransform(), fast, "no returns", &st) == 0);
  CHECK(st.points_in == 0);
  RigidTransform flip;  // row 0 = (-1, -0, -0), t0 = -0: pixel (cx, cy) maps to x = -0.0
  flip.r[0][0] = -1.0;
  flip.r[0][1] = -0.0;
  flip.r[0][2] = -0.0;
  flip.t[0] = -0.0;
  TestImages one = blank(16, 12);
  one.setDepth(7, 5, 3.0f);
  ColoredPoints single;
  FilterStats st1;
  PinholeIntrinsics centred{40.0, 40.0, 7.0, 5.0};
  filterDepthImage(one.depthView(), one.colorView(ColorEncoding::kRgb8), centred, flip, fast, single, st1);
  CHECK(single.size() == 1 && std::signbit(single.xyz[0](0)));
  checkFusedEqualsThreeStages(one.depthView(), one.colorView(ColorEncoding::kRgb8), centred, flip, fast, "one point");
  one.setDepth(3, 3, 3.0f);
  checkFusedEqualsThreeStages(one.depthView(), one.colorView(ColorEncoding::kBgra8), centred, flip, fast, "two points");
  // Extents that overflow PCL's int32 voxel index while every point lies in the fused pass's window (2048
  // columns of 4 mm: +-4.1 m; the points span +-4 m x 3.3 m x 9 m, 3.7e9 leaves): skipped, the filtered points
  // themselves.
  TestImages deep = blank(64, 48);
  for (uint32_t v = 0; v < 48; ++v)
    for (uint32_t u = 0; u < 64; ++u) deep.setDepth(u, v, 1.0f + 9.0f * static_cast<float>(v * 64 + u) / 3071.0f);
  const PinholeIntrinsics wide{78.75, 78.75, 31.5, 23.5};
  FilterOptions tiny;
  tiny.voxel_leaf_m = 0.004;
  checkFusedEqualsThreeStages(deep.depthView(), deep.colorView(ColorEncoding::kRgb8), wide, RigidTransform(), tiny,
                              "index overflow", &st);
  DepthFrontEndPath path;
  checkFusedEqualsThreeStages(deep.depthView(), none, wide, RigidTransform(), tiny, "index overflow", &st, &path);
  CHECK_MSG(st.voxel_grid_skipped && st.points_out == 64 * 48 && path == DepthFrontEndPath::kOnePass,
            "skipped " << st.voxel_grid_skipped << ", " << st.points_out << " points, path " << static_cast<int>(path));
  // Points beyond the window (here 600 m to each side at 0.25 m leaves: 4800 x 3584 columns, too wide for the
  // cloud path's column map too, which sorts instead, and 10 m deep so that PCL's index does not overflow)
  // take the three-stage path: the same result.
  TestImages far = blank(64, 48);
  for (uint32_t v = 0; v < 48; ++v)
    for (uint32_t u = 0; u < 64; ++u) far.setDepth(u, v, (u + v) % 7 == 0 ? 600.0f : 590.0f + 0.01f * u);
  const PinholeIntrinsics fov90{31.5, 31.5, 31.5, 23.5};
  FilterOptions quarter;
  quarter.voxel_leaf_m = 0.25;
  CHECK(checkFusedEqualsThreeStages(far.depthView(), far.colorView(ColorEncoding::kRgb8), fov90, RigidTransform(),
                                    quarter, "beyond the window", &st, &path) > 100);
  CHECK(!st.voxel_grid_skipped && path == DepthFrontEndPath::kThreeStages);
  // A sensor or points beyond 2^29 leaves, and points that overflow float in the map frame.
  RigidTransform remote;
  remote.t[0] = 1e9;
  checkFusedEqualsThreeStages(far.depthView(), none, fov90, remote, quarter, "remote sensor", &st, &path);
  CHECK(path == DepthFrontEndPath::kThreeStages);
  TestImages huge = blank(16, 12);
  huge.setDepth(2, 2, 3e38f);
  huge.setDepth(3, 2, 5.0f);
  huge.setDepth(4, 2, 5.5f);
  RigidTransform stretch;
  stretch.r[2][2] = 2.0;  // not a rotation: z doubles, beyond float
  checkFusedEqualsThreeStages(huge.depthView(), none, k, stretch, quarter, "map-frame overflow", &st, &path);
  CHECK(st.voxel_grid_skipped && path == DepthFrontEndPath::kThreeStages);
  // 76,800 pixels in one leaf: colour sums of 200 each stay below 2^24, where the pass's integer sums equal
  // float ones; of 255 each they pass it (float rounds from there on) and the frame takes the three stages.
  TestImages wall = blank(320, 240);
  for (uint32_t v = 0; v < 240; ++v)
    for (uint32_t u = 0; u < 320; ++u) wall.setDepth(u, v, 0.2f + 0.0001f * static_cast<float>(u % 7));
  const PinholeIntrinsics narrow{1600.0, 1600.0, 159.5, 119.5};
  RigidTransform offset;  // x, y in [0.23, 0.27]: one 0.5 m leaf
  offset.t[0] = 0.25;
  offset.t[1] = 0.25;
  for (uint8_t level : {200, 255}) {
    std::fill(wall.color.begin(), wall.color.end(), level);
    CHECK(checkFusedEqualsThreeStages(wall.depthView(), wall.colorView(ColorEncoding::kRgb8), narrow, offset, fast,
                                      "one bright leaf", &st, &path) == 1);
    CHECK(path == (level == 200 ? DepthFrontEndPath::kOnePass : DepthFrontEndPath::kThreeStages));
  }
  // The views are checked by the core too.
  TestImages bad = blank(16, 12);
  DepthImageView short_step = bad.depthView();
  short_step.step_bytes = 60;
  ColoredPoints out;
  checkThrows([&] { filterDepthImage(short_step, none, k, RigidTransform(), fast, out, st); }, "short step");
  checkThrows([&] { filterDepthImage(bad.depthView(), none, PinholeIntrinsics{0.0, 1.0, 0.0, 0.0}, RigidTransform(),
                                     fast, out, st); },
              "zero focal length");
  checkThrows([&] { filterDepthImage(bad.depthView(), ColorImageView{bad.color.data(), 47, ColorEncoding::kRgb8}, k,
                                     RigidTransform(), fast, out, st); },
              "short colour step");
}

TEST(fused_depth_insert_equals_cloud_insert) {
  // Mapper::insertFiltered on the fused front end's output builds the same map as Mapper::insert on the
  // back-projected cloud (what the node did for depth images before), with the same stats.
  static const synthetic::World world{synthetic::WorldOptions{120.0, 0.25, 3, 4.0, 20.0}};
  synthetic::Camera cam;
  cam.width = 160;
  cam.height = 120;
  MapperConfig c = config(Backend::kOctomap, 0.5, InsertMode::kTruncated);
  c.filter.voxel_leaf_m = 0.5;
  c.filter.min_z_m = -5.0;
  Mapper a(c);
  Mapper b(c);
  for (int i = 0; i < 3; ++i) {
    const RigidTransform pose = synthetic::tiltedPose(world, 30.0 + 6.0 * i, 25.0, 20.0, 10.0 * i);
    const synthetic::DepthFrame frame = synthetic::renderDepth(world, cam, pose, 1);
    ColoredPoints optical;
    depthToOpticalPoints(frame.depthView(), frame.colorView(), frame.k, optical);
    const InsertStats sa = a.insert(optical, pose, 1.0 + i);
    ColoredPoints filtered;
    FilterStats fs;
    filterDepthImage(frame.depthView(), frame.colorView(), frame.k, pose, c.filter, filtered, fs);
    const InsertStats sb = b.insertFiltered(filtered, fs, 0.0, pose.origin(), 1.0 + i);
    CHECK(sa.filter.points_in == sb.filter.points_in && sa.filter.points_out == sb.filter.points_out);
    CHECK(sa.points_inserted == sb.points_inserted && sa.hits == sb.hits && sa.misses == sb.misses);
    CHECK(sb.points_inserted < sb.filter.points_in && sb.points_inserted > 100);
  }
  checkSameVoxels(a.map(), b.map());
  checkSameLayers(a.layers(), b.layers());
}

TEST(config_validation) {
  auto bad = [](const std::function<void(MapperConfig&)>& edit) {
    MapperConfig c;
    edit(c);
    checkThrows([&] { c.validate(); }, "invalid config");
  };
  bad([](MapperConfig& c) { c.resolution_m = 0.0; });
  bad([](MapperConfig& c) { c.resolution_m = std::nan(""); });
  bad([](MapperConfig& c) { c.sensor.hit = 0.4; });
  bad([](MapperConfig& c) { c.sensor.miss = 0.6; });
  bad([](MapperConfig& c) { c.sensor.clamp_max = 1.0; });
  bad([](MapperConfig& c) { c.truncation_m = -1.0; });
  bad([](MapperConfig& c) { c.filter.min_z_m = 5.0; c.filter.max_z_m = 1.0; });
  bad([](MapperConfig& c) { c.threads = 0; });
  checkThrows([] { insertModeFromString("fast"); }, "mode name");
  checkThrows([] { backendFromString("voxblox"); }, "backend name");
  MapperConfig ok;
  ok.validate();
}

}  // namespace

/// Sample outputs for the Python readers' tests (tests/unit/map_server): a full-mode octree map of three small
/// frames as raw binary message data, a .bt file and exported cells at 0.25 m and 1 m.
int writeSample(const std::string& dir) {
  Mapper m = filledMapper(Backend::kOctomap, InsertMode::kFull);
  const auto& octree = dynamic_cast<const OctreeMap&>(m.map());
  std::ostringstream bin;
  octree.writeBinaryData(bin);
  writeFileAtomically(dir + "/sample_binary.bin", bin.str());
  m.save(dir + "/sample.bt");
  m.exportOccupied(dir + "/sample_occupied.npy", 0.25, "map");
  m.exportOccupied(dir + "/sample_occupied_1m.npy", 1.0, "map");
  std::size_t occupied = 0;
  std::size_t free_voxels = 0;
  m.map().forEachLeaf(
      [&](const Leaf& l) {
        const std::size_t v = static_cast<std::size_t>(l.size) * l.size * l.size;
        (m.map().isOccupied(l.state.log_odds) ? occupied : free_voxels) += v;
      },
      false);
  std::cout << "{\"resolution_m\": 0.25, \"occupied_voxels\": " << occupied << ", \"free_voxels\": " << free_voxels
            << ", \"leaves\": " << m.map().leafCount() << "}" << std::endl;
  return 0;
}

int main(int argc, char** argv) {
  if (argc == 3 && std::string(argv[1]) == "--write-sample") return writeSample(argv[2]);
  std::vector<std::string> names;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--list") {
      for (const auto& [name, fn] : registry()) std::cout << name << "\n";
      return 0;
    }
    if (a == "--all") {
      for (const auto& [name, fn] : registry()) names.push_back(name);
    } else {
      names.push_back(a);
    }
  }
  if (names.empty()) {
    std::cerr << "usage: map_core_tests --list | --all | NAME...\n";
    return 2;
  }
  int failed = 0;
  for (const std::string& name : names) {
    auto it = registry().find(name);
    if (it == registry().end()) {
      std::cerr << "unknown test " << name << "\n";
      return 2;
    }
    try {
      it->second();
      std::cout << "PASS " << name << std::endl;
    } catch (const std::exception& e) {
      std::cout << "FAIL " << name << ": " << e.what() << std::endl;
      ++failed;
    }
  }
  return failed == 0 ? 0 : 1;
}
