// A roscpp node's side of the causal lockstep: see lockstep_participant.h and docs/lockstep.md.
#include "lockstep_participant.h"

#include <tf2_msgs/TFMessage.h>
#include <uav_msgs/LockstepDone.h>
#include <uav_msgs/LockstepJoin.h>

#include <chrono>
#include <cmath>
#include <sstream>

namespace uav_mapping {
namespace lockstep {
namespace {

/// Wall seconds between "still waiting" log lines (a watchdog that only reports).
constexpr double kReportEveryS = 10.0;

std::string show(XmlRpc::XmlRpcValue& value) {
  std::ostringstream os;
  os << value;
  return os.str();
}

double secondsSince(std::chrono::steady_clock::time_point t) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
}

}  // namespace

Settings readSettings(const std::string& node, int default_lookahead, const std::string& ns) {
  Settings s;
  s.ns = ns;
  s.lookahead_steps = default_lookahead;
  XmlRpc::XmlRpcValue value;
  if (ros::param::get(ns + "/causal", value)) {
    if (value.getType() != XmlRpc::XmlRpcValue::TypeBoolean)
      throw std::invalid_argument(ns + "/causal must be true or false, got " + show(value));
    s.causal = static_cast<bool>(value);
  }
  const std::string bare = !node.empty() && node[0] == '/' ? node.substr(1) : node;
  XmlRpc::XmlRpcValue table;
  if (ros::param::get(ns + "/lookahead_steps", table) && table.valid()) {
    if (table.getType() != XmlRpc::XmlRpcValue::TypeStruct)
      throw std::invalid_argument(ns + "/lookahead_steps must map node names to steps, got " + show(table));
    if (table.hasMember(bare)) {
      XmlRpc::XmlRpcValue& entry = table[bare];
      if (entry.getType() != XmlRpc::XmlRpcValue::TypeInt || static_cast<int>(entry) < 1)
        throw std::invalid_argument(ns + "/lookahead_steps/" + bare + " must be an integer >= 1, got " + show(entry));
      s.lookahead_steps = static_cast<int>(entry);
    }
  }
  if (ros::param::get(ns + "/watchdog_s", value)) {
    double w = 0.0;
    if (value.getType() == XmlRpc::XmlRpcValue::TypeDouble) {
      w = static_cast<double>(value);
    } else if (value.getType() == XmlRpc::XmlRpcValue::TypeInt) {
      w = static_cast<int>(value);
    } else {
      w = std::nan("");
    }
    if (!(std::isfinite(w) && w > 0.0))
      throw std::invalid_argument(ns + "/watchdog_s must be a positive number of seconds, got " + show(value));
    s.watchdog_s = w;
  }
  if (s.lookahead_steps < 1)
    throw std::invalid_argument(node + ": lookahead_steps must be >= 1, got " + std::to_string(s.lookahead_steps));
  return s;
}

// ------------------------------------------------------------------------------------------------- building

Participant::Participant(const Settings& settings) : settings_(settings), node_(ros::this_node::getName()) {
  if (!causal()) return;
  ros::SubscribeOptions ops;
  ops.init<uav_msgs::LockstepTick>(settings_.ns + "/tick", 0,
                                   [this](const uav_msgs::LockstepTick::ConstPtr& msg) { onTick(msg); });
  ops.callback_queue = &input_queue_;
  ops.transport_hints = ros::TransportHints().tcpNoDelay();
  tick_sub_ = nh_.subscribe(ops);
  done_pub_ = nh_.advertise<uav_msgs::LockstepDone>(settings_.ns + "/done", 0);
}

Participant::~Participant() { shutdown(); }

void Participant::shutdown() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stopping_ = true;
  }
  cv_.notify_all();
  if (input_spinner_) input_spinner_->stop();
  if (service_spinner_) service_spinner_->stop();
  for (ros::Subscriber& s : subscribers_) s.shutdown();
  tick_sub_.shutdown();
}

void Participant::requireCausal(const char* what) const {
  if (!causal()) throw std::logic_error(std::string("lockstep Participant::") + what + " is for causal mode only");
}

void Participant::registerOutput(const std::string& topic) {
  std::lock_guard<std::mutex> lock(counts_mutex_);
  if (counts_.count(topic) != 0) return;
  counts_[topic] = 0;
  output_names_.push_back(topic);
}

void Participant::count(const std::string& topic) {
  std::lock_guard<std::mutex> lock(counts_mutex_);
  ++counts_[topic];
}

bool Participant::registerInput(const std::string& resolved, const std::string& datatype,
                                std::function<void(const Message&)> callback, bool priority) {
  std::lock_guard<std::mutex> lock(mutex_);
  Input& input = inputs_[resolved];
  const bool first = input.datatype.empty();
  if (!first && input.datatype != datatype) {
    throw std::invalid_argument("lockstep input " + resolved + " subscribed as " + input.datatype + " and as " +
                                datatype);
  }
  input.datatype = datatype;
  input.callbacks.push_back(std::move(callback));
  if (first) {
    ledger_.addTopic(resolved, priority);
    input_names_.push_back(resolved);
  }
  return first;
}

void Participant::timer(double period_s, const std::function<void(double)>& callback, const std::string& name) {
  requireCausal("timer");
  timers_.push_back({SimTimer(period_s, std::nullopt, name), callback});
}

void Participant::onStep(const std::function<void(uint64_t, double)>& hook) {
  requireCausal("onStep");
  step_hooks_.push_back(hook);
}

void Participant::feedTf(tf2_ros::Buffer& buffer) {
  requireCausal("feedTf");
  // Each is dispatched before the inputs declared so far: /tf_static, then /tf, then the node's own.
  subscribe<tf2_msgs::TFMessage>(
      nh_, "/tf",
      [&buffer](const tf2_msgs::TFMessage::ConstPtr& msg) {
        for (const auto& t : msg->transforms) buffer.setTransform(t, "lockstep", false);
      },
      true);
  subscribe<tf2_msgs::TFMessage>(
      nh_, "/tf_static",
      [&buffer](const tf2_msgs::TFMessage::ConstPtr& msg) {
        for (const auto& t : msg->transforms) buffer.setTransform(t, "lockstep", true);
      },
      true);
}

ros::Time Participant::now() const {
  if (!causal()) return ros::Time::now();
  std::lock_guard<std::mutex> lock(mutex_);
  return stamp_;
}

/// The lines of a protocol text field ("" has none).
std::vector<std::string> splitLines(const std::string& text) {
  std::vector<std::string> out;
  std::size_t start = 0;
  while (start < text.size()) {
    const auto end = text.find('\n', start);
    out.push_back(text.substr(start, end == std::string::npos ? std::string::npos : end - start));
    if (end == std::string::npos) break;
    start = end + 1;
  }
  return out;
}

// ------------------------------------------------------------------------------------------------- callbacks

void Participant::file(const std::string& topic, const std::string& publisher, const Message& msg) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    ledger_.received(topic, publisher, msg);
  }
  cv_.notify_all();
}

void Participant::onTick(const uav_msgs::LockstepTick::ConstPtr& msg) {
  PendingTick pending;
  pending.tick.step = msg->step;
  pending.tick.t_s = stampSeconds(msg->header.stamp.sec, msg->header.stamp.nsec);
  // "topic publisher" lines aligned with the counts (they change only when a publisher first publishes on a topic)
  if (msg->counted != counted_) {
    counted_ = msg->counted;
    keys_.clear();
    for (const std::string& line : splitLines(counted_)) {
      const auto space = line.find(' ');
      keys_.emplace_back(line.substr(0, space), space == std::string::npos ? std::string() : line.substr(space + 1));
    }
  }
  if (keys_.size() != msg->counts.size()) {
    ROS_ERROR("%s: lockstep: a malformed tick of step %llu: %zu keys, %zu counts (ignored)", node_.c_str(),
              static_cast<unsigned long long>(msg->step), keys_.size(), msg->counts.size());
    return;
  }
  for (std::size_t i = 0; i < keys_.size(); ++i) pending.tick.counts[keys_[i]] = msg->counts[i];
  for (const std::string& name : splitLines(msg->participants)) pending.tick.participants.insert(name);
  pending.stamp = msg->header.stamp;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (pending.tick.step >= first_step_) ticks_.push_back(std::move(pending));
  }
  cv_.notify_all();
}

void Participant::applyAtBoundary(const std::string& service, const ros::M_string& header,
                                  std::function<void()> work) {
  const auto caller = header.find("callerid");
  const std::string who = caller == header.end() ? std::string("?") : caller->second;
  const auto raw = header.find(kApplyAfterHeader);
  auto request = std::make_shared<Request>();
  request->work = std::move(work);
  {
    std::unique_lock<std::mutex> lock(mutex_);
    // The boundary the node is at: after the step it is processing, else after the step it finished.
    const uint64_t current = processing_step_ ? *processing_step_ : finished_step_;
    int64_t boundary = static_cast<int64_t>(current);
    if (raw != header.end()) {
      boundary = parseApplyAfter(raw->second);  // std::invalid_argument: roscpp answers the caller with it
      if (boundary < static_cast<int64_t>(current)) {
        const std::string where = processing_step_ ? "it is processing step " + std::to_string(*processing_step_)
                                                   : "it finished step " + std::to_string(finished_step_);
        // Thrown to roscpp, which logs it and answers the caller with this text.
        throw LockstepError(node_ + ": " + service + " from " + who + " for the boundary after step " +
                            std::to_string(boundary) + " came when " + where +
                            ": too late to apply it there, the run is no longer reproducible");
      }
    }
    requests_.put(boundary, request);
    cv_.notify_all();
    while (request->state != Request::State::kDone) {
      cv_.wait_for(lock, std::chrono::seconds(1));
      if ((stopping_ || !ros::ok()) && request->state == Request::State::kQueued) {
        request->state = Request::State::kCancelled;
        throw std::runtime_error(node_ + " is shutting down; " + service + " was not applied");
      }
    }
  }
  if (request->error) std::rethrow_exception(request->error);
}

// ------------------------------------------------------------------------------------------------- running

bool Participant::stopping() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return stopping_ || !ros::ok();
}

void Participant::spin() {
  if (!causal()) {
    ros::spin();
    return;
  }
  input_spinner_ = std::make_unique<ros::AsyncSpinner>(1, &input_queue_);
  input_spinner_->start();
  service_spinner_ = std::make_unique<ros::AsyncSpinner>(kServiceThreads);
  service_spinner_->start();
  try {
    join();
    std::vector<RequestPtr> requests;
    std::optional<PendingTick> tick;
    while (nextWork(requests, tick)) {
      if (tick) {
        runStep(*tick);
        tick.reset();
      } else {
        serve(requests);
      }
    }
  } catch (const Interrupted&) {
    return;
  }
}

void Participant::join() {
  const std::string service = settings_.ns + "/join";
  const auto started = std::chrono::steady_clock::now();
  while (true) {
    if (stopping()) throw Interrupted();
    if (ros::service::waitForService(service, static_cast<int32_t>(1000 * kReportEveryS))) break;
    ROS_WARN("%s: lockstep: still waiting for the step master's %s (%.0f s; is the sim bridge up?)", node_.c_str(),
             service.c_str(), secondsSince(started));
  }
  uav_msgs::LockstepJoin srv;
  srv.request.node = node_;
  srv.request.lookahead_steps = static_cast<uint32_t>(settings_.lookahead_steps);
  srv.request.inputs = input_names_;
  srv.request.outputs = output_names_;
  for (const Timer& t : timers_) srv.request.timers.push_back(t.timer.describe());
  {
    std::lock_guard<std::mutex> lock(counts_mutex_);
    for (const auto& [topic, n] : counts_) {  // sorted by topic
      srv.request.topics += (srv.request.topics.empty() ? "" : "\n") + topic;
      srv.request.published.push_back(n);
    }
  }
  if (!ros::service::call(service, srv)) {
    if (stopping()) throw Interrupted();
    throw LockstepError(node_ + ": the call of the step master's " + service + " failed (did the master stop?)");
  }
  if (!srv.response.accepted)
    throw LockstepError(node_ + ": the step master refused the join: " + srv.response.message);
  {
    std::lock_guard<std::mutex> lock(mutex_);
    first_step_ = srv.response.first_step;
    finished_step_ = first_step_ > 0 ? first_step_ - 1 : 0;
    while (!ticks_.empty() && ticks_.front().tick.step < first_step_) ticks_.pop_front();
  }
  ROS_INFO("%s: lockstep: joined (lookahead %d steps, %zu inputs, %zu outputs, %zu timers)", node_.c_str(),
           settings_.lookahead_steps, input_names_.size(), output_names_.size(), timers_.size());
}

bool Participant::nextWork(std::vector<RequestPtr>& requests, std::optional<PendingTick>& tick) {
  std::unique_lock<std::mutex> lock(mutex_);
  while (!stopping_ && ros::ok()) {
    requests = requests_.due(static_cast<int64_t>(finished_step_));
    if (!requests.empty()) return true;
    if (!ticks_.empty()) {
      tick = std::move(ticks_.front());
      ticks_.pop_front();
      return true;
    }
    cv_.wait_for(lock, std::chrono::seconds(1));
  }
  return false;
}

void Participant::serve(const std::vector<RequestPtr>& requests) {
  for (const RequestPtr& r : requests) {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (r->state == Request::State::kCancelled) continue;
      r->state = Request::State::kRunning;
    }
    try {
      r->work();
    } catch (...) {  // the caller gets the error (roscpp answers with its text)
      r->error = std::current_exception();
    }
    {
      std::lock_guard<std::mutex> lock(mutex_);
      r->state = Request::State::kDone;
    }
    cv_.notify_all();
  }
}

void Participant::runStep(const PendingTick& pending) {
  const Tick& tick = pending.tick;
  uint64_t finished = 0;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    finished = finished_step_;
  }
  if (tick.step != finished + 1) {
    fail("tick of step " + std::to_string(tick.step) + " after step " + std::to_string(finished) +
         ": ticks must come in order");
  }
  {
    std::lock_guard<std::mutex> lock(mutex_);
    processing_step_ = tick.step;
    stamp_ = pending.stamp;
  }
  const auto batch = waitInputs(tick);
  try {
    for (const auto& [topic, msg] : batch) {
      for (const auto& callback : inputs_.at(topic).callbacks) callback(msg);
    }
    for (Timer& t : timers_) {
      if (t.timer.due(tick.t_s)) t.callback(tick.t_s);
    }
    for (const auto& hook : step_hooks_) hook(tick.step, tick.t_s);
  } catch (const LockstepError&) {
    throw;
  } catch (const std::exception& e) {  // tell the master at once rather than leaving it to its watchdog
    fail("step " + std::to_string(tick.step) + " failed: " + e.what());
  }
  reportDone(tick.step, "");
  {
    std::lock_guard<std::mutex> lock(mutex_);
    finished_step_ = tick.step;
    processing_step_.reset();
  }
}

std::vector<std::pair<std::string, Participant::Message>> Participant::waitInputs(const Tick& tick) {
  const auto started = std::chrono::steady_clock::now();
  auto reported = started;
  std::unique_lock<std::mutex> lock(mutex_);
  while (true) {
    std::vector<Missing> missing;
    std::string error;
    try {
      missing = ledger_.missing(tick);
      if (missing.empty()) return ledger_.take(tick);
    } catch (const LockstepError& e) {
      error = e.what();
    }
    if (!error.empty()) {
      lock.unlock();
      fail("step " + std::to_string(tick.step) + ": " + error);
    }
    cv_.wait_for(lock, std::chrono::milliseconds(500));
    if (stopping_ || !ros::ok()) throw Interrupted();
    const double waited = secondsSince(started);
    if (waited > settings_.watchdog_s) {
      lock.unlock();
      fail("step " + std::to_string(tick.step) + ": inputs never arrived within " + settings_.ns +
           "/watchdog_s (" + std::to_string(static_cast<int>(std::lround(settings_.watchdog_s))) +
           " s): " + describe(missing));
    }
    if (std::chrono::duration<double>(std::chrono::steady_clock::now() - reported).count() >= kReportEveryS) {
      reported = std::chrono::steady_clock::now();
      ROS_WARN("%s: lockstep: step %llu still waits after %.0f s for %s", node_.c_str(),
               static_cast<unsigned long long>(tick.step), waited, describe(missing).c_str());
    }
  }
}

void Participant::reportDone(uint64_t step, const std::string& error) {
  uav_msgs::LockstepDone msg;
  msg.node = node_;
  msg.step = step;
  msg.error = error;
  {
    std::lock_guard<std::mutex> lock(counts_mutex_);
    for (const auto& [topic, n] : counts_) {  // sorted by topic
      msg.topics += (msg.topics.empty() ? "" : "\n") + topic;
      msg.published.push_back(n);
    }
  }
  done_pub_.publish(msg);
}

void Participant::fail(const std::string& text) {
  uint64_t step = 0;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    step = processing_step_ ? *processing_step_ : finished_step_ + 1;
  }
  const std::string msg = node_ + ": " + text;
  try {
    reportDone(step, msg);
    // roscpp writes the done from its own threads: give it a moment to leave before the caller exits.
    ros::WallDuration(1.0).sleep();
  } catch (...) {  // the error below is what matters
  }
  throw LockstepError(msg);
}

}  // namespace lockstep
}  // namespace uav_mapping
