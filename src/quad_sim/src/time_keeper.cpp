#include "quad_sim/time_keeper.h"

#include <algorithm>
#include <cmath>
#include <iomanip>
#include <sstream>
#include <stdexcept>
#include <string>

namespace quad_sim {
namespace {

double RequirePositive(double v, const char* name) {
  if (!std::isfinite(v) || v <= 0.0) {
    throw std::invalid_argument(std::string("time keeper: ") + name + " must be > 0, got " +
                                std::to_string(v));
  }
  return v;
}

}  // namespace

TimeKeeper::TimeKeeper(const SimConfig& config, double wall_now_s)
    : mode_(config.time.mode),
      factor_(mode_ == TimeMode::kRealTime ? 1.0 : config.time.real_time_factor),
      wait_for_command_(config.lockstep.wait_for_command),
      has_depth_consumers_(!config.lockstep.depth_consumers.empty()),
      dt_s_(RequirePositive(config.physics_dt_s, "physics_dt_s")),
      dt_ns_(static_cast<uint64_t>(std::llround(config.physics_dt_s * 1e9))),
      steps_per_odom_(static_cast<uint64_t>(std::llround(
          1.0 / (config.physics_dt_s * RequirePositive(config.odometry_rate_hz, "odometry_rate_hz"))))),
      steps_per_clock_(std::max<uint64_t>(
          1, std::llround(RequirePositive(config.time.clock_period_s, "time.clock_period_s") /
                          config.physics_dt_s))),
      stats_wall_s_(wall_now_s) {
  if (mode_ == TimeMode::kRealTimeFactor) RequirePositive(factor_, "time.real_time_factor");
}

namespace {

std::string Seconds(uint64_t ns) {
  std::ostringstream s;
  s << std::fixed << std::setprecision(3) << quad_core::StampSeconds(ns);
  return s.str();
}

// "keyed episode N" when ns is a keyed episode's start, else "an episode".
std::string EpisodeAt(uint64_t ns) {
  using quad_core::kEpisodeSpacingNs;
  using quad_core::kEpisodeTimeBaseNs;
  if (ns > kEpisodeTimeBaseNs && (ns - kEpisodeTimeBaseNs) % kEpisodeSpacingNs == 0) {
    return "keyed episode " + std::to_string((ns - kEpisodeTimeBaseNs) / kEpisodeSpacingNs - 1);
  }
  return "an episode";
}

}  // namespace

void TimeKeeper::StartEpisodeAt(uint64_t ns) {
  if (ns <= now_ns()) {
    throw std::invalid_argument(EpisodeAt(ns) + " starts at " + Seconds(ns) +
                                " s, not after the current sim time " + Seconds(now_ns()) +
                                " s (an episode longer than the " +
                                std::to_string(quad_core::kEpisodeSpacingNs / 1000000000ULL) +
                                " s spacing, or keyed episodes flown out of order?)");
  }
  if ((ns - kTimeBaseNs) % dt_ns_ != 0) {
    throw std::invalid_argument(EpisodeAt(ns) + " start " + std::to_string(ns) +
                                " ns is not a whole number of physics steps (" + std::to_string(dt_ns_) +
                                " ns) after the first stamp");
  }
  total_steps_ = (ns - kTimeBaseNs) / dt_ns_;
}

std::optional<uint32_t> TimeKeeper::BeginEpisode(const EpisodeRequest& request) {
  if (!request.keyed) {
    NewEpisode();
    return std::nullopt;
  }
  const uint32_t id = quad_core::EpisodeIdOf(request.episode_index);  // checks the index's range
  StartEpisodeAt(quad_core::EpisodeStartNs(request.episode_index));
  return id;
}

void TimeKeeper::Anchor(double wall_now_s) {
  wall_anchor_s_ = wall_now_s;
  sim_anchor_s_ = sim_s();
}

std::optional<double> TimeKeeper::PaceUntil(double wall_now_s) {
  if (mode_ != TimeMode::kRealTime && mode_ != TimeMode::kRealTimeFactor) return std::nullopt;
  const double target_s = wall_anchor_s_ + (sim_s() - sim_anchor_s_) / factor_;
  if (target_s > wall_now_s) return target_s;
  if (wall_now_s - target_s > 1.0) Anchor(wall_now_s);
  return std::nullopt;
}

double TimeKeeper::RealTimeFactor(double wall_now_s) const {
  return (sim_s() - stats_sim_s_) / std::max(1e-9, wall_now_s - stats_wall_s_);
}

void TimeKeeper::MarkStats(double wall_now_s) {
  stats_wall_s_ = wall_now_s;
  stats_sim_s_ = sim_s();
}

}  // namespace quad_sim
