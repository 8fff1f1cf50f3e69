// The causal lockstep's pure bookkeeping (docs/lockstep.md): see uav_mapping/lockstep.h.
#include <uav_mapping/lockstep.h>

#include <cctype>
#include <cmath>
#include <cstdio>

namespace uav_mapping {
namespace lockstep {

std::string describe(const std::vector<Missing>& missing) {
  std::string out;
  const std::size_t shown = std::min<std::size_t>(missing.size(), 6);
  for (std::size_t i = 0; i < shown; ++i) {
    const Missing& m = missing[i];
    if (!out.empty()) out += ", ";
    out += m.topic + " from " + m.publisher + " (" + std::to_string(m.received) + " of " +
           std::to_string(m.expected) + ")";
  }
  if (missing.size() > shown) out += " and " + std::to_string(missing.size() - shown) + " more";
  return out;
}

double stampSeconds(uint32_t sec, uint32_t nsec) {
  return static_cast<double>(sec) + static_cast<double>(nsec) / 1e9;
}

int64_t parseApplyAfter(const std::string& raw) {
  std::size_t begin = 0;
  std::size_t end = raw.size();
  while (begin < end && std::isspace(static_cast<unsigned char>(raw[begin]))) ++begin;
  while (end > begin && std::isspace(static_cast<unsigned char>(raw[end - 1]))) --end;
  const std::string digits = raw.substr(begin, end - begin);
  bool ok = !digits.empty() && digits.size() <= 18;
  for (const char c : digits) ok = ok && c >= '0' && c <= '9';
  if (!ok) {
    throw std::invalid_argument("the connection header lockstep_apply_after must be a step number (an integer >= 0), "
                                "got '" + raw + "'");
  }
  return std::stoll(digits);
}

SimTimer::SimTimer(double period_s, std::optional<double> first_due_s, std::string name)
    : period_s_(period_s), name_(std::move(name)), next_due_s_(first_due_s ? *first_due_s : period_s) {
  if (!(std::isfinite(period_s) && period_s > 0.0)) {
    throw std::invalid_argument("timer " + (name_.empty() ? std::string("?") : name_) +
                                ": period_s must be a positive number of seconds, got " + std::to_string(period_s));
  }
}

bool SimTimer::due(double t_s) {
  // The same arithmetic as uav_common.lockstep.timers.SimTimer, operation for operation (this package compiles
  // with -ffp-contract=off: no fused multiply-add), so both fire at the same steps. The small tolerance: step times
  // are sums of float steps, due times sums of float periods.
  if (t_s + 1e-9 < next_due_s_) return false;
  const double behind = std::floor((t_s + 1e-9 - next_due_s_) / period_s_);
  next_due_s_ += (behind + 1.0) * period_s_;
  ++fired_;
  return true;
}

std::string SimTimer::describe() const {
  char period[64];
  std::snprintf(period, sizeof(period), "%g", period_s_);
  return (name_.empty() ? std::string("timer") : name_) + " " + period;
}

}  // namespace lockstep
}  // namespace uav_mapping
