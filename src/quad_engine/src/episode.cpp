#include "quad_engine/episode.h"

#include <quad_core/episode_key.h>
#include <quad_sim/episode_request.h>

#include <cmath>
#include <cstdio>
#include <exception>

namespace quad_engine {

Configs LoadConfigs(const ConfigPaths& paths) {
  Configs c;
  c.sim = quad_sim::LoadSimConfig(paths.sim);
  c.planner = fast_planner::LoadPlannerConfig(paths.planner);
  c.tracker = kr_tracker::LoadTrackerConfig(paths.tracker);
  c.vehicle = quad_core::LoadVehicleParams(paths.vehicle);
  return c;
}

std::string ResetKeyed(const quad_sim::SimConfig& cfg, const EpisodeSpec& spec, quad_sim::Simulator* sim) {
  quad_sim::EpisodeRequest req;
  req.seed = spec.seed;
  req.start_world_m = Eigen::Vector3d(spec.start_world.x(), spec.start_world.y(), kGroundZM);
  req.q_start_wxyz =
      Eigen::Vector4d(std::cos(spec.start_yaw_rad / 2), 0.0, 0.0, std::sin(spec.start_yaw_rad / 2));
  req.goal_world_m = spec.goal_world;
  req.keyed = true;
  req.episode_index = static_cast<uint32_t>(spec.index);
  try {
    const quad_sim::EpisodeSetup e = quad_sim::ResolveEpisode(cfg, req);
    sim->Reset(e.world, e.start_world_m, e.start_yaw_rad, e.goal_world_m, quad_core::EpisodeIdOf(spec.index));
  } catch (const std::exception& e) {
    return std::string("reset rejected: ") + e.what();
  }
  return "";
}

void WorldPoints::Give(const quad_sim::Simulator& sim,
                       std::initializer_list<fast_planner::ExpertSession*> sessions) {
  bool any = false;
  for (const fast_planner::ExpertSession* s : sessions) any = any || s != nullptr;
  if (!any || (world_ && *world_ == sim.world())) return;
  world_.reset();  // until every session holds the new world's points
  const auto centres = sim.ComputeVoxelMap().OccupiedCenters();
  points_.clear();
  points_.reserve(centres.size());
  for (const auto& c : centres) points_.push_back(c.cast<double>());
  for (fast_planner::ExpertSession* s : sessions) {
    if (s) s->SetGlobalMap(points_);
  }
  world_ = sim.world();
}

EpisodeDirector::EpisodeDirector(const EpisodeSpec& spec, const EpisodeLimits& limits, double t_start_s)
    : spec_(spec), limits_(limits), t_start_s_(t_start_s) {}

EpisodeDirector::Action EpisodeDirector::OnFrame(double t_s, const Eigen::Vector3d& p_world, double speed_mps,
                                                 const StatusView& status, uint64_t records_since_goal) {
  t_last_s_ = t_s;
  switch (phase_) {
    case Phase::kTakeoffPending:
      phase_ = Phase::kTakingOff;
      return Action::kGoto;
    case Phase::kTakingOff:
      if ((p_world - spec_.start_world).norm() < kTakeoffToleranceM && speed_mps < kTakeoffMaxSpeedMps) {
        t_goal_s_ = t_s;
        phase_ = Phase::kFlying;
        return Action::kGiveGoal;
      }
      if (t_s - t_start_s_ > limits_.takeoff_timeout_s) {
        End("timeout", "take-off did not reach its altitude", t_start_s_, t_s);
        return Action::kEnd;
      }
      return Action::kContinue;
    case Phase::kFlying: {
      if (status.reached_goal) {
        End("goal_reached", status.reason, t_goal_s_, t_s);
      } else if (status.collided) {
        End("collision", status.reason, t_goal_s_, t_s);
      } else if (!status.active) {
        End("ended", status.reason, t_goal_s_, t_s);
      } else if (t_s - t_goal_s_ > limits_.episode_timeout_s) {
        char buf[96];
        std::snprintf(buf, sizeof(buf), "no goal within %g s", limits_.episode_timeout_s);
        End("timeout", buf, t_goal_s_, t_s);
      } else if (limits_.max_samples && limits_.samples_before + records_since_goal >= limits_.max_samples) {
        End("stopped",
            std::to_string(limits_.samples_before + records_since_goal) +
                " samples recorded (max_samples=" + std::to_string(limits_.max_samples) + ")",
            t_goal_s_, t_s);
      } else {
        return Action::kContinue;
      }
      return Action::kEnd;
    }
    case Phase::kDone:
      break;
  }
  return Action::kEnd;
}

void EpisodeDirector::OnGotoAnswer(const std::string& why) {
  if (!why.empty()) End("reset_failed", "take-off refused: " + why, t_start_s_, t_last_s_);
}

void EpisodeDirector::OnGoalAnswer(const std::string& why) {
  if (!why.empty()) End("goal_rejected", "goal rejected: " + why, t_goal_s_, t_last_s_);
}

void EpisodeDirector::End(const std::string& outcome, const std::string& reason, double t_from_s,
                          double t_now_s) {
  phase_ = Phase::kDone;
  outcome_ = outcome;
  reason_ = reason;
  duration_s_ = std::max(0.0, t_now_s - t_from_s);
}

void OwnedRecord::Rebind() {
  if (frame) record.depth = frame->image.view();
  record.status.text = status_text;
}

}  // namespace quad_engine
