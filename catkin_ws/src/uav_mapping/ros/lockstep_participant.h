// A roscpp node's side of the causal lockstep (docs/lockstep.md): the C++ twin of uav_common.ros.lockstep.Participant.
//
// A node builds one Participant (after ros::init) from readSettings(), makes its counted publishers and its
// services through it (with /lockstep/causal false they are roscpp's own, exactly as without it), and, when
// causal(), its lockstep inputs, simulated-time timers, step hooks and tf buffer too; then it calls spin(). When
// causal, spin():
//
//   * joins the step master (/lockstep/join) with the node's manifest, then works step by step in the calling
//     thread: for each tick it waits until every counted input has arrived (per (topic, publisher) FIFOs, the
//     pure uav_mapping/lockstep.h InputLedger), dispatches exactly the step's messages in the fixed order,
//     fires the timers that are due, runs the step hooks and publishes /lockstep/done with its published counts;
//   * between steps, applies the service requests due at that boundary: a request carrying the connection header
//     `lockstep_apply_after: S` is applied after step S, one without it at the next boundary; the service thread
//     waits until the step thread has applied it;
//   * now() is the step's time t_k (the tick's stamp), not ros::Time::now();
//   * a tick out of order, or an input that does not arrive within /lockstep/watchdog_s wall seconds, is reported
//     to the master as a done with an error and thrown as LockstepError (the node exits 1).
//
// Threads: the subscriptions' callbacks (inputs and ticks) only file messages, on their own callback queue and
// spinner thread; services (and any other callback of the global queue, e.g. wall timers) run on a pool of
// kServiceThreads spinner threads, each blocking until the step thread has served its request; the step runs in
// the thread that calls spin(). Build everything (publishers, inputs, services, timers, hooks) before spin().
#pragma once

#include <uav_mapping/lockstep.h>

#include <ros/callback_queue.h>
#include <ros/ros.h>
#include <tf2_ros/buffer.h>
#include <uav_msgs/LockstepTick.h>

#include <boost/shared_ptr.hpp>

#include <condition_variable>
#include <cstdint>
#include <deque>
#include <exception>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

namespace uav_mapping {
namespace lockstep {

/// The service connection header naming the step boundary a request applies at (docs/lockstep.md).
inline constexpr char kApplyAfterHeader[] = "lockstep_apply_after";
inline constexpr char kDefaultNs[] = "/lockstep";
/// Spinner threads for services in causal mode: how many service requests may wait for their boundary at once.
inline constexpr int kServiceThreads = 4;

/// The global /lockstep/* parameters as one node sees them.
struct Settings {
  bool causal = false;
  int lookahead_steps = 1;
  double watchdog_s = 120.0;
  std::string ns = kDefaultNs;
};

/// The node's lockstep settings from the parameter server (`default_lookahead`: its manifest's default, which
/// `<ns>/lookahead_steps/<node>` overrides). Throws std::invalid_argument naming a malformed parameter.
Settings readSettings(const std::string& node, int default_lookahead, const std::string& ns = kDefaultNs);

class Participant;

/// A publisher whose messages the lockstep counts (causal: unbounded queue, never drops) or a plain one.
class CountedPublisher {
 public:
  CountedPublisher() = default;

  template <class M>
  void publish(const M& msg) const;
  uint32_t getNumSubscribers() const { return pub_.getNumSubscribers(); }
  std::string getTopic() const { return pub_.getTopic(); }

 private:
  friend class Participant;
  CountedPublisher(const ros::Publisher& pub, Participant* owner)
      : pub_(pub), owner_(owner), topic_(pub.getTopic()) {}

  ros::Publisher pub_;
  Participant* owner_ = nullptr;  // null: not counted (not causal)
  std::string topic_;
};

class Participant {
 public:
  explicit Participant(const Settings& settings);
  ~Participant();
  Participant(const Participant&) = delete;
  Participant& operator=(const Participant&) = delete;

  bool causal() const { return settings_.causal; }
  const Settings& settings() const { return settings_; }
  const std::string& node() const { return node_; }

  /// A counted publisher that never drops (causal: queue 0) or nh.advertise's own (otherwise).
  template <class M>
  CountedPublisher advertise(ros::NodeHandle& nh, const std::string& topic, uint32_t queue_size, bool latch = false,
                             const ros::SubscriberStatusCallback& connect = ros::SubscriberStatusCallback());

  /// A lockstep input (causal only): unbounded and tcp_nodelay, filed per (topic, publisher); `callback` runs in
  /// the step thread, in dispatch order (`priority`: before the inputs declared so far, like tf).
  template <class M>
  void subscribe(ros::NodeHandle& nh, const std::string& topic,
                 const std::function<void(const boost::shared_ptr<const M>&)>& callback, bool priority = false);

  /// A service whose requests apply at step boundaries (causal) or at once, as nh.advertiseService (otherwise).
  template <class Req, class Res>
  ros::ServiceServer advertiseService(ros::NodeHandle& nh, const std::string& name,
                                      const std::function<bool(Req&, Res&)>& handler);

  /// `callback(now_s)` every `period_s` of simulated time, fired from the step (causal only; `name` is the
  /// manifest's "name period").
  void timer(double period_s, const std::function<void(double)>& callback, const std::string& name);

  /// `hook(step, now_s)` once a step, after the inputs and the timers (causal only).
  void onStep(const std::function<void(uint64_t, double)>& hook);

  /// Feed `buffer` from counted /tf and /tf_static inputs, dispatched before the other inputs (causal only).
  void feedTf(tf2_ros::Buffer& buffer);

  /// The step's time (causal; the last step's between steps, 0 before the first), else ros::Time::now().
  ros::Time now() const;

  /// ros::spin() (not causal); causal: join, then process ticks in this thread until shutdown.
  /// Throws LockstepError: the master refused the join, a tick came out of order, an input never arrived (the
  /// master has been told).
  void spin();

  /// Stop the step loop and the spinner threads (a node calls it first in its destructor).
  void shutdown();

  /// Count one message published on `topic` (CountedPublisher does it).
  void count(const std::string& topic);

 private:
  using Message = boost::shared_ptr<const void>;
  struct Input {
    std::string datatype;
    std::vector<std::function<void(const Message&)>> callbacks;
  };
  struct Request {
    enum class State { kQueued, kRunning, kDone, kCancelled };
    std::function<void()> work;
    State state = State::kQueued;
    std::exception_ptr error;
  };
  using RequestPtr = std::shared_ptr<Request>;
  struct PendingTick {
    Tick tick;
    ros::Time stamp;
  };
  struct Timer {
    SimTimer timer;
    std::function<void(double)> callback;
  };
  struct Interrupted {};  // shutdown while waiting

  void requireCausal(const char* what) const;
  void registerOutput(const std::string& topic);
  /// Returns true when `resolved` is a new input (then the caller subscribes it).
  bool registerInput(const std::string& resolved, const std::string& datatype,
                     std::function<void(const Message&)> callback, bool priority);
  void file(const std::string& topic, const std::string& publisher, const Message& msg);
  void onTick(const uav_msgs::LockstepTick::ConstPtr& msg);
  /// Called in a service thread: queue `work` for its boundary and wait until the step thread has run it.
  void applyAtBoundary(const std::string& service, const ros::M_string& header, std::function<void()> work);

  void join();
  bool nextWork(std::vector<RequestPtr>& requests, std::optional<PendingTick>& tick);
  void serve(const std::vector<RequestPtr>& requests);
  void runStep(const PendingTick& pending);
  std::vector<std::pair<std::string, Message>> waitInputs(const Tick& tick);
  void reportDone(uint64_t step, const std::string& error);
  [[noreturn]] void fail(const std::string& text);
  bool stopping() const;

  Settings settings_;
  std::string node_;
  ros::NodeHandle nh_;

  mutable std::mutex mutex_;  // guards everything below up to the counts
  std::condition_variable cv_;
  InputLedger<Message> ledger_;
  std::deque<PendingTick> ticks_;
  std::string counted_;                                    // the last tick's "topic publisher" lines
  std::vector<std::pair<std::string, std::string>> keys_;  // ... parsed (tick callback thread only)
  BoundaryQueue<RequestPtr> requests_;
  uint64_t first_step_ = 1;
  uint64_t finished_step_ = 0;
  std::optional<uint64_t> processing_step_;
  ros::Time stamp_;
  bool stopping_ = false;

  std::mutex counts_mutex_;
  std::map<std::string, uint64_t> counts_;  // cumulative per output topic

  // Set up before spin(), read-only afterwards.
  std::map<std::string, Input> inputs_;
  std::vector<std::string> input_names_;
  std::vector<std::string> output_names_;
  std::vector<Timer> timers_;
  std::vector<std::function<void(uint64_t, double)>> step_hooks_;

  ros::CallbackQueue input_queue_;
  std::vector<ros::Subscriber> subscribers_;
  ros::Subscriber tick_sub_;
  ros::Publisher done_pub_;
  std::unique_ptr<ros::AsyncSpinner> input_spinner_;
  std::unique_ptr<ros::AsyncSpinner> service_spinner_;
};

// ------------------------------------------------------------------------------------------------- templates

template <class M>
void CountedPublisher::publish(const M& msg) const {
  pub_.publish(msg);
  if (owner_ != nullptr) owner_->count(topic_);
}

template <class M>
CountedPublisher Participant::advertise(ros::NodeHandle& nh, const std::string& topic, uint32_t queue_size, bool latch,
                                        const ros::SubscriberStatusCallback& connect) {
  const ros::SubscriberStatusCallback none;
  if (!causal()) return CountedPublisher(nh.advertise<M>(topic, queue_size, connect, none, ros::VoidConstPtr(), latch), nullptr);
  const ros::Publisher pub = nh.advertise<M>(topic, 0, connect, none, ros::VoidConstPtr(), latch);
  registerOutput(pub.getTopic());
  return CountedPublisher(pub, this);
}

template <class M>
void Participant::subscribe(ros::NodeHandle& nh, const std::string& topic,
                            const std::function<void(const boost::shared_ptr<const M>&)>& callback, bool priority) {
  requireCausal("subscribe");
  const std::string resolved = nh.resolveName(topic);
  const auto typed = [callback](const Message& msg) { callback(boost::static_pointer_cast<const M>(msg)); };
  if (!registerInput(resolved, ros::message_traits::DataType<M>::value(), typed, priority)) return;
  ros::SubscribeOptions ops;
  ops.template initByFullCallbackType<const ros::MessageEvent<M const>&>(
      topic, 0, [this, resolved](const ros::MessageEvent<M const>& event) {
        file(resolved, event.getPublisherName(), event.getConstMessage());
      });
  ops.callback_queue = &input_queue_;
  ops.transport_hints = ros::TransportHints().tcpNoDelay();
  subscribers_.push_back(nh.subscribe(ops));
}

template <class Req, class Res>
ros::ServiceServer Participant::advertiseService(ros::NodeHandle& nh, const std::string& name,
                                                 const std::function<bool(Req&, Res&)>& handler) {
  if (!causal()) return nh.advertiseService<Req, Res>(name, boost::function<bool(Req&, Res&)>(handler));
  const std::string resolved = nh.resolveName(name);
  const boost::function<bool(ros::ServiceEvent<Req, Res>&)> deferred =
      [this, handler, resolved](ros::ServiceEvent<Req, Res>& event) {
        Req req = event.getRequest();
        Res& res = event.getResponse();
        bool ok = false;
        applyAtBoundary(resolved, event.getConnectionHeader(), [&] { ok = handler(req, res); });
        return ok;
      };
  ros::AdvertiseServiceOptions ops;
  ops.template initBySpecType<ros::ServiceEvent<Req, Res>>(name, deferred);
  return nh.advertiseService(ops);
}

}  // namespace lockstep
}  // namespace uav_mapping
