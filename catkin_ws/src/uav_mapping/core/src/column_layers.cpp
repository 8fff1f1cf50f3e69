#include <uav_mapping/column_layers.h>

#include <algorithm>
#include <cmath>

namespace uav_mapping {

namespace {
constexpr int kChunk = 64;
int floorDiv(int a, int b) { return a >= 0 ? a / b : -((-a + b - 1) / b); }
}  // namespace

void ColumnLayers::clear() {
  kx0_ = ky0_ = w_ = h_ = 0;
  top_.clear();
  last_.clear();
  observed_.clear();
  dirty_flag_.clear();
  dirty_.clear();
  obs_box_ = KeyBox();
  min_kz_ = std::numeric_limits<int>::max();
}

void ColumnLayers::reserve(int kx0, int ky0, int kx1, int ky1) {
  if (w_ > 0 && kx0 >= kx0_ && ky0 >= ky0_ && kx1 < kx0_ + w_ && ky1 < ky0_ + h_) return;
  int nx0 = kx0;
  int ny0 = ky0;
  int nx1 = kx1;
  int ny1 = ky1;
  if (w_ > 0) {  // grow to cover the old grid plus at least doubling on the side that grows
    nx0 = std::min(nx0, kx0_);
    ny0 = std::min(ny0, ky0_);
    nx1 = std::max(nx1, kx0_ + w_ - 1);
    ny1 = std::max(ny1, ky0_ + h_ - 1);
    if (kx0 < kx0_) nx0 = std::min(nx0, kx0_ - w_);
    if (kx1 >= kx0_ + w_) nx1 = std::max(nx1, kx0_ + 2 * w_ - 1);
    if (ky0 < ky0_) ny0 = std::min(ny0, ky0_ - h_);
    if (ky1 >= ky0_ + h_) ny1 = std::max(ny1, ky0_ + 2 * h_ - 1);
  }
  nx0 = std::max(0, floorDiv(nx0, kChunk) * kChunk);
  ny0 = std::max(0, floorDiv(ny0, kChunk) * kChunk);
  nx1 = std::min(2 * kKeyOffset - 1, (floorDiv(nx1, kChunk) + 1) * kChunk - 1);
  ny1 = std::min(2 * kKeyOffset - 1, (floorDiv(ny1, kChunk) + 1) * kChunk - 1);
  const int nw = nx1 - nx0 + 1;
  const int nh = ny1 - ny0 + 1;
  const std::size_t n = static_cast<std::size_t>(nw) * static_cast<std::size_t>(nh);
  std::vector<int32_t> top(n, kNoTop);
  std::vector<float> last(n, kNoTime);
  std::vector<uint8_t> obs(n, 0);
  std::vector<uint8_t> dflag(n, 0);
  for (int y = 0; y < h_; ++y) {
    const std::size_t src = static_cast<std::size_t>(y) * w_;
    const std::size_t dst = static_cast<std::size_t>(y + ky0_ - ny0) * nw + static_cast<std::size_t>(kx0_ - nx0);
    std::copy_n(&top_[src], w_, &top[dst]);
    std::copy_n(&last_[src], w_, &last[dst]);
    std::copy_n(&observed_[src], w_, &obs[dst]);
  }
  // Dirty columns are resolved at the end of every frame, so none are pending here.
  dirty_.clear();
  kx0_ = nx0;
  ky0_ = ny0;
  w_ = nw;
  h_ = nh;
  top_.swap(top);
  last_.swap(last);
  observed_.swap(obs);
  dirty_flag_.swap(dflag);
}

void ColumnLayers::observeColumn(int kx, int ky, int kz, bool occupied_now, bool lost_occupied, float time_s) {
  const std::size_t i = index(kx, ky);
  observed_[i] = 1;
  if (time_s > last_[i]) last_[i] = time_s;
  if (occupied_now) {
    if (kz > top_[i]) top_[i] = kz;
  } else if (lost_occupied && kz == top_[i] && !dirty_flag_[i]) {
    dirty_flag_[i] = 1;
    dirty_.push_back(i);
  }
}

void ColumnLayers::applyFrame(const FrameUpdate& frame, const std::vector<uint8_t>& transitions, float time_s) {
  if (frame.updates.empty()) return;
  reserve(frame.box.min[0], frame.box.min[1], frame.box.max[0], frame.box.max[1]);
  for (std::size_t i = 0; i < frame.updates.size(); ++i) {
    const Key k = keyOfMorton(frame.updates[i].morton);
    const uint8_t t = transitions[i];
    observeColumn(k[0], k[1], k[2], (t & kIsOccupied) != 0, (t & kWasOccupied) != 0, time_s);
    if (k[2] < min_kz_) min_kz_ = k[2];
    obs_box_.add(Key(k[0], k[1], 0));
  }
}

void ColumnLayers::resolveDirty(const VoxelMap& map) {
  for (const std::size_t i : dirty_) {
    dirty_flag_[i] = 0;
    const int kx = kx0_ + static_cast<int>(i % static_cast<std::size_t>(w_));
    const int ky = ky0_ + static_cast<int>(i / static_cast<std::size_t>(w_));
    const int top = map.topOccupiedZ(static_cast<uint16_t>(kx), static_cast<uint16_t>(ky), top_[i] - 1, min_kz_);
    top_[i] = top < 0 ? kNoTop : top;
  }
  dirty_.clear();
}

void ColumnLayers::rebuild(const VoxelMap& map) {
  clear();
  KeyBox box;
  map.forEachLeaf(
      [&box](const Leaf& leaf) {
        box.add(leaf.key);
        box.add(Key(static_cast<uint16_t>(leaf.key[0] + leaf.size - 1), static_cast<uint16_t>(leaf.key[1] + leaf.size - 1),
                    static_cast<uint16_t>(leaf.key[2] + leaf.size - 1)));
      },
      false);
  if (box.empty()) return;
  reserve(box.min[0], box.min[1], box.max[0], box.max[1]);
  const float occ = map.logOdds().occupied;
  map.forEachLeaf(
      [&](const Leaf& leaf) {
        const bool occupied = leaf.state.log_odds >= occ;
        const int top_kz = leaf.key[2] + static_cast<int>(leaf.size) - 1;
        for (unsigned dy = 0; dy < leaf.size; ++dy) {
          for (unsigned dx = 0; dx < leaf.size; ++dx) {
            const int kx = leaf.key[0] + static_cast<int>(dx);
            const int ky = leaf.key[1] + static_cast<int>(dy);
            observeColumn(kx, ky, top_kz, occupied, false, leaf.state.time_s);
            obs_box_.add(Key(static_cast<uint16_t>(kx), static_cast<uint16_t>(ky), 0));
          }
        }
        if (leaf.key[2] < min_kz_) min_kz_ = leaf.key[2];
      },
      false);
}

int32_t ColumnLayers::top(int kx, int ky) const { return inside(kx, ky) ? top_[index(kx, ky)] : kNoTop; }
float ColumnLayers::lastSeen(int kx, int ky) const { return inside(kx, ky) ? last_[index(kx, ky)] : kNoTime; }
bool ColumnLayers::observed(int kx, int ky) const { return inside(kx, ky) && observed_[index(kx, ky)] != 0; }

std::size_t ColumnLayers::memoryBytes() const {
  return top_.capacity() * sizeof(int32_t) + last_.capacity() * sizeof(float) + observed_.capacity() * 2;
}

LayersSnapshot ColumnLayers::snapshot(int factor, double time_origin_s) const {
  LayersSnapshot s;
  factor = std::max(1, factor);
  s.resolution_m = res_m_ * factor;
  if (obs_box_.empty()) return s;
  // Layer cell (r, c) covers map columns with floor((k - 32768) / factor) == cell index.
  const int cx0 = floorDiv(obs_box_.min[0] - kKeyOffset, factor);
  const int cy0 = floorDiv(obs_box_.min[1] - kKeyOffset, factor);
  const int cx1 = floorDiv(obs_box_.max[0] - kKeyOffset, factor);
  const int cy1 = floorDiv(obs_box_.max[1] - kKeyOffset, factor);
  s.width = static_cast<uint32_t>(cx1 - cx0 + 1);
  s.height = static_cast<uint32_t>(cy1 - cy0 + 1);
  s.origin_x_m = cx0 * s.resolution_m;
  s.origin_y_m = cy0 * s.resolution_m;
  const std::size_t n = static_cast<std::size_t>(s.width) * s.height;
  const float nan = std::numeric_limits<float>::quiet_NaN();
  s.elevation_m.assign(n, nan);
  s.last_seen_s.assign(n, nan);
  s.observed.assign(n, 0.0f);
  std::vector<int32_t> top(n, kNoTop);
  std::vector<float> last(n, kNoTime);
  for (int ky = obs_box_.min[1]; ky <= obs_box_.max[1]; ++ky) {
    const std::size_t row = static_cast<std::size_t>(floorDiv(ky - kKeyOffset, factor) - cy0) * s.width;
    const std::size_t src_row = static_cast<std::size_t>(ky - ky0_) * w_;
    for (int kx = obs_box_.min[0]; kx <= obs_box_.max[0]; ++kx) {
      const std::size_t src = src_row + static_cast<std::size_t>(kx - kx0_);
      if (!observed_[src]) continue;
      const std::size_t dst = row + static_cast<std::size_t>(floorDiv(kx - kKeyOffset, factor) - cx0);
      s.observed[dst] = 1.0f;
      top[dst] = std::max(top[dst], top_[src]);
      last[dst] = std::max(last[dst], last_[src]);
    }
  }
  for (std::size_t i = 0; i < n; ++i) {
    if (top[i] != kNoTop) s.elevation_m[i] = static_cast<float>((top[i] - kKeyOffset + 0.5) * res_m_);
    if (last[i] != kNoTime) s.last_seen_s[i] = static_cast<float>(time_origin_s + last[i]);
  }
  return s;
}

}  // namespace uav_mapping
