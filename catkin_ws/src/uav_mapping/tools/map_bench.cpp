// Benchmark driver for bench/bench_map.py: prints one JSON object per line.
//
//   map_bench frames   --res 0.5 --frames 5 [--modes full,truncated,surface] [--backends octomap,openvdb]
//                      [--stock 1] [--threads 2] [--agl 50] [--spacing 20] [--max-range -1]
//       Per-frame insertion time and memory for each backend x mode on the same nadir frames, plus stock
//       OcTree::insertPointCloud (octomap_server's insertion) on the same frames as the baseline, and whether
//       full ray clearing gives exactly stock's set of occupied and free keys (and log-odds).
//   map_bench pipeline --res 0.5 --frames 5 --mode surface --leaf 0.5 [--backend octomap] [--truncation 3]
//                      [--voxel fast|pcl] [--min-z -inf] [--max-z inf]
//       Time of the whole Mapper::insert (transform, filters, voxel grid, insertion).
//       With --depth-file F (or --input depth: synthetic depth frames) [--repeat 3]: depth images in, into two
//       mappers in turn, one through the fused rgbd front end (filterDepthImage + Mapper::insertFiltered, what
//       the node does), one through the three stages (depthToOpticalPoints + Mapper::insert); filter and total
//       times include the back-projection; whether both maps end up identical.
//   map_bench frontend --frames 5 --leaf 0.5 [--depth-file F] [--repeat 5] [--voxel fast|pcl] [--min-range -1]
//                      [--min-z -inf] [--max-z inf]
//       The rgbd front end alone on the same depth frames: the three stages (back-projection, transform +
//       filters, voxel grid; each timed) against the fused one-pass filterDepthImage, interleaved, and whether
//       their outputs are bit-identical.
//   map_bench coverage --res 0.5 --backend octomap --mode surface --side 1000 [--spacing 20] [--row 80]
//       Lawnmower over a side x side square at 50 m AGL; map memory and process RSS at the end.
//
// Frames come from the built-in synthetic world unless --frames-file FILE (or - for stdin) gives rendered
// ones in the stream format below (bench/bench_map.py writes it from the sim bridge's renderer):
//   "UAVFRAMES1\n", then per frame: float64 origin[3], float64 stamp_s, uint64 n, float32 xyz[n][3] (map frame),
//   uint8 rgb[n][3]; a frame with n = 2^64 - 1 ends the stream.
// Depth frames (--depth-file) likewise:
//   "UAVDEPTH1\n", then per frame: uint32 width, uint32 height, float64 fx, fy, cx, cy, float64 r[3][3] and t[3]
//   (map <- optical, row-major), float64 stamp_s, float32 depth_m[height][width] (NaN: no return),
//   uint8 rgb[height][width][3]; a frame with width = height = 2^32 - 1 ends the stream.
#include "synthetic_world.h"

#include <uav_mapping/depth_filter.h>
#include <uav_mapping/mapper.h>
#include <uav_mapping/octree_map.h>

#include <octomap/OcTree.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <iostream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

using namespace uav_mapping;

namespace {

using Clock = std::chrono::steady_clock;
double msSince(Clock::time_point t0) { return std::chrono::duration<double, std::milli>(Clock::now() - t0).count(); }

std::map<std::string, std::string> parseArgs(int argc, char** argv, int first) {
  std::map<std::string, std::string> a;
  for (int i = first; i + 1 < argc; i += 2) {
    std::string k = argv[i];
    if (k.rfind("--", 0) == 0) k = k.substr(2);
    a[k] = argv[i + 1];
  }
  return a;
}
std::string arg(const std::map<std::string, std::string>& a, const std::string& k, const std::string& def) {
  auto it = a.find(k);
  return it == a.end() ? def : it->second;
}
std::vector<std::string> split(const std::string& s) {
  std::vector<std::string> out;
  std::stringstream ss(s);
  std::string item;
  while (std::getline(ss, item, ',')) {
    if (!item.empty()) out.push_back(item);
  }
  return out;
}

std::size_t rssBytes() {
  std::ifstream f("/proc/self/status");
  std::string line;
  while (std::getline(f, line)) {
    if (line.rfind("VmRSS:", 0) == 0) return static_cast<std::size_t>(std::stoull(line.substr(6))) * 1024;
  }
  return 0;
}

double median(std::vector<double> v) {
  if (v.empty()) return NAN;
  std::sort(v.begin(), v.end());
  const std::size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

std::string jsonList(const std::vector<double>& v) {
  std::ostringstream o;
  o << "[";
  for (std::size_t i = 0; i < v.size(); ++i) o << (i ? ", " : "") << v[i];
  return o.str() + "]";
}

struct Frame {
  ColoredPoints map_points;
  Point3 origin;
  double stamp_s;
};

/// Reads frames in the stream format (see the header comment); false at the end of the stream.
class FrameStream {
 public:
  explicit FrameStream(const std::string& path) {
    if (path == "-") {
      in_ = &std::cin;
    } else {
      file_.open(path, std::ios::binary);
      if (!file_) throw std::runtime_error("cannot open " + path);
      in_ = &file_;
    }
    std::string magic;
    std::getline(*in_, magic);
    if (magic != "UAVFRAMES1") throw std::runtime_error("not a frame stream: " + path);
  }
  bool next(Frame& f) {
    double head[4];
    uint64_t n = 0;
    if (!in_->read(reinterpret_cast<char*>(head), sizeof(head)) || !in_->read(reinterpret_cast<char*>(&n), 8))
      return false;
    if (n == ~0ULL) return false;
    if (n > 100000000ULL) throw std::runtime_error("frame stream: absurd point count");
    std::vector<float> xyz(3 * n);
    std::vector<uint8_t> rgb(3 * n);
    if (!in_->read(reinterpret_cast<char*>(xyz.data()), static_cast<std::streamsize>(xyz.size() * 4)) ||
        !in_->read(reinterpret_cast<char*>(rgb.data()), static_cast<std::streamsize>(rgb.size())))
      throw std::runtime_error("frame stream truncated");
    f.map_points.clear();
    f.map_points.xyz.reserve(n);
    f.map_points.rgb.reserve(n);
    for (uint64_t i = 0; i < n; ++i) {
      f.map_points.xyz.emplace_back(xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2]);
      f.map_points.rgb.push_back({rgb[3 * i], rgb[3 * i + 1], rgb[3 * i + 2]});
    }
    f.origin = Point3(static_cast<float>(head[0]), static_cast<float>(head[1]), static_cast<float>(head[2]));
    f.stamp_s = head[3];
    return true;
  }

 private:
  std::ifstream file_;
  std::istream* in_ = nullptr;
};

struct DepthInputFrame {
  synthetic::DepthFrame image;
  RigidTransform pose;  // map <- optical
  double stamp_s = 0.0;
};

/// Reads depth frames in the stream format (see the header comment); false at the end of the stream.
class DepthStream {
 public:
  explicit DepthStream(const std::string& path) : file_(path, std::ios::binary) {
    if (!file_) throw std::runtime_error("cannot open " + path);
    std::string magic;
    std::getline(file_, magic);
    if (magic != "UAVDEPTH1") throw std::runtime_error("not a depth frame stream: " + path);
  }
  bool next(DepthInputFrame& f) {
    uint32_t size[2];
    double head[4 + 9 + 3 + 1];
    if (!file_.read(reinterpret_cast<char*>(size), sizeof(size))) return false;
    if (size[0] == ~0U && size[1] == ~0U) return false;
    if (static_cast<uint64_t>(size[0]) * size[1] > 100000000ULL) throw std::runtime_error("depth stream: absurd size");
    if (!file_.read(reinterpret_cast<char*>(head), sizeof(head))) throw std::runtime_error("depth stream truncated");
    synthetic::DepthFrame& im = f.image;
    im.width = size[0];
    im.height = size[1];
    im.k = PinholeIntrinsics{head[0], head[1], head[2], head[3]};
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) f.pose.r[i][j] = head[4 + 3 * i + j];
    for (int i = 0; i < 3; ++i) f.pose.t[i] = head[13 + i];
    f.stamp_s = head[16];
    const std::size_t n = static_cast<std::size_t>(im.width) * im.height;
    im.depth_m.resize(n);
    im.rgb.resize(3 * n);
    if (!file_.read(reinterpret_cast<char*>(im.depth_m.data()), static_cast<std::streamsize>(4 * n)) ||
        !file_.read(reinterpret_cast<char*>(im.rgb.data()), static_cast<std::streamsize>(3 * n)))
      throw std::runtime_error("depth stream truncated");
    return true;
  }

 private:
  std::ifstream file_;
};

/// Depth frames from --depth-file, or rendered from the synthetic world (nadir, 50 m AGL, 20 m apart).
std::vector<DepthInputFrame> loadDepthFrames(const std::map<std::string, std::string>& a, int n_frames, int threads,
                                             std::string& source) {
  std::vector<DepthInputFrame> frames;
  if (a.count("depth-file")) {
    DepthStream stream(a.at("depth-file"));
    DepthInputFrame f;
    while (static_cast<int>(frames.size()) < n_frames && stream.next(f)) frames.push_back(f);
    source = "rendered depth frames from " + a.at("depth-file");
    return frames;
  }
  synthetic::World world{synthetic::WorldOptions()};
  synthetic::Camera cam;
  for (int i = 0; i < n_frames; ++i) {
    DepthInputFrame f;
    f.pose = synthetic::nadirPose(world, 20.0 * i + 40.0, 35.0, 50.0);
    f.image = synthetic::renderDepth(world, cam, f.pose, threads);
    f.stamp_s = 10.0 + 0.5 * i;
    frames.push_back(std::move(f));
  }
  source = "synthetic heightfield depth frames (tools/synthetic_world.cpp)";
  return frames;
}

bool sameFiltered(const ColoredPoints& a, const FilterStats& sa, const ColoredPoints& b, const FilterStats& sb) {
  return a.size() == b.size() && a.rgb == b.rgb &&
         (a.size() == 0 || std::memcmp(a.xyz.data(), b.xyz.data(), a.size() * sizeof(Point3)) == 0) &&
         sa.points_in == sb.points_in && sa.nonfinite == sb.nonfinite && sa.too_close == sb.too_close &&
         sa.outside_box == sb.outside_box && sa.points_out == sb.points_out &&
         sa.voxel_grid_skipped == sb.voxel_grid_skipped;
}

std::vector<Frame> makeFrames(const synthetic::World& world, int count, double spacing_m, double agl_m, int threads) {
  std::vector<Frame> frames;
  synthetic::Camera cam;
  for (int i = 0; i < count; ++i) {
    // Along x through the world centre's neighbourhood, away from the clear home pad.
    const double x = -0.5 * spacing_m * (count - 1) + spacing_m * i + 40.0;
    const double y = 35.0;
    const RigidTransform pose = synthetic::nadirPose(world, x, y, agl_m);
    Frame f;
    f.map_points = synthetic::toMap(synthetic::render(world, cam, pose, threads), pose);
    f.origin = pose.origin();
    f.stamp_s = 10.0 + 0.5 * i;
    frames.push_back(std::move(f));
  }
  return frames;
}

octomap::Pointcloud toOctomap(const ColoredPoints& pts) {
  octomap::Pointcloud pc;
  pc.reserve(pts.size());
  for (const Point3& p : pts.xyz) pc.push_back(p);
  return pc;
}

/// Exact comparison of a map against stock OctoMap: every voxel of every stock leaf (stock prunes too, so a leaf
/// may cover 2^k voxels per axis) must exist in the map with the same log-odds, and the map must hold no other
/// voxel.
struct Identity {
  bool identical = true;
  std::size_t stock_occupied = 0;  // voxels
  std::size_t stock_free = 0;      // voxels
  std::size_t mismatches = 0;
  std::size_t map_voxels = 0;
};
Identity compareToStock(const octomap::OcTree& stock, const VoxelMap& map) {
  Identity id;
  for (auto it = stock.begin_leafs(), end = stock.end_leafs(); it != end; ++it) {
    const unsigned size = 1U << (16 - it.getDepth());
    const std::size_t voxels = static_cast<std::size_t>(size) * size * size;
    if (stock.isNodeOccupied(*it))
      id.stock_occupied += voxels;
    else
      id.stock_free += voxels;
    // The iterator's key is the node centre at its depth; the first voxel is half a node below it.
    const octomap::OcTreeKey c = it.getKey();
    const int half = static_cast<int>(size / 2);
    for (unsigned dz = 0; dz < size; ++dz)
      for (unsigned dy = 0; dy < size; ++dy)
        for (unsigned dx = 0; dx < size; ++dx) {
          const Key k(static_cast<uint16_t>(c[0] - half + dx), static_cast<uint16_t>(c[1] - half + dy),
                      static_cast<uint16_t>(c[2] - half + dz));
          VoxelState s;
          if (!map.query(k, s) || s.log_odds != it->getLogOdds()) ++id.mismatches;
        }
  }
  map.forEachLeaf([&](const Leaf& l) { id.map_voxels += static_cast<std::size_t>(l.size) * l.size * l.size; }, false);
  id.identical = id.mismatches == 0 && id.map_voxels == id.stock_occupied + id.stock_free;
  return id;
}

int runFrames(const std::map<std::string, std::string>& a) {
  const double res = std::stod(arg(a, "res", "0.5"));
  const int n_frames = std::stoi(arg(a, "frames", "5"));
  const int threads = std::stoi(arg(a, "threads", "2"));
  const double agl = std::stod(arg(a, "agl", "50"));
  const double spacing = std::stod(arg(a, "spacing", "20"));
  const double max_range = std::stod(arg(a, "max-range", "-1"));
  const bool stock = arg(a, "stock", "1") == "1";
  const double truncation = std::stod(arg(a, "truncation", "3"));
  std::vector<Frame> frames;
  std::string source = "synthetic heightfield (tools/synthetic_world.cpp)";
  if (a.count("frames-file")) {
    FrameStream stream(a.at("frames-file"));
    Frame f;
    while (static_cast<int>(frames.size()) < n_frames && stream.next(f)) frames.push_back(f);
    source = "rendered frames from " + a.at("frames-file");
  } else {
    synthetic::World world{synthetic::WorldOptions()};
    frames = makeFrames(world, n_frames, spacing, agl, threads);
  }
  std::size_t points = 0;
  for (const auto& f : frames) points += f.map_points.size();
  std::cout << "{\"kind\": \"frames\", \"res_m\": " << res << ", \"frames\": " << frames.size()
            << ", \"points_per_frame\": " << points / std::max<std::size_t>(1, frames.size()) << ", \"source\": \""
            << source << "\"}" << std::endl;

  std::unique_ptr<octomap::OcTree> stock_tree;
  if (stock) {
    // octomap_server's sensor model (OctoMap's own OcTree defaults clamp at 0.1192 / 0.971 instead).
    const SensorModel model;
    stock_tree = std::make_unique<octomap::OcTree>(res);
    stock_tree->setProbHit(model.hit);
    stock_tree->setProbMiss(model.miss);
    stock_tree->setClampingThresMin(model.clamp_min);
    stock_tree->setClampingThresMax(model.clamp_max);
    std::vector<double> ms;
    const std::size_t rss0 = rssBytes();
    for (const auto& f : frames) {
      const octomap::Pointcloud pc = toOctomap(f.map_points);
      const auto t0 = Clock::now();
      stock_tree->insertPointCloud(pc, f.origin, max_range, false, false);
      ms.push_back(msSince(t0));
    }
    std::cout << "{\"kind\": \"run\", \"impl\": \"stock\", \"backend\": \"octomap\", \"mode\": \"full\", \"res_m\": "
              << res << ", \"ms\": " << jsonList(ms) << ", \"median_ms\": " << median(ms)
              << ", \"memory_bytes\": " << stock_tree->memoryUsage() << ", \"rss_delta_bytes\": "
              << static_cast<long long>(rssBytes()) - static_cast<long long>(rss0) << ", \"nodes\": " << stock_tree->size()
              << "}" << std::endl;
  }
  for (const std::string& backend : split(arg(a, "backends", "octomap,openvdb"))) {
    for (const std::string& mode : split(arg(a, "modes", "full,truncated,surface"))) {
      MapperConfig cfg;
      cfg.backend = backendFromString(backend);
      cfg.resolution_m = res;
      cfg.mode = insertModeFromString(mode);
      cfg.max_range_m = max_range;
      cfg.truncation_m = truncation;
      cfg.threads = threads;
      Mapper mapper(cfg);
      std::vector<double> ms, raycast, update, layers;
      std::size_t hits = 0, misses = 0;
      const std::size_t rss0 = rssBytes();
      for (const auto& f : frames) {
        const InsertStats st = mapper.insertMapPoints(f.map_points, f.origin, f.stamp_s);
        ms.push_back(st.total_ms);
        raycast.push_back(st.raycast_ms);
        update.push_back(st.update_ms);
        layers.push_back(st.layers_ms);
        hits += st.hits;
        misses += st.misses;
      }
      std::cout << "{\"kind\": \"run\", \"impl\": \"uav_mapping\", \"backend\": \"" << backend << "\", \"mode\": \"" << mode
                << "\", \"res_m\": " << res << ", \"threads\": " << threads << ", \"ms\": " << jsonList(ms)
                << ", \"median_ms\": " << median(ms) << ", \"median_raycast_ms\": " << median(raycast)
                << ", \"median_update_ms\": " << median(update) << ", \"median_layers_ms\": " << median(layers)
                << ", \"hits\": " << hits << ", \"misses\": " << misses
                << ", \"memory_bytes\": " << mapper.map().memoryBytes() << ", \"rss_delta_bytes\": "
                << static_cast<long long>(rssBytes()) - static_cast<long long>(rss0)
                << ", \"leaves\": " << mapper.map().leafCount();
      if (stock_tree && mode == "full") {
        const Identity id = compareToStock(*stock_tree, mapper.map());
        std::cout << ", \"identical_to_stock\": " << (id.identical ? "true" : "false")
                  << ", \"stock_occupied\": " << id.stock_occupied << ", \"stock_free\": " << id.stock_free
                  << ", \"map_voxels\": " << id.map_voxels << ", \"mismatches\": " << id.mismatches;
      }
      std::cout << "}" << std::endl;
    }
  }
  return 0;
}

/// The pipeline on depth frames, both ways in one process: mapper "fused" gets the node's rgbd path
/// (filterDepthImage + Mapper::insertFiltered), mapper "three_stages" what the node did before
/// (depthToOpticalPoints + Mapper::insert), frame by frame in turn (which goes first alternates per round), the
/// frame sequence `repeat` times over. Both maps must end up identical.
int runDepthPipeline(const std::map<std::string, std::string>& a, const MapperConfig& cfg, int n_frames, int threads) {
  std::string source;
  const std::vector<DepthInputFrame> frames = loadDepthFrames(a, n_frames, threads, source);
  const int repeat = std::max(1, std::stoi(arg(a, "repeat", "3")));
  Mapper fused_mapper(cfg);
  Mapper three_mapper(cfg);
  struct Times {
    std::vector<double> total, filter, insert;
  } fused_t, three_t;
  std::size_t pts_in = 0, pts_out = 0;
  ColoredPoints points;
  auto record = [](Times& t, const InsertStats& st) {
    t.total.push_back(st.total_ms);
    t.filter.push_back(st.filter_ms);
    t.insert.push_back(st.total_ms - st.filter_ms);
  };
  for (int round = 0; round < repeat; ++round) {
    for (std::size_t i = 0; i < frames.size(); ++i) {
      const DepthInputFrame& f = frames[i];
      const double stamp_s = f.stamp_s + 1000.0 * round;
      auto runFused = [&] {
        FilterStats fs;
        const auto t0 = Clock::now();
        filterDepthImage(f.image.depthView(), f.image.colorView(), f.image.k, f.pose, cfg.filter, points, fs);
        record(fused_t, fused_mapper.insertFiltered(points, fs, msSince(t0), f.pose.origin(), stamp_s));
      };
      auto runThree = [&] {
        const auto t0 = Clock::now();
        depthToOpticalPoints(f.image.depthView(), f.image.colorView(), f.image.k, points);
        const double backproject_ms = msSince(t0);
        InsertStats st = three_mapper.insert(points, f.pose, stamp_s);
        st.filter_ms += backproject_ms;
        st.total_ms += backproject_ms;
        record(three_t, st);
        if (round == 0) {
          pts_in += st.filter.points_in;
          pts_out += st.points_inserted;
        }
      };
      if ((round + static_cast<int>(i)) % 2 == 0) {
        runFused();
        runThree();
      } else {
        runThree();
        runFused();
      }
    }
  }
  const bool identical = fused_mapper.occupiedCells(cfg.resolution_m) == three_mapper.occupiedCells(cfg.resolution_m) &&
                         fused_mapper.map().leafCount() == three_mapper.map().leafCount();
  const std::size_t n = std::max<std::size_t>(1, frames.size());
  std::cout << "{\"kind\": \"pipeline\", \"input\": \"depth\", \"backend\": \"" << toString(cfg.backend)
            << "\", \"mode\": \"" << toString(cfg.mode) << "\", \"voxel\": \"" << toString(cfg.filter.voxel_impl)
            << "\", \"res_m\": " << cfg.resolution_m << ", \"leaf_m\": " << cfg.filter.voxel_leaf_m
            << ", \"frames\": " << frames.size() << ", \"repeat\": " << repeat;
  for (const auto& [name, t] : {std::pair<const char*, const Times*>{"fused", &fused_t}, {"three_stages", &three_t}}) {
    std::cout << ", \"median_total_ms_" << name << "\": " << median(t->total) << ", \"median_filter_ms_" << name
              << "\": " << median(t->filter) << ", \"median_insert_ms_" << name << "\": " << median(t->insert);
  }
  std::cout << ", \"identical_maps\": " << (identical ? "true" : "false")
            << ", \"points_in_per_frame\": " << pts_in / n << ", \"points_inserted_per_frame\": " << pts_out / n
            << ", \"source\": \"" << source << "\"}" << std::endl;
  return identical ? 0 : 3;
}

/// The rgbd front end alone: the three stages against the fused pass, same frames, interleaved.
int runFrontend(const std::map<std::string, std::string>& a) {
  const int n_frames = std::stoi(arg(a, "frames", "5"));
  const int repeat = std::max(1, std::stoi(arg(a, "repeat", "5")));
  const int threads = std::stoi(arg(a, "threads", "2"));
  FilterOptions opt;
  opt.voxel_leaf_m = std::stod(arg(a, "leaf", "0.5"));
  opt.voxel_impl = voxelFilterImplFromString(arg(a, "voxel", "fast"));
  opt.min_range_m = std::stod(arg(a, "min-range", "-1"));
  opt.min_z_m = std::stod(arg(a, "min-z", "-inf"));
  opt.max_z_m = std::stod(arg(a, "max-z", "inf"));
  std::string source;
  const std::vector<DepthInputFrame> frames = loadDepthFrames(a, n_frames, threads, source);
  std::vector<double> three, backproject, transform, voxel, fused;
  bool identical = true;
  std::size_t pixels = 0, pts_in = 0, pts_out = 0, one_pass = 0;
  ColoredPoints optical, ref, out;
  // Round 0 warms the buffers up (first-frame allocations) and is not timed; odd rounds run the fused pass
  // first, so that neither side always finds the caches as the other left them.
  for (int round = 0; round <= repeat; ++round) {
    for (const DepthInputFrame& f : frames) {
      const DepthImageView depth = f.image.depthView();
      const ColorImageView color = f.image.colorView();
      FilterStats sr, sf;
      double ms_b = 0.0, ms_t = 0.0, ms_v = 0.0, ms_f = 0.0;
      DepthFrontEndPath path = DepthFrontEndPath::kThreeStages;
      auto runThree = [&] {
        const auto t0 = Clock::now();
        depthToOpticalPoints(depth, color, f.image.k, optical);
        const auto t1 = Clock::now();
        transformAndFilter(optical, f.pose, opt, ref, sr);
        const auto t2 = Clock::now();
        voxelGridFilter(ref, opt.voxel_leaf_m, sr, opt.voxel_impl);
        ms_b = std::chrono::duration<double, std::milli>(t1 - t0).count();
        ms_t = std::chrono::duration<double, std::milli>(t2 - t1).count();
        ms_v = msSince(t2);
      };
      auto runFused = [&] {
        const auto t0 = Clock::now();
        path = filterDepthImage(depth, color, f.image.k, f.pose, opt, out, sf);
        ms_f = msSince(t0);
      };
      if (round % 2 == 1) {
        runFused();
        runThree();
      } else {
        runThree();
        runFused();
      }
      if (round == 0) {
        identical = identical && sameFiltered(out, sf, ref, sr);
        pixels += static_cast<std::size_t>(depth.width) * depth.height;
        pts_in += sr.points_in;
        pts_out += sr.points_out;
        one_pass += path == DepthFrontEndPath::kOnePass;
        continue;
      }
      backproject.push_back(ms_b);
      transform.push_back(ms_t);
      voxel.push_back(ms_v);
      three.push_back(ms_b + ms_t + ms_v);
      fused.push_back(ms_f);
    }
  }
  const std::size_t n = std::max<std::size_t>(1, frames.size());
  std::cout << "{\"kind\": \"frontend\", \"frames\": " << frames.size() << ", \"repeat\": " << repeat
            << ", \"leaf_m\": " << opt.voxel_leaf_m << ", \"voxel\": \"" << toString(opt.voxel_impl)
            << "\", \"pixels_per_frame\": " << pixels / n << ", \"points_in_per_frame\": " << pts_in / n
            << ", \"points_out_per_frame\": " << pts_out / n << ", \"one_pass_frames\": " << one_pass
            << ", \"identical\": " << (identical ? "true" : "false")
            << ", \"median_three_stages_ms\": " << median(three) << ", \"median_backproject_ms\": " << median(backproject)
            << ", \"median_transform_filter_ms\": " << median(transform)
            << ", \"median_voxel_grid_ms\": " << median(voxel) << ", \"median_fused_ms\": " << median(fused)
            << ", \"three_stages_ms\": " << jsonList(three) << ", \"fused_ms\": " << jsonList(fused)
            << ", \"source\": \"" << source << "\"}" << std::endl;
  return identical ? 0 : 3;
}

int runPipeline(const std::map<std::string, std::string>& a) {
  const double res = std::stod(arg(a, "res", "0.5"));
  const int n_frames = std::stoi(arg(a, "frames", "5"));
  const int threads = std::stoi(arg(a, "threads", "2"));
  MapperConfig cfg;
  cfg.backend = backendFromString(arg(a, "backend", "octomap"));
  cfg.resolution_m = res;
  cfg.mode = insertModeFromString(arg(a, "mode", "surface"));
  cfg.truncation_m = std::stod(arg(a, "truncation", "3"));
  cfg.filter.voxel_leaf_m = std::stod(arg(a, "leaf", "0"));
  cfg.filter.voxel_impl = voxelFilterImplFromString(arg(a, "voxel", "fast"));
  cfg.filter.min_z_m = std::stod(arg(a, "min-z", "-inf"));  // pass-through box, as pointcloud_{min,max}_z
  cfg.filter.max_z_m = std::stod(arg(a, "max-z", "inf"));
  cfg.threads = threads;
  cfg.max_range_m = std::stod(arg(a, "max-range", "-1"));
  if (a.count("depth-file") || arg(a, "input", "cloud") == "depth") return runDepthPipeline(a, cfg, n_frames, threads);
  Mapper mapper(cfg);
  // Sensor-frame clouds and their poses: rendered frames (map-frame points shifted to the sensor origin, a
  // pure translation) or the synthetic camera.
  std::vector<std::pair<ColoredPoints, RigidTransform>> inputs;
  if (a.count("frames-file")) {
    FrameStream stream(a.at("frames-file"));
    Frame f;
    while (static_cast<int>(inputs.size()) < n_frames && stream.next(f)) {
      RigidTransform tf;
      for (int k = 0; k < 3; ++k) tf.t[k] = f.origin(k);
      for (Point3& p : f.map_points.xyz) p -= f.origin;
      inputs.emplace_back(f.map_points, tf);
    }
  } else {
    synthetic::World world{synthetic::WorldOptions()};
    synthetic::Camera cam;
    for (int i = 0; i < n_frames; ++i) {
      const RigidTransform pose = synthetic::nadirPose(world, 20.0 * i + 40.0, 35.0, 50.0);
      inputs.emplace_back(synthetic::render(world, cam, pose, threads), pose);
    }
  }
  std::vector<double> total, filter, insert, raycast, update, layers;
  std::size_t pts_in = 0, pts_out = 0;
  for (std::size_t i = 0; i < inputs.size(); ++i) {
    const InsertStats st = mapper.insert(inputs[i].first, inputs[i].second, 10.0 + 0.5 * static_cast<double>(i));
    total.push_back(st.total_ms);
    filter.push_back(st.filter_ms);
    insert.push_back(st.total_ms - st.filter_ms);
    raycast.push_back(st.raycast_ms);
    update.push_back(st.update_ms);
    layers.push_back(st.layers_ms);
    pts_in += st.filter.points_in;
    pts_out += st.points_inserted;
  }
  const std::size_t n = std::max<std::size_t>(1, inputs.size());
  std::cout << "{\"kind\": \"pipeline\", \"backend\": \"" << arg(a, "backend", "octomap") << "\", \"mode\": \""
            << arg(a, "mode", "surface") << "\", \"voxel\": \"" << toString(cfg.filter.voxel_impl)
            << "\", \"res_m\": " << res << ", \"leaf_m\": " << cfg.filter.voxel_leaf_m
            << ", \"median_total_ms\": " << median(total) << ", \"median_filter_ms\": " << median(filter)
            << ", \"median_insert_ms\": " << median(insert) << ", \"median_raycast_ms\": " << median(raycast)
            << ", \"median_update_ms\": " << median(update) << ", \"median_layers_ms\": " << median(layers)
            << ", \"points_in_per_frame\": " << pts_in / n
            << ", \"points_inserted_per_frame\": " << pts_out / n << "}" << std::endl;
  return 0;
}

int runCoverage(const std::map<std::string, std::string>& a) {
  const double res = std::stod(arg(a, "res", "0.5"));
  const double side = std::stod(arg(a, "side", "1000"));
  const double spacing = std::stod(arg(a, "spacing", "20"));
  const double row = std::stod(arg(a, "row", "80"));
  const int threads = std::stoi(arg(a, "threads", "2"));
  synthetic::WorldOptions wo;
  wo.half_size_m = a.count("frames-file") ? 10.0 : 0.5 * side + 60.0;  // unused with rendered frames
  synthetic::World world(wo);
  synthetic::Camera cam;
  MapperConfig cfg;
  cfg.backend = backendFromString(arg(a, "backend", "octomap"));
  cfg.resolution_m = res;
  cfg.mode = insertModeFromString(arg(a, "mode", "surface"));
  cfg.max_range_m = std::stod(arg(a, "max-range", "-1"));
  cfg.truncation_m = std::stod(arg(a, "truncation", "3"));
  cfg.threads = threads;
  const std::size_t rss0 = rssBytes();
  Mapper mapper(cfg);
  std::vector<double> ms;
  int frame = 0;
  const int rows = a.count("frames-file") ? 0 : static_cast<int>(std::ceil(side / row));
  const auto t_start = Clock::now();
  if (a.count("frames-file")) {
    FrameStream stream(a.at("frames-file"));
    Frame f;
    while (stream.next(f)) {
      ms.push_back(mapper.insertMapPoints(f.map_points, f.origin, f.stamp_s).total_ms);
      ++frame;
    }
  }
  for (int r = 0; r < rows; ++r) {
    const double y = -0.5 * side + (r + 0.5) * row;
    const int cols = static_cast<int>(std::ceil(side / spacing)) + 1;
    for (int c = 0; c < cols; ++c) {
      const double x = (r % 2 == 0) ? -0.5 * side + c * spacing : 0.5 * side - c * spacing;
      const RigidTransform pose = synthetic::nadirPose(world, x, y, 50.0);
      const ColoredPoints pts = synthetic::toMap(synthetic::render(world, cam, pose, threads), pose);
      const InsertStats st = mapper.insertMapPoints(pts, pose.origin(), 0.5 * frame);
      ms.push_back(st.total_ms);
      ++frame;
    }
  }
  const LayersSnapshot layers = mapper.layers();
  std::size_t observed = 0;
  for (float o : layers.observed) observed += o > 0.0f;
  KeyBox box;
  mapper.map().forEachLeaf(
      [&box](const Leaf& l) {
        box.add(l.key);
        box.add(Key(static_cast<uint16_t>(l.key[0] + l.size - 1), static_cast<uint16_t>(l.key[1] + l.size - 1),
                    static_cast<uint16_t>(l.key[2] + l.size - 1)));
      },
      false);
  const double dense_bytes = static_cast<double>(box.volume()) * sizeof(float);  // OctoMap's memoryFullGrid
  std::cout << "{\"kind\": \"coverage\", \"backend\": \"" << arg(a, "backend", "octomap") << "\", \"mode\": \""
            << arg(a, "mode", "surface") << "\", \"res_m\": " << res << ", \"side_m\": " << side
            << ", \"frames\": " << frame << ", \"median_ms\": " << median(ms)
            << ", \"observed_area_m2\": " << observed * res * res << ", \"memory_bytes\": " << mapper.map().memoryBytes()
            << ", \"layers_bytes\": " << mapper.columnLayers().memoryBytes() << ", \"leaves\": " << mapper.map().leafCount()
            << ", \"rss_delta_bytes\": " << static_cast<long long>(rssBytes()) - static_cast<long long>(rss0)
            << ", \"dense_grid_bytes\": " << dense_bytes << ", \"wall_s\": " << msSince(t_start) / 1000.0 << "}"
            << std::endl;
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2) {
    std::cerr << "usage: map_bench frames|pipeline|frontend|coverage [--key value ...]\n";
    return 2;
  }
  const std::string cmd = argv[1];
  const auto a = parseArgs(argc, argv, 2);
  try {
    if (cmd == "frames") return runFrames(a);
    if (cmd == "pipeline") return runPipeline(a);
    if (cmd == "frontend") return runFrontend(a);
    if (cmd == "coverage") return runCoverage(a);
  } catch (const std::exception& e) {
    std::cerr << "map_bench: " << e.what() << "\n";
    return 1;
  }
  std::cerr << "unknown command " << cmd << "\n";
  return 2;
}
