// Tests of the causal lockstep's C++ bookkeeping (uav_mapping/lockstep.h) without ROS.
//
//   lockstep_tests --list          names of all tests
//   lockstep_tests NAME [NAME...]  run the named tests (exit 1 if any fails)
//   lockstep_tests --all           run every test
//   lockstep_tests --replay        read a trace of ledger, boundary-queue and timer operations on stdin and print
//                                  every decision (tests/unit/mapping/test_lockstep_cpp.py replays the same random
//                                  traces through the Python reference, uav_common.lockstep, and compares)
//
// tests/unit/mapping/test_lockstep_cpp.py runs each test as its own pytest case.
#include <uav_mapping/lockstep.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <functional>
#include <iostream>
#include <map>
#include <memory>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

using namespace uav_mapping::lockstep;

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

template <class E, class F>
std::string checkThrows(F&& f, const std::string& what) {
  try {
    f();
  } catch (const E& e) {
    return e.what();
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
  const Register register_##name(#name, test_##name); \
  void test_##name()

using Ledger = InputLedger<std::string>;
using Batch = std::vector<std::pair<std::string, std::string>>;

Tick tick(uint64_t step, std::map<Key, uint64_t> counts, std::set<std::string> participants) {
  Tick t;
  t.step = step;
  t.t_s = 0.1 * static_cast<double>(step);
  t.counts = std::move(counts);
  t.participants = std::move(participants);
  return t;
}

std::string show(const Batch& batch) {
  std::string out;
  for (const auto& [topic, msg] : batch) out += (out.empty() ? "" : " ") + topic + ":" + msg;
  return out;
}

/// The map server's inputs in the order its participant declares them: the cloud, then /tf and /tf_static, each
/// dispatched first (so /tf_static, /tf, cloud).
Ledger mapServerLedger() {
  Ledger l({"/cloud"});
  l.addTopic("/tf", true);
  l.addTopic("/tf_static", true);
  return l;
}

// ------------------------------------------------------------------------------------------------- ledger

TEST(ledger_dispatch_order_is_topics_then_publishers_then_arrival) {
  Ledger l = mapServerLedger();
  CHECK((l.topics() == std::vector<std::string>{"/tf_static", "/tf", "/cloud"}));
  l.addTopic("/cloud");  // declared twice: no change
  CHECK(l.topics().size() == 3);
  l.received("/cloud", "/b", "b1");
  l.received("/tf", "/b", "tb1");
  l.received("/cloud", "/a", "a1");
  l.received("/tf_static", "/a", "s1");
  l.received("/cloud", "/b", "b2");
  l.received("/tf", "/a", "ta1");
  const Tick t = tick(1, {{{"/cloud", "/a"}, 1}, {{"/cloud", "/b"}, 2}, {{"/tf", "/a"}, 1}, {{"/tf", "/b"}, 1},
                          {{"/tf_static", "/a"}, 1}},
                      {"/a", "/b"});
  CHECK(l.missing(t).empty());
  const std::string got = show(l.take(t));
  CHECK_MSG(got == "/tf_static:s1 /tf:ta1 /tf:tb1 /cloud:a1 /cloud:b1 /cloud:b2", got);
  CHECK(l.held() == 0);
}

TEST(ledger_order_does_not_depend_on_the_arrival_order) {
  // Every interleaving of three publishers' streams (each in its own order, as one ROS connection delivers them)
  // gives the same batch.
  const std::vector<std::vector<std::pair<std::string, std::string>>> streams = {
      {{"/cloud", "c1"}, {"/tf", "t1"}, {"/cloud", "c2"}},  // publisher /m (the master)
      {{"/tf_static", "s1"}, {"/tf", "t2"}},                // publisher /r
      {{"/cloud", "d1"}},                                    // publisher /d
  };
  const std::vector<std::string> pubs = {"/m", "/r", "/d"};
  const Tick t = tick(3,
                      {{{"/cloud", "/m"}, 2}, {{"/tf", "/m"}, 1}, {{"/tf_static", "/r"}, 1}, {{"/tf", "/r"}, 1},
                       {{"/cloud", "/d"}, 1}},
                      {"/m", "/r", "/d"});
  std::vector<int> order = {0, 0, 0, 1, 1, 2};  // which stream each arrival comes from
  std::set<std::string> seen;
  int interleavings = 0;
  do {
    Ledger l = mapServerLedger();
    std::vector<std::size_t> next(3, 0);
    for (const int s : order) {
      const auto& [topic, msg] = streams[s][next[s]++];
      l.received(topic, pubs[s], msg);
    }
    CHECK(l.missing(t).empty());
    seen.insert(show(l.take(t)));
    ++interleavings;
  } while (std::next_permutation(order.begin(), order.end()));
  CHECK(interleavings == 60);
  CHECK_MSG(seen.size() == 1, seen.size() << " different batches");
  CHECK_MSG(*seen.begin() == "/tf_static:s1 /tf:t1 /tf:t2 /cloud:d1 /cloud:c1 /cloud:c2", *seen.begin());
}

TEST(ledger_keeps_messages_beyond_the_count_for_later_ticks) {
  Ledger l({"/cloud"});
  for (const char* m : {"1", "2", "3", "4"}) l.received("/cloud", "/m", m);
  const std::set<std::string> parts = {"/m", "/late"};
  CHECK(show(l.take(tick(1, {{{"/cloud", "/m"}, 2}}, parts))) == "/cloud:1 /cloud:2");
  CHECK(l.held() == 2);
  CHECK(show(l.take(tick(2, {{{"/cloud", "/m"}, 2}}, parts))).empty());  // same count: nothing new
  CHECK(show(l.take(tick(3, {{{"/cloud", "/m"}, 4}}, parts))) == "/cloud:3 /cloud:4");
  CHECK(l.held() == 0);
  // A participant's messages without a count in the tick (its count is still 0: it is ahead) wait.
  l.received("/cloud", "/late", "x");
  CHECK(show(l.take(tick(4, {{{"/cloud", "/m"}, 4}}, parts))).empty());
  CHECK(l.held() == 1);
  CHECK(show(l.take(tick(5, {{{"/cloud", "/m"}, 4}, {{"/cloud", "/late"}, 1}}, parts))) == "/cloud:x");
}

TEST(ledger_foreign_messages_come_after_the_counted_ones_in_arrival_order) {
  Ledger l({"/cloud"});
  l.addTopic("/tf", true);
  // Before the first tick nobody knows who is a participant: these are classified at the first tick.
  l.received("/cloud", "/operator", "op1");
  l.received("/cloud", "/m", "c1");
  l.received("/tf", "/replay", "rp1");
  l.received("/tf", "/m", "t1");
  const std::set<std::string> parts = {"/m"};
  const Tick t1 = tick(1, {{{"/cloud", "/m"}, 1}, {{"/tf", "/m"}, 1}}, parts);
  CHECK(l.missing(t1).empty());
  std::string got = show(l.take(t1));
  CHECK_MSG(got == "/tf:t1 /cloud:c1 /cloud:op1 /tf:rp1", got);
  // After the first tick: foreign ones are dispatched at the next step they are seen, uncounted.
  l.received("/tf", "/operator", "op2");
  l.received("/cloud", "/m", "c2");
  got = show(l.take(tick(2, {{{"/cloud", "/m"}, 2}, {{"/tf", "/m"}, 1}}, parts)));
  CHECK_MSG(got == "/cloud:c2 /tf:op2", got);
  l.received("/cloud", "/operator", "op3");
  got = show(l.take(tick(3, {{{"/cloud", "/m"}, 2}, {{"/tf", "/m"}, 1}}, parts)));
  CHECK_MSG(got == "/cloud:op3", got);
}

TEST(ledger_reports_what_is_missing_and_refuses_to_take) {
  Ledger l({"/cloud"});
  l.addTopic("/tf", true);
  l.received("/cloud", "/m", "c1");
  const Tick t = tick(7,
                      {{{"/cloud", "/m"}, 3}, {{"/tf", "/m"}, 1}, {{"/tf", "/odom"}, 2}, {{"/other", "/m"}, 9}},
                      {"/m", "/odom"});
  const std::vector<Missing> missing = l.missing(t);
  CHECK(missing.size() == 3);  // /other is not an input: ignored
  CHECK(missing[0].topic == "/cloud" && missing[0].publisher == "/m");
  CHECK(missing[0].expected == 3 && missing[0].received == 1);
  CHECK(missing[1].topic == "/tf" && missing[1].publisher == "/m" && missing[1].received == 0);
  CHECK(missing[2].publisher == "/odom" && missing[2].expected == 2);
  const std::string text = describe(missing);
  CHECK_MSG(text == "/cloud from /m (1 of 3), /tf from /m (0 of 1), /tf from /odom (0 of 2)", text);
  const std::string err = checkThrows<LockstepError>([&] { l.take(t); }, "take with missing inputs");
  CHECK_MSG(err == "step 7: /cloud from /m: 1 of 3 messages", err);
  CHECK(l.held() == 1);  // nothing was taken
  std::vector<Missing> many;
  for (int i = 0; i < 8; ++i) many.push_back({"/t" + std::to_string(i), "/p", 1, 0});
  CHECK(describe(many).find(" and 2 more") != std::string::npos);
}

TEST(ledger_a_count_below_what_was_taken_is_an_error) {
  Ledger l({"/cloud"});
  const std::set<std::string> parts = {"/m"};
  l.received("/cloud", "/m", "1");
  l.received("/cloud", "/m", "2");
  CHECK(show(l.take(tick(1, {{{"/cloud", "/m"}, 2}}, parts))) == "/cloud:1 /cloud:2");
  const std::string err =
      checkThrows<LockstepError>([&] { l.missing(tick(2, {{{"/cloud", "/m"}, 1}}, parts)); }, "count went back");
  CHECK_MSG(err.find("/cloud from /m: the tick of step 2 counts 1 messages but 2 were already taken") == 0, err);
}

// ------------------------------------------------------------------------------------------------- boundaries

TEST(boundary_queue_applies_requests_at_their_boundary_in_arrival_order) {
  BoundaryQueue<std::string> q;
  q.put(5, "a");
  q.put(3, "b");
  q.put(5, "c");
  q.put(3, "d");
  q.put(0, "e");
  CHECK(q.size() == 5);
  CHECK((q.due(0) == std::vector<std::string>{"e"}));
  CHECK(q.due(2).empty());
  CHECK((q.due(3) == std::vector<std::string>{"b", "d"}));
  q.put(4, "f");
  CHECK((q.due(10) == std::vector<std::string>{"f", "a", "c"}));
  CHECK(q.empty());
}

TEST(apply_after_header_parses_step_numbers_only) {
  CHECK(parseApplyAfter("12") == 12);
  CHECK(parseApplyAfter(" 7\n") == 7);
  CHECK(parseApplyAfter("0") == 0);
  for (const char* bad : {"", "-1", "x", "1.5", "12a", "99999999999999999999"}) {
    const std::string err = checkThrows<std::invalid_argument>([&] { parseApplyAfter(bad); }, bad);
    CHECK(err.find("lockstep_apply_after") != std::string::npos);
  }
}

// ------------------------------------------------------------------------------------------------- timers

std::vector<int> firing(SimTimer& timer, double t0, double step, int n) {
  std::vector<int> fired;
  double t = t0;
  for (int k = 1; k <= n; ++k) {
    t += step;  // step times are sums of float steps, as the master's are
    if (timer.due(t)) fired.push_back(k);
  }
  return fired;
}

TEST(sim_timer_fires_once_at_the_first_step_past_its_due_time) {
  SimTimer layers(0.5, std::nullopt, "layers");
  CHECK(layers.describe() == "layers 0.5");
  CHECK(SimTimer(1.0, std::nullopt, "map").describe() == "map 1");
  CHECK(SimTimer(1.0 / 3.0).describe() == "timer 0.333333");
  // 2 Hz in 0.1 s steps from time 0: due at 0.5, 1.0, ...: steps 5, 10, 15, 20.
  std::vector<int> fired = firing(layers, 0.0, 0.1, 20);
  CHECK_MSG((fired == std::vector<int>{5, 10, 15, 20}), fired.size());
  // Steps far from time 0 (a simulation that starts at 1000 s): the first step fires at once, then on the grid.
  SimTimer late(0.5);
  fired = firing(late, 1000.0, 0.1, 12);
  CHECK_MSG((fired == std::vector<int>{1, 5, 10}), fired.size());
  CHECK(std::fabs(late.nextDueS() - 1001.5) < 1e-9);
  // 20 Hz in 10 Hz steps: once a step, never twice.
  SimTimer fast(0.05);
  fired = firing(fast, 0.0, 0.1, 10);
  CHECK(fired.size() == 10 && fast.fired() == 10);
  // A jump in time: one call, then back on the grid past it.
  SimTimer jump(1.0, 2.0);
  CHECK(!jump.due(1.5));
  CHECK(jump.due(7.3));
  CHECK(jump.nextDueS() == 8.0);
  CHECK(!jump.due(7.9));
  CHECK(jump.due(8.0));
  for (const double bad : {0.0, -1.0, std::nan(""), static_cast<double>(INFINITY)}) {
    const std::string err = checkThrows<std::invalid_argument>([&] { SimTimer t(bad, std::nullopt, "x"); }, "period");
    CHECK(err.find("timer x: period_s must be a positive number of seconds") == 0);
  }
}

TEST(stamp_seconds_is_rospy_to_sec) {
  // rospy: secs + nsecs / 1e9 (not nsecs * 1e-9, which rounds differently for some values).
  CHECK(stampSeconds(1000, 100000000) == 1000.0 + 100000000 / 1e9);
  CHECK(stampSeconds(1700000000, 123456789) == 1700000000.0 + 123456789 / 1e9);
  CHECK(stampSeconds(0, 0) == 0.0);
}

// ------------------------------------------------------------------------------------------------- replay

/// Reads commands from stdin, prints every decision (one line each); see the file comment.
///   ledger                      a new, empty ledger
///   topic NAME first|last       addTopic
///   recv TOPIC PUBLISHER ID     received
///   tick STEP T NP P.. NC (TOPIC PUBLISHER COUNT)..   -> "take TOPIC:ID ..." | "missing TOPIC PUB E R ..." | "error"
///   queue                       a new boundary queue;  put S ID;  due F  -> "due ID ..."
///   timer PERIOD FIRST|-        a new timer;  at T  -> "1 NEXT" | "0 NEXT" (NEXT as %.17g)
int replay() {
  std::unique_ptr<InputLedger<std::string>> ledger;
  BoundaryQueue<std::string> queue;
  std::unique_ptr<SimTimer> timer;
  std::string line;
  while (std::getline(std::cin, line)) {
    std::istringstream in(line);
    std::string cmd;
    if (!(in >> cmd)) continue;
    if (cmd == "ledger") {
      ledger = std::make_unique<InputLedger<std::string>>();
    } else if (cmd == "topic") {
      std::string name, where;
      in >> name >> where;
      ledger->addTopic(name, where == "first");
    } else if (cmd == "recv") {
      std::string topic, pub, id;
      in >> topic >> pub >> id;
      ledger->received(topic, pub, id);
    } else if (cmd == "tick") {
      Tick t;
      std::size_t np = 0, nc = 0;
      in >> t.step >> t.t_s >> np;
      for (std::size_t i = 0; i < np; ++i) {
        std::string p;
        in >> p;
        t.participants.insert(p);
      }
      in >> nc;
      for (std::size_t i = 0; i < nc; ++i) {
        std::string topic, pub;
        uint64_t n = 0;
        in >> topic >> pub >> n;
        t.counts[{topic, pub}] = n;
      }
      try {
        const std::vector<Missing> missing = ledger->missing(t);
        if (missing.empty()) {
          std::string out = "take";
          for (const auto& [topic, id] : ledger->take(t)) out += " " + topic + ":" + id;
          std::cout << out << "\n";
        } else {
          std::string out = "missing";
          for (const Missing& m : missing)
            out += " " + m.topic + " " + m.publisher + " " + std::to_string(m.expected) + " " +
                   std::to_string(m.received);
          std::cout << out << "\n";
        }
      } catch (const LockstepError&) {
        std::cout << "error\n";
      }
    } else if (cmd == "queue") {
      queue = BoundaryQueue<std::string>();
    } else if (cmd == "put") {
      int64_t s = 0;
      std::string id;
      in >> s >> id;
      queue.put(s, id);
    } else if (cmd == "due") {
      int64_t f = 0;
      in >> f;
      std::string out = "due";
      for (const std::string& id : queue.due(f)) out += " " + id;
      std::cout << out << "\n";
    } else if (cmd == "timer") {
      std::string period, first;
      in >> period >> first;
      std::optional<double> first_due;
      if (first != "-") first_due = std::stod(first);
      timer = std::make_unique<SimTimer>(std::stod(period), first_due);
    } else if (cmd == "at") {
      std::string t;
      in >> t;
      const bool fired = timer->due(std::stod(t));
      char next[64];
      std::snprintf(next, sizeof(next), "%.17g", timer->nextDueS());
      std::cout << (fired ? "1 " : "0 ") << next << "\n";
    } else {
      std::cerr << "unknown replay command '" << cmd << "'\n";
      return 2;
    }
  }
  std::cout.flush();
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc == 2 && std::string(argv[1]) == "--replay") return replay();
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
    std::cerr << "usage: lockstep_tests --list | --all | --replay | NAME...\n";
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
