#include "quad_engine/expert_worker.h"

#include "quad_engine/record_buffer.h"

#include <fast_planner/plan_collector.h>
#include <quad_core/episode_key.h>
#include <quad_core/pairing.h>
#include <quad_core/wire.h>

#include <chrono>
#include <cmath>
#include <deque>
#include <functional>
#include <stdexcept>

namespace quad_engine {

quad_sim::So3Command ToSimCommand(const kr_tracker::So3Command& c) {
  quad_sim::So3Command s;
  s.force_world_N = c.force_world_N;
  s.q_world_des =
      Eigen::Quaterniond(c.q_world_des.w(), c.q_world_des.x(), c.q_world_des.y(), c.q_world_des.z());
  s.w_body_des_radps = c.w_body_des_radps;
  if (!(c.kR.isZero(0.0) && c.kOm.isZero(0.0))) {
    s.kR = c.kR;
    s.kOm = c.kOm;
  }
  s.enable_motors = c.enable_motors;
  return s;
}

kr_tracker::BsplineGoalSpec ToGoalSpec(const fast_planner::PlanResult& plan) {
  kr_tracker::BsplineGoalSpec s;
  s.order = plan.spline->order();
  s.traj_id = plan.traj_id;
  s.start_time_s = quad_core::RosTimeRoundTrip(plan.start_time_s);
  s.knots = plan.spline->knots();
  s.pos_pts = plan.spline->ctrl_pts();
  s.yaw_dt_s = 0.0;
  return s;
}

ExpertWorker::ExpertWorker(const Configs& configs)
    : cfg_(configs),
      sim_(cfg_.sim),
      tracker_(cfg_.tracker, cfg_.vehicle.mass_kg, cfg_.vehicle.gravity_mps2, cfg_.vehicle.MaxThrustN()),
      expert_(cfg_.planner, /*label_every_frame=*/false),
      buffer_(std::make_shared<RecordBuffer>()) {
  expert_.SetPlanObserver(buffer_);
  // The privileged expert plans on the simulator's voxel map: without depth noise (whose random stream every
  // rendered frame advances) a frame needs pixels only when a plan made at it is recorded.
  lazy_depth_ =
      cfg_.planner.map.source == fast_planner::MapSource::kGlobal && cfg_.sim.camera.noise_std_at_1m_m == 0.0;
  // The camera mount as the simulator's static transform carries it (base_link -> camera).
  const auto& cam = cfg_.sim.camera;
  mount_.p_body_camera = cam.p_body_camera_m;
  mount_.q_body_camera = Eigen::Quaterniond(cam.q_body_camera.w(), cam.q_body_camera.x(),
                                            cam.q_body_camera.y(), cam.q_body_camera.z());
}

ExpertWorker::~ExpertWorker() = default;

namespace {

struct OdomSample {
  double t_s;  // as rospy reads the stamp
  Eigen::Vector3d p;
  double speed;
};

}  // namespace

EpisodeRun ExpertWorker::Run(const EpisodeSpec& spec, const EpisodeLimits& limits) {
  const auto wall0 = std::chrono::steady_clock::now();
  EpisodeRun run;
  run.spec = spec;
  run.intrinsics = sim_.camera_intrinsics();
  const uint64_t t0_ns = quad_core::EpisodeStartNs(spec.index);
  const uint32_t episode_id = quad_core::EpisodeIdOf(spec.index);

  const std::string rejected = ResetKeyed(cfg_.sim, spec, &sim_);
  if (!rejected.empty()) {
    run.outcome = "reset_failed";
    run.reason = rejected;
    return run;
  }
  if (!z_offset_measured_) {
    z_offset_m_ = sim_.MeasureZOffset();
    z_offset_measured_ = true;
  }

  // The new episode's status reaches the tracker and the expert (its voxel map first, as it is published
  // first).
  const double t0_s = quad_core::StampSeconds(t0_ns);
  tracker_.OnEpisodeStatus(episode_id, t0_s);
  if (cfg_.planner.map.source == fast_planner::MapSource::kGlobal) world_points_.Give(sim_, {&expert_});
  buffer_->Start(episode_id, sim_.world().seed);

  auto send = [&](const fast_planner::ReplannerOutput& out, double clock_s) {
    run.plan_failures += out.failed_plans.size();
    if (!out.trajectory) return;
    if (out.trajectory->reason != "emergency stop") ++run.plans;
    tracker_.AddGoal(next_goal_id_++, ToGoalSpec(*out.trajectory), clock_s);
  };
  for (const auto& [t_s, out] : expert_.StartEpisode(t0_s)) send(out, t_s);

  EpisodeDirector director(spec, limits, quad_core::RospySeconds(t0_ns));
  std::deque<OdomSample> odom;
  size_t goal_record = 0;
  const uint64_t dt_ns = static_cast<uint64_t>(std::llround(cfg_.sim.physics_dt_s * 1e9));
  double last_depth_s = 0.0;
  for (uint64_t step = 0;; ++step) {
    const uint64_t t_ns = t0_ns + step * dt_ns;
    const double t_s = quad_core::StampSeconds(t_ns);
    const bool odom_due = sim_.OdometryDue();
    std::optional<quad_sim::So3Command> command;
    if (odom_due) {
      const quad_core::VehicleState wire =
          quad_core::OdometryAsReceived(sim_.Odometry(z_offset_m_, t_s), t_ns);
      command = ToSimCommand(tracker_.OnOdometry(wire).command);
      try {
        send(expert_.OnOdometry(wire), t_s);
      } catch (const std::invalid_argument&) {
        // Non-finite odometry: the node skips it (logged there).
      }
      odom.push_back({quad_core::RospySeconds(t_ns), wire.p_world_body, wire.v_world.norm()});
      if (odom.size() > 400) odom.pop_front();
    }
    if (sim_.DepthDue()) {
      ++run.frames;
      auto frame = std::make_shared<fast_planner::DepthFrame>();
      frame->stamp_s = t_s;
      frame->seq = run.frames;
      frame->intrinsics = run.intrinsics;
      if (lazy_depth_) {
        frame->image.width = run.intrinsics.width;
        frame->image.height = run.intrinsics.height;
        frame->image.depth_m.assign(static_cast<size_t>(run.intrinsics.width) * run.intrinsics.height, 0.0f);
        buffer_->SetPlaceholder(frame, [this] { return sim_.RenderDepth(); });
      } else {
        frame->image = sim_.RenderDepth();
      }
      if (expert_.SetCameraPose(mount_, frame.get())) {
        try {
          const fast_planner::ExpertSession::FrameOutput out = expert_.OnDepth(frame);
          buffer_->SetMapUpdateMs(out.map_update.total_ms);
          send(out.flight, t_s);
        } catch (const std::invalid_argument&) {
          // A malformed frame is skipped (the node logs it).
        }
      }
      last_depth_s = t_s;
      // The manager's decision at this frame.
      const double t_mgr = quad_core::RospySeconds(t_ns);
      const OdomSample* at = nullptr;
      for (auto it = odom.rbegin(); it != odom.rend(); ++it) {
        if (quad_core::OdometryNotNewerThanFrame(it->t_s, t_mgr)) {
          at = &*it;
          break;
        }
      }
      const quad_sim::EpisodeState& e = sim_.episode();
      const StatusView status{e.reached_goal, e.collision.collided, e.active, e.reason};
      const Eigen::Vector3d p = at ? at->p : Eigen::Vector3d::Constant(std::nan(""));
      const double speed = at ? at->speed : std::nan("");
      switch (director.OnFrame(t_mgr, p, speed, status, buffer_->size() - goal_record)) {
        case EpisodeDirector::Action::kGoto:
          director.OnGotoAnswer(tracker_.Goto(spec.start_world, spec.start_yaw_rad, 0.0, 0.0));
          break;
        case EpisodeDirector::Action::kGiveGoal: {
          // The planner plans from its newest sensor stamp (OnGoal): this frame's, or newer odometry.
          double now_s = last_depth_s;
          if (!expert_.odometry().empty()) now_s = std::max(now_s, expert_.odometry().newest().t_s);
          goal_record = buffer_->size();
          fast_planner::ReplannerOutput out;
          const std::string why = expert_.SetGoal(spec.goal_world, now_s, &out);
          director.OnGoalAnswer(why);
          if (why.empty()) send(out, t_s);
          break;
        }
        default:
          break;
      }
      if (director.done()) break;
    }
    if (command) sim_.SetSo3Command(*command);
    sim_.Step();
    ++run.steps;
  }
  run.outcome = director.outcome();
  run.reason = director.reason();
  run.sim_duration_s = director.duration_s();
  run.records = buffer_->Take();
  run.samples = run.records.size() - std::min(goal_record, run.records.size());
  run.sim_s = static_cast<double>(run.steps) * cfg_.sim.physics_dt_s;
  run.wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - wall0).count();
  return run;
}

}  // namespace quad_engine
