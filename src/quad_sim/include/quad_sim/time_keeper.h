// Sim time of the simulator node and its time modes (docs/quad_sim.md, "Time"), ROS-free. The node owns one
// TimeKeeper and drives it with the wall clock and the lockstep gate's state:
//
//   sim time     = kTimeBaseNs + (physics steps so far) * dt; it advances only by Stepped() (one physics
//                  step), by NewEpisode() (one odometry period, so that stamps never repeat) and by
//                  StartEpisodeAt() (to a keyed episode's start, quad_core/episode_key.h);
//   /clock       = published before a step when ClockDue(): every clock_period_s of sim time, and at every
//                  odometry and depth frame time (so a frame's stamp is never ahead of /clock);
//   real_time    = each step is paced to wall time (PaceUntil), factor: to wall time * real_time_factor;
//   as_fast_as_possible and lockstep: never paced; lockstep additionally waits for the lockstep gate
//                  (quad_core/lockstep_gate.h) after odometry and depth frames (WaitsForCommand,
//                  WaitsForFrames), which only the node can do (it sleeps on its inputs).
//
// Wall times are seconds on the caller's monotonic clock.
#pragma once

#include "quad_core/episode_key.h"
#include "quad_sim/episode_request.h"
#include "quad_sim/sim_config.h"
#include "quad_sim/simulator.h"

#include <chrono>
#include <cstdint>
#include <optional>
#include <tuple>

namespace quad_sim {

// The wall clock the node drives the TimeKeeper and the lockstep gate with (steady_clock, in seconds).
inline double WallNow() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}
inline std::chrono::steady_clock::time_point WallPoint(double wall_s) {
  return std::chrono::steady_clock::time_point(
      std::chrono::duration_cast<std::chrono::steady_clock::duration>(std::chrono::duration<double>(wall_s)));
}

class TimeKeeper {
 public:
  // Sim time of the first step: 1 s, so that stamps are valid (non-zero) from the first message.
  static constexpr uint64_t kTimeBaseNs = quad_core::kEpisodeTimeBaseNs;

  // Throws std::invalid_argument if physics_dt_s, odometry_rate_hz or time.clock_period_s are not positive.
  TimeKeeper(const SimConfig& config, double wall_now_s);

  TimeMode mode() const { return mode_; }
  bool lockstep() const { return mode_ == TimeMode::kLockstep; }

  // Sim time now (the stamp of whatever is published before the next step).
  uint64_t now_ns() const { return kTimeBaseNs + total_steps_ * dt_ns_; }
  double sim_s() const { return static_cast<double>(total_steps_) * dt_s_; }
  uint64_t total_steps() const { return total_steps_; }

  bool ClockDue(bool odometry_due, bool depth_due) const {
    return total_steps_ % steps_per_clock_ == 0 || odometry_due || depth_due;
  }
  // Lockstep waits after an odometry message / a depth frame (given the lockstep config).
  bool WaitsForCommand() const { return lockstep() && wait_for_command_; }
  bool WaitsForFrames() const { return lockstep() && has_depth_consumers_; }

  void Stepped() { ++total_steps_; }
  // A new (unkeyed) episode starts one odometry period after the last stamp of the previous one.
  void NewEpisode() { total_steps_ += steps_per_odom_; }
  // A keyed episode starts at sim time ns (quad_core::EpisodeStartNs): afterwards now_ns() == ns. Throws
  // std::invalid_argument if ns is not after now_ns() (stamps never go back) or not a whole number of
  // physics steps after kTimeBaseNs.
  void StartEpisodeAt(uint64_t ns);
  // The sim time of the episode a reset starts: keyed (request.keyed) at EpisodeStartNs(episode_index),
  // returning its id EpisodeIdOf(episode_index); else NewEpisode(), returning nullopt (the simulator's next
  // unkeyed id). Throws std::invalid_argument (an index out of range, StartEpisodeAt's refusals) and then
  // leaves the time unchanged.
  std::optional<uint32_t> BeginEpisode(const EpisodeRequest& request);

  // Pacing of real_time and factor: Anchor pins sim time now to wall_now_s (at start and after every reset);
  // PaceUntil gives the wall time to sleep until before the next step (nothing if not paced or not ahead).
  // More than a second behind (e.g. after a slow reset), it re-anchors instead of racing to catch up.
  void Anchor(double wall_now_s);
  std::optional<double> PaceUntil(double wall_now_s);

  // Periodic statistics: due once a second of wall time; the real-time factor is measured since the last
  // MarkStats.
  bool StatsDue(double wall_now_s) const { return wall_now_s - stats_wall_s_ >= 1.0; }
  double RealTimeFactor(double wall_now_s) const;
  void MarkStats(double wall_now_s);

 private:
  TimeMode mode_;
  double factor_;
  bool wait_for_command_;
  bool has_depth_consumers_;
  double dt_s_;
  uint64_t dt_ns_;
  uint64_t steps_per_odom_;
  uint64_t steps_per_clock_;
  uint64_t total_steps_ = 0;
  double wall_anchor_s_ = 0.0;
  double sim_anchor_s_ = 0.0;
  double stats_wall_s_ = 0.0;
  double stats_sim_s_ = 0.0;
};

// When the node publishes the episode status: at a reset (forced), whenever something a listener acts on
// changed (episode, still active, number of collisions, goal reached, lockstep timeouts), and every sim
// second (steps_per_second steps) of the episode.
class StatusSchedule {
 public:
  bool Due(const EpisodeState& e, uint64_t lockstep_timeouts, uint64_t episode_step,
           uint64_t steps_per_second, bool force) {
    const auto key = std::make_tuple(e.episode_id, e.active, e.collision.num_collisions, e.reached_goal,
                                     lockstep_timeouts);
    if (!force && key == last_ && episode_step % steps_per_second != 0) return false;
    last_ = key;
    return true;
  }

 private:
  std::tuple<uint32_t, bool, int, bool, uint64_t> last_{0, false, -1, false, 0};
};

}  // namespace quad_sim
