#include "quad_engine/policy_worker.h"

#include <quad_core/episode_key.h>
#include <quad_core/pairing.h>
#include <quad_core/wire.h>
#include <quad_policy/input_checks.h>

#include <cmath>
#include <cstdio>
#include <stdexcept>

#include "quad_engine/expert_worker.h"
#include "quad_engine/record_buffer.h"

namespace quad_engine {

namespace {

constexpr int kMaxGotos = 20;          // the runner's take-off attempts
constexpr size_t kOdometryKept = 400;  // policy_node's odometry buffer
constexpr double kTrajectoryPeriodS = 0.1;

}  // namespace

PolicyEpisode::PolicyEpisode(const Configs& configs, const quad_policy::PolicyNodeConfig& policy,
                             const quad_policy::PolicyMeta& meta, bool with_labeller)
    : cfg_(configs),
      policy_cfg_(policy),
      meta_(meta),
      sim_(cfg_.sim),
      tracker_(cfg_.tracker, cfg_.vehicle.mass_kg, cfg_.vehicle.gravity_mps2, cfg_.vehicle.MaxThrustN()),
      decider_(std::make_unique<quad_policy::PolicyDecider>(meta, policy.safety, policy.refusal,
                                                            policy.recovery, policy.keeping)) {
  const auto& cam = cfg_.sim.camera;
  mount_.p_body_camera = cam.p_body_camera_m;
  mount_.q_body_camera = cam.q_body_camera;
  T_body_camera_.linear() = cam.q_body_camera.normalized().toRotationMatrix();
  T_body_camera_.translation() = cam.p_body_camera_m;
  dt_ns_ = static_cast<uint64_t>(std::llround(cfg_.sim.physics_dt_s * 1e9));
  if (with_labeller) {
    labeller_ = std::make_unique<fast_planner::ExpertSession>(cfg_.planner, /*label_every_frame=*/true);
    label_records_ = std::make_shared<RecordBuffer>();
    labeller_->SetPlanObserver(label_records_);
  }
}

PolicyEpisode::PolicyEpisode(const Configs& configs)
    : cfg_(configs),
      sim_(cfg_.sim),
      tracker_(cfg_.tracker, cfg_.vehicle.mass_kg, cfg_.vehicle.gravity_mps2, cfg_.vehicle.MaxThrustN()),
      expert_(std::make_unique<fast_planner::ExpertSession>(cfg_.planner, /*label_every_frame=*/false)) {
  mount_.p_body_camera = cfg_.sim.camera.p_body_camera_m;
  mount_.q_body_camera = cfg_.sim.camera.q_body_camera;
  dt_ns_ = static_cast<uint64_t>(std::llround(cfg_.sim.physics_dt_s * 1e9));
}

PolicyEpisode::~PolicyEpisode() = default;

void PolicyEpisode::Fly(const fast_planner::ReplannerOutput& out, double clock_s) {
  if (!out.trajectory) return;
  ++result_.decisions;
  ++result_.counts[out.trajectory->reason == "emergency stop" ? "emergency_stop" : "plan"];
  if (!tracker_.AddGoal(goal_ids_++, ToGoalSpec(*out.trajectory), clock_s).empty())
    ++result_.counts["tracker_rejection"];
}

double PolicyEpisode::NowS() const { return quad_core::StampSeconds(t0_ns_ + step_ * dt_ns_); }

void PolicyEpisode::Reset(const EpisodeSpec& spec, const EvalLimits& limits) {
  spec_ = spec;
  limits_ = limits;
  result_ = PolicyEpisodeResult{};
  done_ = false;
  pending_ = false;
  frame_open_ = false;
  phase_ = Phase::kTakeoff;
  gotos_ = 0;
  goal_.reset();
  odom_.clear();
  last_decision_ns_.reset();
  command_.reset();
  hovering_ = false;
  step_ = 0;
  t0_ns_ = quad_core::EpisodeStartNs(spec.index);
  const uint32_t id = quad_core::EpisodeIdOf(spec.index);
  const std::string rejected = ResetKeyed(cfg_.sim, spec, &sim_);
  if (!rejected.empty()) {
    Finish("reset_failed", rejected, 0.0);
    return;
  }
  if (!z_offset_measured_) {
    z_offset_m_ = sim_.MeasureZOffset();
    z_offset_measured_ = true;
  }
  const double t0 = quad_core::StampSeconds(t0_ns_);
  tracker_.OnEpisodeStatus(id, t0);
  if (decider_) decider_->Reset();
  if (cfg_.planner.map.source == fast_planner::MapSource::kGlobal) {
    world_points_.Give(sim_, {labeller_.get(), expert_.get()});
  }
  for (fast_planner::ExpertSession* e : {labeller_.get(), expert_.get()}) {
    if (!e) continue;
    for (const auto& [t_s, out] : e->StartEpisode(t0)) {
      if (e == expert_.get()) Fly(out, t_s);
    }
  }
  if (labeller_) label_records_->Start(id, sim_.world().seed);
  t_takeoff_s_ = quad_core::RospySeconds(t0_ns_);
  last_depth_s_ = 0.0;
  label_frames_ = 0;
}

bool PolicyEpisode::Advance() {
  if (pending_) throw std::logic_error("PolicyEpisode::Advance: the pending decision was not made (Decide)");
  while (!done_) {
    if (frame_open_) {
      frame_open_ = false;
      DirectFrame();
      if (done_) break;
      StepOnce();
      continue;
    }
    const uint64_t t_ns = t0_ns_ + step_ * dt_ns_;
    const double t_s = quad_core::StampSeconds(t_ns);
    command_.reset();
    if (sim_.OdometryDue()) {
      const quad_core::VehicleState wire =
          quad_core::OdometryAsReceived(sim_.Odometry(z_offset_m_, t_s), t_ns);
      command_ = ToSimCommand(tracker_.OnOdometry(wire).command);
      odom_.push_back(wire);
      result_.points.push_back({quad_core::RospySeconds(t_ns), wire.p_world_body.x(), wire.p_world_body.y(),
                                wire.p_world_body.z()});
      if (odom_.size() > kOdometryKept) odom_.pop_front();
      for (fast_planner::ExpertSession* e : {labeller_.get(), expert_.get()}) {
        if (!e) continue;
        try {
          const fast_planner::ReplannerOutput out = e->OnOdometry(wire);
          if (e == expert_.get()) Fly(out, t_s);
        } catch (const std::invalid_argument&) {
        }
      }
      if (phase_ == Phase::kFlying) {
        const double t_rel = quad_core::RospySeconds(t_ns) - t_goal_s_;
        result_.path_length_m += (wire.p_world_body - p_prev_).norm();
        p_prev_ = wire.p_world_body;
        result_.min_clearance_m = std::min(result_.min_clearance_m, sim_.ClearanceToObstacles());
        if (t_rel >= next_traj_sample_s_ - 1e-9) {
          result_.trajectory.push_back(
              {t_rel, wire.p_world_body.x(), wire.p_world_body.y(), wire.p_world_body.z()});
          next_traj_sample_s_ += kTrajectoryPeriodS;
        }
      }
    }
    if (sim_.DepthDue()) {
      frame_open_ = true;
      OnFrame();
      if (pending_) return true;
      continue;  // the runner's decision at this frame, then the step
    }
    StepOnce();
  }
  return false;
}

void PolicyEpisode::StepOnce() {
  if (command_) sim_.SetSo3Command(*command_);
  const bool was_running =
      sim_.episode().active && !sim_.episode().reached_goal && !sim_.collision().collided;
  sim_.Step();
  ++step_;
  ++result_.steps;
  const bool running = sim_.episode().active && !sim_.episode().reached_goal && !sim_.collision().collided;
  if (was_running && !running) status_end_s_ = quad_core::RospySeconds(t0_ns_ + step_ * dt_ns_);
}

void PolicyEpisode::OnFrame() {
  const uint64_t t_ns = t0_ns_ + step_ * dt_ns_;
  const double stamp = quad_core::StampSeconds(t_ns);
  auto frame = std::make_shared<fast_planner::DepthFrame>();
  frame->stamp_s = stamp;
  frame->intrinsics = sim_.camera_intrinsics();
  // The policy alone (no expert, no labeller) needs the pixels only for a decision: without depth noise
  // (whose random stream every rendered frame advances) a frame skipped before one (no goal, rate limited,
  // ...) is not rendered, and the others are rendered at the same sim state as before.
  const bool lazy = !expert_ && !labeller_ && cfg_.sim.camera.noise_std_at_1m_m == 0.0;
  if (!lazy) frame->image = sim_.RenderDepth();
  frame_ = frame;
  request_ = DecisionRequest{};
  request_.stamp_s = stamp;
  if (expert_) {  // the expert controller: integrates the frame, replans, flies
    if (expert_->SetCameraPose(mount_, frame.get())) {
      try {
        Fly(expert_->OnDepth(frame).flight, stamp);
      } catch (const std::invalid_argument&) {
        Skip("bad_input");
      }
    }
    last_depth_s_ = stamp;
    return;
  }
  if (labeller_ && labeller_->SetCameraPose(mount_, frame.get())) {
    const size_t kept = label_records_->size();
    const bool keep = label_frames_++ % static_cast<uint64_t>(label_stride_) == 0;
    try {
      const fast_planner::ExpertSession::FrameOutput out = labeller_->OnDepth(frame);
      if (!keep) label_records_->Truncate(kept);
      label_records_->SetMapUpdateMs(out.map_update.total_ms);
      if (out.label && out.label->ok()) {
        request_.has_label = true;
        request_.label_knots = out.label->spline->knots();
        request_.label_ctrl_pts = out.label->spline->ctrl_pts();
      } else {
        request_.label_reason = out.label ? out.label->reason : "no goal or odometry yet";
      }
    } catch (const std::invalid_argument& e) {
      request_.label_reason = e.what();
    }
  }
  // policy_node.cpp's checks, in its order.
  if (!goal_) return Skip("no_goal");
  const quad_core::VehicleState* paired =
      quad_core::PairedOdometry(odom_, stamp, [](const quad_core::VehicleState& s) { return s.t_s; });
  if (!paired) return Skip("no_odometry");
  const quad_core::VehicleState odom = *paired;
  const auto& k = sim_.camera_intrinsics();
  // A lazy frame will have the camera's size (the renderer renders it): only a rendered one can differ.
  std::string problem =
      lazy ? std::string()
           : quad_policy::DepthSizeProblem(frame->image.width, frame->image.height, k.width, k.height);
  if (problem.empty()) problem = quad_policy::StateProblem(odom, odom.t_s);
  if (!problem.empty()) return Skip("bad_input");
  if (stamp - odom.t_s > policy_cfg_.max_odom_age_s) return Skip("stale_odometry");
  if ((odom.p_world_body - *goal_).norm() < policy_cfg_.goal_tolerance_m) return Skip("goal_reached");
  if (policy_cfg_.replan_rate_hz > 0.0 && last_decision_ns_ &&
      static_cast<int64_t>(t_ns - *last_decision_ns_) < std::llround(1e9 / policy_cfg_.replan_rate_hz)) {
    return Skip("rate_limited");
  }
  if (lazy) frame->image = sim_.RenderDepth();
  inputs_ = quad_policy::DecisionInputs{};
  inputs_.stamp_s = stamp;
  inputs_.depth = frame->image.view();
  inputs_.camera.intrinsics = k;
  Eigen::Isometry3d T_world_body = Eigen::Isometry3d::Identity();
  T_world_body.linear() = odom.q_world_body.normalized().toRotationMatrix();
  T_world_body.translation() = odom.p_world_body;
  inputs_.camera.T_world_camera = T_world_body * T_body_camera_;
  inputs_.state = odom;
  inputs_.goal_world = *goal_;
  request_.depth_x =
      quad_policy::PreprocessDepth(inputs_.depth, meta_.input_height, meta_.input_width, meta_.max_depth_m);
  request_.state_x = quad_policy::EncodeState(odom, *goal_, meta_);
  request_.state = odom;
  request_.goal_world = *goal_;
  pending_ = true;
}

PolicyEpisode::Outcome PolicyEpisode::Decide(std::vector<float> y,
                                             const quad_policy::PolicyDecider::AskNetwork& ask) {
  if (!pending_) throw std::logic_error("PolicyEpisode::Decide: no decision is pending (Advance first)");
  pending_ = false;
  const uint64_t t_ns = t0_ns_ + step_ * dt_ns_;
  quad_policy::Decision d;
  try {
    d = decider_->Decide(inputs_, std::move(y), ask);
  } catch (const std::invalid_argument& e) {
    Skip("bad_input");
    return Outcome{"none", e.what(), "", false};
  }
  last_decision_ns_ = t_ns;
  ++result_.decisions;
  const quad_policy::DecisionSummary summary = quad_policy::Summarize(d, meta_.hypotheses, inputs_.stamp_s);
  ++result_.counts[quad_policy::ToString(d.safety.verdict)];
  for (const std::string& e : summary.events) ++result_.counts[e];
  if (const quad_policy::UniformBspline* send = d.to_send()) {
    kr_tracker::BsplineGoalSpec spec;
    spec.order = 3;
    spec.traj_id = ++traj_id_;
    spec.start_time_s = inputs_.stamp_s;
    spec.knots = send->Knots();
    spec.pos_pts = send->ctrl_world;
    const std::string why = tracker_.AddGoal(goal_ids_++, spec, inputs_.stamp_s);
    if (!why.empty()) ++result_.counts["tracker_rejection"];
    hovering_ = false;
  } else if (summary.action == "hover" && !hovering_) {
    hovering_ = tracker_.Switch("hover").empty();
    if (!hovering_) ++result_.counts["hover_failed"];
  }
  return Outcome{summary.action, summary.reason, quad_policy::ToString(d.safety.verdict), d.accepted()};
}

void PolicyEpisode::DirectFrame() {
  const double t = quad_core::RospySeconds(t0_ns_ + step_ * dt_ns_);
  switch (phase_) {
    case Phase::kTakeoff: {
      const std::string why = tracker_.Goto(spec_.start_world, spec_.start_yaw_rad, 0.0, 0.0);
      ++gotos_;
      if (why.empty()) {
        phase_ = Phase::kTakingOff;
        t_takeoff_s_ = t;
      } else if (gotos_ >= kMaxGotos) {
        Finish("takeoff_failed", "goto refused: " + why, t);
      }
      return;
    }
    case Phase::kTakingOff: {
      const quad_core::VehicleState* at =
          quad_core::PairedOdometry(odom_, t, [](const quad_core::VehicleState& s) { return s.t_s; });
      if (at && (at->p_world_body - spec_.start_world).norm() < kTakeoffToleranceM &&
          at->v_world.norm() < kTakeoffMaxSpeedMps) {
        if (!spec_.goal_world.allFinite()) {
          Finish("reset_failed", "the controller refused the episode's goal: goal rejected: not finite", t);
          return;
        }
        goal_ = spec_.goal_world;
        const double now_s = quad_core::StampSeconds(t0_ns_ + step_ * dt_ns_);
        if (labeller_) {
          fast_planner::ReplannerOutput unused;
          labeller_->SetGoal(spec_.goal_world, now_s, &unused);
        }
        if (expert_) {  // fast_planner_node plans from its newest sensor stamp
          double plan_s = last_depth_s_;
          if (!expert_->odometry().empty()) plan_s = std::max(plan_s, expert_->odometry().newest().t_s);
          fast_planner::ReplannerOutput out;
          const std::string why = expert_->SetGoal(spec_.goal_world, plan_s, &out);
          if (!why.empty()) {
            Finish("reset_failed", "the controller refused the episode's goal: goal rejected: " + why, t);
            return;
          }
          Fly(out, now_s);
        }
        t_goal_s_ = t;
        phase_ = Phase::kFlying;
        p_prev_ = at->p_world_body;
        next_traj_sample_s_ = 0.0;
        status_end_s_ = 0.0;
      } else if (t - t_takeoff_s_ > limits_.takeoff_timeout_s) {
        char buf[160];
        std::snprintf(buf, sizeof(buf), "take-off to [%.2f, %.2f, %.2f] did not settle",
                      spec_.start_world.x(), spec_.start_world.y(), spec_.start_world.z());
        Finish("takeoff_failed", buf, t);
      }
      return;
    }
    case Phase::kFlying: {
      const quad_sim::EpisodeState& e = sim_.episode();
      if (e.reached_goal) {
        Finish("goal_reached", e.reason, status_end_s_);
      } else if (e.collision.collided) {
        Finish("collision", e.reason, status_end_s_);
      } else if (!e.active) {
        Finish("timeout", "episode ended: " + e.reason, status_end_s_);
      } else if (t - t_goal_s_ > limits_.episode_timeout_s) {
        char buf[96];
        std::snprintf(buf, sizeof(buf), "no goal within %g s", limits_.episode_timeout_s);
        Finish("timeout", buf, t);
      }
      return;
    }
  }
}

void PolicyEpisode::Finish(const std::string& outcome, const std::string& reason, double t_end_s) {
  done_ = true;
  pending_ = false;
  result_.outcome = outcome;
  result_.reason = reason;
  result_.t_goal_s = t_goal_s_;
  result_.t_end_s = t_end_s;
  if (phase_ == Phase::kFlying) {
    result_.flight_time_s = std::max(0.0, t_end_s - t_goal_s_);
    if (outcome == "goal_reached") result_.time_to_goal_s = result_.flight_time_s;
  }
  result_.sim_s = static_cast<double>(result_.steps) * cfg_.sim.physics_dt_s;
}

void PolicyEpisode::set_label_stride(int n) {
  if (n < 1) throw std::invalid_argument("label stride " + std::to_string(n) + " < 1");
  label_stride_ = n;
}

std::vector<OwnedRecord> PolicyEpisode::TakeLabelRecords() {
  return label_records_ ? label_records_->Take() : std::vector<OwnedRecord>{};
}

}  // namespace quad_engine
