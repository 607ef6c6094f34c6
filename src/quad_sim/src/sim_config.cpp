#include "quad_sim/sim_config.h"

#include "quad_sim/math_utils.h"

#include <quad_core/strict_yaml.h>

#include <array>
#include <cmath>
#include <stdexcept>

namespace quad_sim {

namespace {

constexpr double kDegToRad = 3.14159265358979323846 / 180.0;

Eigen::Vector3d ReadVector3(quad_core::StrictYaml* y, const std::string& key,
                            const quad_core::Check& check = nullptr) {
  const std::vector<double> v = y->Get<std::vector<double>>(key, check);
  if (v.size() != 3) {
    throw quad_core::ConfigError(y->source() + ": key '" + key + "' must be a list of 3 numbers, got " +
                                 std::to_string(v.size()));
  }
  return Eigen::Vector3d(v[0], v[1], v[2]);
}

std::string DirName(const std::string& path) {
  const size_t slash = path.find_last_of('/');
  return slash == std::string::npos ? std::string(".") : path.substr(0, slash);
}

std::string Resolve(const std::string& base_dir, const std::string& path) {
  if (path.empty() || path[0] == '/') return path;
  return base_dir + "/" + path;
}

template <typename Enum, size_t N>
Enum ReadEnum(quad_core::StrictYaml* y, const std::string& key,
              const std::array<std::pair<const char*, Enum>, N>& map) {
  const std::string value = y->Get<std::string>(key);
  std::string allowed;
  for (const auto& [name, e] : map) {
    if (value == name) return e;
    allowed += (allowed.empty() ? "'" : ", '") + std::string(name) + "'";
  }
  throw quad_core::ConfigError(y->source() + ": key '" + key + "' has value '" + value +
                               "' which is not one of " + allowed);
}

}  // namespace

const char* ToString(CollisionPolicy p) { return p == CollisionPolicy::kFreeze ? "freeze" : "continue"; }
const char* ToString(StaleCommandAction a) { return a == StaleCommandAction::kLand ? "land" : "motors_off"; }
const char* ToString(TimeMode m) {
  switch (m) {
    case TimeMode::kRealTime:
      return "real_time";
    case TimeMode::kRealTimeFactor:
      return "factor";
    case TimeMode::kAsFastAsPossible:
      return "as_fast_as_possible";
    case TimeMode::kLockstep:
      return "lockstep";
  }
  return "unknown";
}

void SimConfig::Validate() const {
  auto fail = [](const std::string& what) { throw std::invalid_argument("SimConfig: " + what); };
  vehicle.Validate();
  camera.Validate();
  world_gen.Validate();
  if (!(physics_dt_s > 0.0 && physics_dt_s <= 0.01)) fail("physics.dt_s must be in (0, 0.01]");
  if (!(odometry_rate_hz > 0.0)) fail("odometry_rate_hz must be > 0");
  const double steps = 1.0 / (physics_dt_s * odometry_rate_hz);
  if (steps < 1.0 - 1e-9 || std::abs(steps - std::round(steps)) > 1e-6) {
    fail("odometry_rate_hz = " + std::to_string(odometry_rate_hz) + " must divide the physics rate " +
         std::to_string(1.0 / physics_dt_s) + " Hz");
  }
  if (camera.rate_hz * physics_dt_s > 1.0) fail("camera.rate_hz must not exceed the physics rate");
  if (!(stale_command.timeout_s > 0.0)) fail("stale_command.timeout_s must be > 0");
  if (!(episode.goal_tolerance_m > 0.0)) fail("episode.goal_tolerance_m must be > 0");
  if (!(spawn_frame.units_per_m > 0.0) || !spawn_frame.origin_world_m.allFinite()) {
    fail("spawn_frame: units_per_m must be > 0 and origin_world_m finite");
  }
  if (!(time.real_time_factor > 0.0)) fail("time.real_time_factor must be > 0");
  if (!(time.clock_period_s >= physics_dt_s)) fail("time.clock_period_s must be >= physics.dt_s");
  if (!(lockstep.timeout_s > 0.0)) fail("lockstep.timeout_s must be > 0");
  if (!start_m.allFinite() || !goal_m.allFinite() || !std::isfinite(start_yaw_rad))
    fail("start/goal must be finite");
}

SimConfig LoadSimConfig(const std::string& yaml_path) {
  using quad_core::NonNegative;
  using quad_core::Positive;
  quad_core::StrictYaml y = quad_core::StrictYaml::FromFile(yaml_path);
  const std::string dir = DirName(yaml_path);
  SimConfig c;
  c.vehicle_file = Resolve(dir, y.Get<std::string>("vehicle_file"));
  c.vehicle = quad_core::LoadVehicleParams(c.vehicle_file);

  c.physics_dt_s = y.Get<double>("physics.dt_s", quad_core::InRange(1e-5, 0.01));
  c.odometry_rate_hz = y.Get<double>("odometry_rate_hz", Positive());

  c.ground_contact.stiffness_N_per_m = y.Get<double>("ground_contact.stiffness_N_per_m", Positive());
  c.ground_contact.damping_Ns_per_m = y.Get<double>("ground_contact.damping_Ns_per_m", NonNegative());
  c.ground_contact.friction_coeff = y.Get<double>("ground_contact.friction_coeff", NonNegative());
  c.ground_contact.friction_damping_Ns_per_m =
      y.Get<double>("ground_contact.friction_damping_Ns_per_m", NonNegative());
  c.ground_crash.max_landing_speed_mps = y.Get<double>("ground_contact.crash_vertical_speed_mps", Positive());
  c.ground_crash.max_landing_horizontal_speed_mps =
      y.Get<double>("ground_contact.crash_horizontal_speed_mps", Positive());
  c.ground_crash.max_landing_tilt_deg =
      y.Get<double>("ground_contact.crash_tilt_deg", quad_core::InRange(0, 180));

  const int width = y.Get<int>("camera.width", quad_core::InRange(1, 8192));
  const int height = y.Get<int>("camera.height", quad_core::InRange(1, 8192));
  c.camera.intrinsics = DepthCameraConfig::FastPlannerFov(width, height);
  c.camera.rate_hz = y.Get<double>("camera.rate_hz", Positive());
  c.camera.min_depth_m = y.Get<double>("camera.min_depth_m", NonNegative());
  c.camera.max_depth_m = y.Get<double>("camera.max_depth_m", Positive());
  c.camera.p_body_camera_m = ReadVector3(&y, "camera.mount_xyz_m");
  const Eigen::Vector3d rpy = ReadVector3(&y, "camera.mount_rpy_deg") * kDegToRad;
  c.camera.q_body_camera = OpticalMountRotation(rpy.x(), rpy.y(), rpy.z());
  c.camera.noise_std_at_1m_m = y.Get<double>("camera.noise_std_at_1m_m", NonNegative());
  c.camera.num_threads = y.Get<int>("camera.num_threads", quad_core::InRange(1, 64));

  c.collision_policy = ReadEnum<CollisionPolicy, 2>(
      &y, "collision.policy",
      {{{"freeze", CollisionPolicy::kFreeze}, {"continue", CollisionPolicy::kContinue}}});

  c.stale_command.timeout_s = y.Get<double>("stale_command.timeout_s", Positive());
  c.stale_command.action = ReadEnum<StaleCommandAction, 2>(
      &y, "stale_command.action",
      {{{"land", StaleCommandAction::kLand}, {"motors_off", StaleCommandAction::kMotorsOff}}});
  c.stale_command.descent_rate_mps = y.Get<double>("stale_command.descent_rate_mps", Positive());
  c.stale_command.vertical_gain_per_s = y.Get<double>("stale_command.vertical_gain_per_s", Positive());

  c.episode.goal_tolerance_m = y.Get<double>("episode.goal_tolerance_m", Positive());
  c.episode.max_duration_s = y.Get<double>("episode.max_duration_s", NonNegative());

  c.world_file = Resolve(dir, y.Get<std::string>("world.file"));
  c.world_seed = y.Get<uint64_t>("world.seed");
  c.start_m = ReadVector3(&y, "world.start_m");
  c.start_yaw_rad = y.Get<double>("world.start_yaw_deg", quad_core::InRange(-180.0, 180.0)) * kDegToRad;
  c.goal_m = ReadVector3(&y, "world.goal_m");
  {
    quad_core::StrictYaml gen(y.GetNode("world.generator"), yaml_path + ": world.generator");
    c.world_gen = ReadWorldGenConfig(&gen);
    gen.CheckAllKeysUsed();
  }
  c.world_gen.AddClearZone(c.start_m);
  c.world_gen.AddClearZone(c.goal_m);

  c.voxel_map.resolution_m = y.Get<double>("voxel_map.resolution_m", quad_core::InRange(0.01, 10.0));
  c.octomap_file = y.Get<std::string>("voxel_map.octomap_file");

  c.spawn_frame.origin_world_m = ReadVector3(&y, "spawn_frame.origin_world_m");
  c.spawn_frame.units_per_m = y.Get<double>("spawn_frame.units_per_m", Positive());

  c.time.mode = ReadEnum<TimeMode, 4>(&y, "time.mode",
                                      {{{"real_time", TimeMode::kRealTime},
                                        {"factor", TimeMode::kRealTimeFactor},
                                        {"as_fast_as_possible", TimeMode::kAsFastAsPossible},
                                        {"lockstep", TimeMode::kLockstep}}});
  c.time.real_time_factor = y.Get<double>("time.real_time_factor", Positive());
  c.time.clock_period_s = y.Get<double>("time.clock_period_s", Positive());

  c.lockstep.depth_consumers = y.Get<std::vector<std::string>>("lockstep.depth_consumers");
  c.lockstep.wait_for_command = y.Get<bool>("lockstep.wait_for_command");
  c.lockstep.timeout_s = y.Get<double>("lockstep.timeout_s", Positive());
  c.noise_seed = y.Get<uint64_t>("noise_seed");
  y.CheckAllKeysUsed();
  try {
    c.Validate();
  } catch (const std::invalid_argument& e) {
    throw quad_core::ConfigError(yaml_path + ": " + e.what());
  }
  return c;
}

}  // namespace quad_sim
