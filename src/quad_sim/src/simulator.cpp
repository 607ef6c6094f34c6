#include "quad_sim/simulator.h"

#include "quad_sim/math_utils.h"

#include <algorithm>
#include <cmath>
#include <iomanip>
#include <sstream>
#include <stdexcept>

namespace quad_sim {

namespace {

constexpr double kRadToDeg = 180.0 / 3.14159265358979323846;
// The vehicle counts as landed after resting on the ground this long (stale-command landing then cuts
// motors).
constexpr double kLandedDwell_s = 0.5;

std::string Vec(const Eigen::Vector3d& v) {
  std::ostringstream s;
  s << std::fixed << std::setprecision(3) << "(" << v.x() << ", " << v.y() << ", " << v.z() << ")";
  return s.str();
}

std::string Fixed(double v, int digits = 3) {
  std::ostringstream s;
  s << std::fixed << std::setprecision(digits) << v;
  return s.str();
}

}  // namespace

const char* ToString(EpisodeOutcome o) {
  switch (o) {
    case EpisodeOutcome::kRunning:
      return "running";
    case EpisodeOutcome::kCollided:
      return "collided";
    case EpisodeOutcome::kReachedGoal:
      return "goal reached";
    case EpisodeOutcome::kTimedOut:
      return "timed out";
    case EpisodeOutcome::kNumericalFailure:
      return "numerical failure";
  }
  return "unknown";
}

Simulator::Simulator(const SimConfig& config)
    : config_(config),
      dynamics_(config.vehicle, config.ground_contact),
      attitude_(config.vehicle),
      renderer_(config.camera),
      collision_checker_(config.vehicle.collision_box_m) {
  config_.Validate();
  spawn_frame_.origin_world_m = config_.spawn_frame.origin_world_m;
  spawn_frame_.units_per_m = config_.spawn_frame.units_per_m;
}

Simulator::~Simulator() = default;

OrientedBox Simulator::VehicleBox() const {
  OrientedBox b;
  b.center_world_m = state_.p_world_body;
  b.q_world_box = state_.q_world_body;
  b.size_m = config_.vehicle.collision_box_m;
  return b;
}

void Simulator::Reset(const World& world, const Eigen::Vector3d& p_start_world, double yaw_start_rad,
                      const Eigen::Vector3d& goal_world, std::optional<uint32_t> episode_id) {
  if (!p_start_world.allFinite() || !std::isfinite(yaw_start_rad) || !goal_world.allFinite()) {
    throw std::invalid_argument("Simulator::Reset: start " + Vec(p_start_world) + ", yaw " +
                                std::to_string(yaw_start_rad) + " or goal " + Vec(goal_world) +
                                " is not finite");
  }
  try {
    world.Validate();
  } catch (const std::invalid_argument& e) {
    throw std::invalid_argument(std::string("Simulator::Reset: invalid world: ") + e.what());
  }
  OrientedBox start_box;
  start_box.center_world_m = p_start_world;
  start_box.q_world_box = QuatFromRpy(0.0, 0.0, yaw_start_rad);
  start_box.size_m = config_.vehicle.collision_box_m;
  const double half_h = 0.5 * config_.vehicle.collision_box_m.z();
  const double lowest = p_start_world.z() - half_h;
  if (lowest < -1e-9) {
    throw std::invalid_argument(
        "Simulator::Reset: start pose " + Vec(p_start_world) +
        " puts the vehicle box below the ground (its bottom at z = " + Fixed(lowest, 4) +
        " m; the lowest valid start z is " + Fixed(half_h, 4) + " m)");
  }
  for (size_t i = 0; i < world.boxes.size(); ++i) {
    if (BoxesOverlap(start_box, world.boxes[i])) {
      const OrientedBox& b = world.boxes[i];
      throw std::invalid_argument("Simulator::Reset: start pose " + Vec(p_start_world) +
                                  " puts the vehicle box inside world box " + std::to_string(i) +
                                  " (centre " + Vec(b.center_world_m) + ", size " + Vec(b.size_m) + ")");
    }
  }

  world_ = world;
  index_.Build(world_);
  collision_checker_.SetWorld(world_);
  goal_world_ = goal_world;

  state_ = DynamicsState();
  state_.p_world_body = p_start_world;
  state_.q_world_body = start_box.q_world_box;
  const bool on_ground = lowest <= 1e-6;
  target_ = AttitudeTarget();
  target_.thrust_from_force = false;
  target_.R_world_des = start_box.q_world_box.toRotationMatrix();
  if (on_ground) {
    target_.enable_motors = false;
  } else {
    // Airborne start: hover at trim until the first command (and the stale-command timeout) arrives.
    target_.enable_motors = true;
    target_.thrust_N = config_.vehicle.HoverThrustN();
    state_.motor_speeds_radps.setConstant(config_.vehicle.HoverMotorSpeedRadps());
  }
  motor_cmd_ = state_.motor_speeds_radps;
  step_count_ = 0;
  last_command_step_ = 0;
  command_stale_ = false;
  frozen_ = false;
  in_ground_contact_ = on_ground;
  landed_since_s_ = on_ground ? 0.0 : -1.0;
  num_rejected_commands_ = 0;
  boxes_in_contact_.clear();
  episode_ = EpisodeState();
  episode_.episode_id = episode_id ? *episode_id : next_episode_id_++;
  episode_.active = true;
  episode_.reason = "running";
  // The noise stream depends on the configured seed and the world's seed only, so equal episodes are
  // identical.
  std::seed_seq seq{static_cast<uint32_t>(config_.noise_seed),
                    static_cast<uint32_t>(config_.noise_seed >> 32), static_cast<uint32_t>(world_.seed),
                    static_cast<uint32_t>(world_.seed >> 32)};
  noise_rng_.seed(seq);
}

void Simulator::ResetDefault(uint64_t seed) {
  World world;
  if (!config_.world_file.empty()) {
    world = LoadWorld(config_.world_file);
  } else {
    world = GenerateWorld(config_.world_gen, seed);
  }
  Reset(world, config_.start_m, config_.start_yaw_rad, config_.goal_m);
}

CommandStatus Simulator::SetSo3Command(const So3Command& cmd) {
  CommandStatus status = ValidateCommand(cmd);
  if (!status.ok()) {
    ++num_rejected_commands_;
    return status;
  }
  target_ = AttitudeTarget::FromSo3(cmd);
  last_command_step_ = step_count_;
  return status;
}

CommandStatus Simulator::SetTrpyCommand(const TrpyCommand& cmd) {
  CommandStatus status = ValidateCommand(cmd);
  if (!status.ok()) {
    ++num_rejected_commands_;
    return status;
  }
  target_ = AttitudeTarget::FromTrpy(cmd);
  last_command_step_ = step_count_;
  return status;
}

bool Simulator::OdometryDue() const {
  const auto steps =
      static_cast<uint64_t>(std::llround(1.0 / (config_.physics_dt_s * config_.odometry_rate_hz)));
  return step_count_ % steps == 0;
}

bool Simulator::DepthDue() const {
  if (step_count_ == 0) return true;
  // Frame k is due at the first step at or after k / rate (1e-9 absorbs rounding of n * dt * rate).
  const double r = config_.physics_dt_s * config_.camera.rate_hz;
  const auto frame_now = static_cast<uint64_t>(std::floor(static_cast<double>(step_count_) * r + 1e-9));
  const auto frame_before =
      static_cast<uint64_t>(std::floor(static_cast<double>(step_count_ - 1) * r + 1e-9));
  return frame_now != frame_before;
}

AttitudeTarget Simulator::StaleTarget() const {
  AttitudeTarget t;
  t.thrust_from_force = false;
  t.R_world_des = QuatFromRpy(0.0, 0.0, YawOf(state_.q_world_body)).toRotationMatrix();
  const bool landed = landed_since_s_ >= 0.0 && time_s() - landed_since_s_ >= kLandedDwell_s;
  if (config_.stale_command.action == StaleCommandAction::kMotorsOff || landed) {
    t.enable_motors = false;
    return t;
  }
  // Emulates an autopilot's land mode: level attitude and a vertical-speed loop towards -descent_rate.
  const double a_z = config_.stale_command.vertical_gain_per_s *
                     (-config_.stale_command.descent_rate_mps - state_.v_world.z());
  const double tilt_cos = std::max(0.5, (state_.q_world_body * Eigen::Vector3d::UnitZ()).z());
  t.thrust_N = std::clamp(config_.vehicle.mass_kg * (config_.vehicle.gravity_mps2 + a_z) / tilt_cos, 0.0,
                          config_.vehicle.MaxThrustN());
  t.enable_motors = true;
  return t;
}

void Simulator::Step() {
  const double dt = config_.physics_dt_s;
  if (frozen_) {
    ++step_count_;
    return;
  }
  command_stale_ =
      static_cast<double>(step_count_ - last_command_step_) * dt > config_.stale_command.timeout_s;
  motor_cmd_ = attitude_.MotorCommands(command_stale_ ? StaleTarget() : target_, state_);
  const DynamicsState next = dynamics_.Step(state_, motor_cmd_, dt);
  ++step_count_;
  if (!next.AllFinite()) {
    // Cannot happen with validated commands and parameters; if it does, keep the last finite state.
    frozen_ = true;
    EndEpisode(EpisodeOutcome::kNumericalFailure,
               "numerical failure: non-finite state at t=" + Fixed(time_s()) + " s");
    return;
  }
  state_ = next;
  CheckCollisions();
  if (frozen_) return;
  if (episode_.active && (state_.p_world_body - goal_world_).norm() <= config_.episode.goal_tolerance_m) {
    episode_.reached_goal = true;
    episode_.reached_goal_time_s = time_s();
    EndEpisode(EpisodeOutcome::kReachedGoal, "goal reached at t=" + Fixed(time_s()) + " s");
  }
  if (episode_.active && config_.episode.max_duration_s > 0.0 &&
      time_s() >= config_.episode.max_duration_s - 0.5 * dt) {
    EndEpisode(EpisodeOutcome::kTimedOut, "timed out at t=" + Fixed(time_s()) + " s");
  }
}

void Simulator::EndEpisode(EpisodeOutcome outcome, const std::string& reason) {
  if (!episode_.active) return;
  episode_.active = false;
  episode_.outcome = outcome;
  episode_.reason = reason;
}

void Simulator::CheckCollisions() {
  const std::vector<Contact> contacts = collision_checker_.Check(state_.p_world_body, state_.q_world_body);
  bool ground_now = false;
  Contact ground_contact;
  std::vector<int> boxes_now;
  std::vector<Contact> new_hits;
  for (const Contact& c : contacts) {
    if (c.box_index == kHitGround) {
      ground_now = true;
      ground_contact = c;
      continue;
    }
    boxes_now.push_back(c.box_index);
    if (std::find(boxes_in_contact_.begin(), boxes_in_contact_.end(), c.box_index) ==
        boxes_in_contact_.end()) {
      new_hits.push_back(c);
    }
  }
  boxes_in_contact_ = boxes_now;
  if (ground_now && !in_ground_contact_) {
    // Touchdown: a gentle, level landing is fine; anything harder is a crash into the ground.
    const Eigen::Vector3d& v = state_.v_world;
    const double tilt_deg = TiltOf(state_.q_world_body) * kRadToDeg;
    if (-v.z() > config_.ground_crash.max_landing_speed_mps ||
        v.head<2>().norm() > config_.ground_crash.max_landing_horizontal_speed_mps ||
        tilt_deg > config_.ground_crash.max_landing_tilt_deg) {
      new_hits.push_back(ground_contact);
    }
  }
  in_ground_contact_ = ground_now;
  if (ground_now) {
    if (landed_since_s_ < 0.0) landed_since_s_ = time_s();
  } else {
    landed_since_s_ = -1.0;
  }

  for (const Contact& c : new_hits) {
    CollisionInfo& info = episode_.collision;
    ++info.num_collisions;
    const std::string what =
        c.box_index == kHitGround ? std::string("the ground") : "box " + std::to_string(c.box_index);
    if (!info.collided) {
      info.collided = true;
      info.time_s = time_s();
      info.box_index = c.box_index;
      info.point_world_m = c.point_world_m;
    }
    if (config_.collision_policy == CollisionPolicy::kFreeze) {
      EndEpisode(EpisodeOutcome::kCollided, "collision with " + what + " at t=" + Fixed(time_s()) + " s");
      frozen_ = true;
      state_.v_world.setZero();
      state_.w_body.setZero();
      state_.motor_speeds_radps.setZero();
      motor_cmd_.setZero();
      break;
    }
    if (episode_.active) {
      episode_.reason = "running (" + std::to_string(info.num_collisions) + " collision(s), last with " +
                        what + " at t=" + Fixed(time_s()) + " s)";
    }
  }
}

quad_core::DepthImage Simulator::RenderDepth() {
  Eigen::Vector3d p;
  Eigen::Quaterniond q;
  CameraPoseWorld(&p, &q);
  quad_core::DepthImage img = renderer_.Render(index_, p, q);
  renderer_.AddNoise(&img, &noise_rng_);
  return img;
}

void Simulator::CameraPoseWorld(Eigen::Vector3d* p_world_camera, Eigen::Quaterniond* q_world_camera) const {
  *p_world_camera = state_.p_world_body + state_.q_world_body * config_.camera.p_body_camera_m;
  *q_world_camera = (state_.q_world_body * config_.camera.q_body_camera).normalized();
}

double Simulator::ClearanceToObstacles() const { return index_.Clearance(VehicleBox()).distance_m; }

double Simulator::GroundHeightInSpawnFrame() const {
  // The engine's ground query: the point of the ground plane straight below the vehicle (boxes are ignored).
  const Eigen::Vector3d ground_world(state_.p_world_body.x(), state_.p_world_body.y(), 0.0);
  return spawn_frame_.ToSpawn(ground_world).z();
}

quad_core::VehicleState Simulator::Odometry(double z_offset_m, double t_s) const {
  quad_core::VehicleState o = state_.Odometry(t_s);
  const Eigen::Vector3d& origin = config_.spawn_frame.origin_world_m;
  o.p_world_body = VehiclePositionInSpawnFrame() / config_.spawn_frame.units_per_m +
                   Eigen::Vector3d(origin.x(), origin.y(), z_offset_m);
  return o;
}

}  // namespace quad_sim
