// The causal lockstep's bookkeeping (docs/lockstep.md) for C++ participants, pure: no ROS, no clocks, no threads.
//
// The C++ twin of uav_common.lockstep.protocol (InputLedger, BoundaryQueue) and uav_common.lockstep.timers
// (SimTimer): the same decisions on the same inputs (tests/unit/mapping/test_lockstep_cpp.py replays random traces
// through both). The ROS shell is ros/lockstep_participant.h; it feeds these what arrived and asks them what to
// do. Every decision is a function of step numbers and counts only.
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <map>
#include <optional>
#include <set>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace uav_mapping {
namespace lockstep {

/// The causal lockstep cannot go on reproducibly: a lost or duplicated message, a participant out of step. The
/// message names who and what; the run must stop (a watchdog never lets a step through).
class LockstepError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// (topic, publisher)
using Key = std::pair<std::string, std::string>;

/// Step `step` at simulation time `t_s`: each consumer takes, per (topic, publisher), messages up to
/// `counts[(topic, publisher)]`. `participants` are the publishers whose messages are counted.
struct Tick {
  uint64_t step = 0;
  double t_s = 0.0;
  std::map<Key, uint64_t> counts;
  std::set<std::string> participants;
};

/// A subscriber is short of messages from one publisher on one topic at a tick.
struct Missing {
  std::string topic;
  std::string publisher;
  uint64_t expected = 0;
  uint64_t received = 0;
};

/// "topic from publisher (received of expected), ..." (at most six, then "and N more").
std::string describe(const std::vector<Missing>& missing);

/// A ROS stamp as seconds, exactly as rospy's Time.to_sec() computes it (secs + nsecs / 1e9), so that timers
/// decide alike in Python and C++ participants.
double stampSeconds(uint32_t sec, uint32_t nsec);

/// The step boundary named by a `lockstep_apply_after` connection header: a decimal integer >= 0.
/// Throws std::invalid_argument naming the header and the value.
int64_t parseApplyAfter(const std::string& raw);

/// A participant's counted inputs: one FIFO per (topic, publisher), taken exactly up to each tick's counts.
///
/// `topics` are its lockstep input topics in dispatch order (addTopic(..., first = true) puts one before the
/// others, like tf). Messages from publishers that are not participants (Tick::participants) are "foreign":
/// dispatched after the counted ones, in arrival order, at the step in which they are taken. Not thread-safe: the
/// shell serialises calls.
template <class M>
class InputLedger {
 public:
  explicit InputLedger(const std::vector<std::string>& topics = {}) {
    for (const std::string& t : topics) addTopic(t);
  }

  /// Declare one more input topic (`first`: dispatched before those declared so far).
  void addTopic(const std::string& topic, bool first = false) {
    if (order_.count(topic) != 0) return;
    if (first) {
      topics_.insert(topics_.begin(), topic);
    } else {
      topics_.push_back(topic);
    }
    order_.clear();
    for (std::size_t i = 0; i < topics_.size(); ++i) order_[topics_[i]] = i;
  }

  const std::vector<std::string>& topics() const { return topics_; }

  /// A message arrived.
  void received(const std::string& topic, const std::string& publisher, M msg) {
    const uint64_t seq = seq_++;
    if (!participants_) {
      unclassified_.push_back({seq, topic, publisher, std::move(msg)});
      return;
    }
    file(seq, topic, publisher, std::move(msg));
  }

  /// What the inputs lack before `tick` can be dispatched (empty: ready).
  /// Throws LockstepError when more messages were taken from a publisher than its count (a duplicate, or a
  /// publisher that restarted): the run is no longer reproducible.
  std::vector<Missing> missing(const Tick& tick) {
    learn(tick);
    std::vector<Missing> out;
    for (const auto& [key, expected] : tick.counts) {  // sorted by (topic, publisher)
      if (order_.count(key.first) == 0) continue;
      const uint64_t taken = takenOf(key);
      if (expected < taken) {
        throw LockstepError(key.first + " from " + key.second + ": the tick of step " + std::to_string(tick.step) +
                            " counts " + std::to_string(expected) + " messages but " + std::to_string(taken) +
                            " were already taken (a duplicate message, or the publisher restarted)");
      }
      const auto it = fifo_.find(key);
      const uint64_t have = taken + (it == fifo_.end() ? 0 : it->second.size());
      if (have < expected) out.push_back({key.first, key.second, expected, have});
    }
    return out;
  }

  /// The step's inputs in dispatch order: counted ones by topic, publisher, arrival; then foreign ones.
  /// Throws LockstepError when the inputs are not complete (call missing() first) or counts went backwards.
  std::vector<std::pair<std::string, M>> take(const Tick& tick) {
    const std::vector<Missing> short_of = missing(tick);
    if (!short_of.empty()) {
      const Missing& m = short_of.front();
      throw LockstepError("step " + std::to_string(tick.step) + ": " + m.topic + " from " + m.publisher + ": " +
                          std::to_string(m.received) + " of " + std::to_string(m.expected) + " messages");
    }
    std::vector<std::pair<std::size_t, const Key*>> keys;
    for (const auto& [key, expected] : tick.counts) {
      const auto it = order_.find(key.first);
      if (it != order_.end()) keys.emplace_back(it->second, &key);
    }
    // Topics in dispatch order, publishers by name (tick.counts is already sorted by publisher within a topic).
    std::stable_sort(keys.begin(), keys.end(),
                     [](const auto& a, const auto& b) { return a.first < b.first; });
    std::vector<std::pair<std::string, M>> out;
    for (const auto& [order, key] : keys) {
      const uint64_t expected = tick.counts.at(*key);
      uint64_t& taken = taken_[*key];
      if (expected > taken) {
        std::deque<M>& fifo = fifo_[*key];
        for (uint64_t n = expected - taken; n > 0; --n) {
          out.emplace_back(key->first, std::move(fifo.front()));
          fifo.pop_front();
        }
      }
      taken = expected;
    }
    for (Foreign& f : foreign_) out.emplace_back(f.topic, std::move(f.msg));
    foreign_.clear();
    return out;
  }

  /// Messages received and not yet dispatched (a publisher ahead of the ticks).
  std::size_t held() const {
    std::size_t n = foreign_.size() + unclassified_.size();
    for (const auto& [key, fifo] : fifo_) n += fifo.size();
    return n;
  }

 private:
  struct Foreign {
    uint64_t seq;
    std::string topic;
    M msg;
  };
  struct Unclassified {
    uint64_t seq;
    std::string topic;
    std::string publisher;
    M msg;
  };

  uint64_t takenOf(const Key& key) const {
    const auto it = taken_.find(key);
    return it == taken_.end() ? 0 : it->second;
  }

  void file(uint64_t seq, const std::string& topic, const std::string& publisher, M msg) {
    if (participants_->count(publisher) != 0) {
      fifo_[{topic, publisher}].push_back(std::move(msg));
    } else {
      foreign_.push_back({seq, topic, std::move(msg)});
    }
  }

  /// Messages that came before the first tick named the participants are classified now, in arrival order.
  void learn(const Tick& tick) {
    if (participants_ && *participants_ == tick.participants) return;
    participants_ = tick.participants;
    std::vector<Unclassified> pending;
    pending.swap(unclassified_);
    for (Unclassified& u : pending) file(u.seq, u.topic, u.publisher, std::move(u.msg));
  }

  std::vector<std::string> topics_;
  std::map<std::string, std::size_t> order_;
  std::map<Key, std::deque<M>> fifo_;
  std::map<Key, uint64_t> taken_;
  std::vector<Foreign> foreign_;
  std::vector<Unclassified> unclassified_;
  std::optional<std::set<std::string>> participants_;
  uint64_t seq_ = 0;
};

/// Service requests waiting for their step boundary (docs/lockstep.md, "Services between participants").
/// A request for boundary S | S+1 is applied once the server has finished step S and before it starts S + 1;
/// requests of one boundary go in arrival order.
template <class R>
class BoundaryQueue {
 public:
  void put(int64_t apply_after, R item) { items_.emplace(std::make_pair(apply_after, seq_++), std::move(item)); }

  /// The requests whose boundary is at or before the end of `finished_step`, in order.
  std::vector<R> due(int64_t finished_step) {
    std::vector<R> out;
    while (!items_.empty() && items_.begin()->first.first <= finished_step) {
      out.push_back(std::move(items_.begin()->second));
      items_.erase(items_.begin());
    }
    return out;
  }

  std::size_t size() const { return items_.size(); }
  bool empty() const { return items_.empty(); }

 private:
  std::map<std::pair<int64_t, uint64_t>, R> items_;
  uint64_t seq_ = 0;
};

/// A timer in simulated time, fired from the step (docs/lockstep.md, "Steps and time"): due first at
/// `first_due_s` (default: one period after time 0), then it fires once at the first step whose time reaches its
/// due time and its due time moves on by whole periods past that step (no catch-up bursts).
class SimTimer {
 public:
  /// Throws std::invalid_argument unless `period_s` is a positive finite number.
  explicit SimTimer(double period_s, std::optional<double> first_due_s = std::nullopt, std::string name = "");

  /// Fire at `t_s`? (Advances the timer when it does.) Times must not go backwards.
  bool due(double t_s);

  /// "name period" (period as %g), the manifest's form.
  std::string describe() const;

  double periodS() const { return period_s_; }
  double nextDueS() const { return next_due_s_; }
  uint64_t fired() const { return fired_; }
  const std::string& name() const { return name_; }

 private:
  double period_s_;
  std::string name_;
  double next_due_s_;
  uint64_t fired_ = 0;
};

}  // namespace lockstep
}  // namespace uav_mapping
