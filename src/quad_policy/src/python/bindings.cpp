// quad_policy_py: the C++ inference core for Python (pybind11). The Python policy node runs its own torch
// preprocessing and forward pass and calls this for everything else: the decider (decoding, safety layer,
// recovery, final approach, keeping, the stopping trajectory), the config loader (overlays merged), the input
// checks and the policy metadata parser; the evaluation tools use the safety layer and the trajectories.
// Errors: quad_core::ConfigError -> quad_policy_py.ConfigError, PolicyFormatError ->
// quad_policy_py.PolicyFormatError (both ValueError), std::invalid_argument -> ValueError, naming the
// problem.
#include <pybind11/eigen.h>
#include <pybind11/functional.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>
#include <quad_core/pairing.h>

#include <quad_core/strict_yaml.h>

#include "quad_policy/config.h"
#include "quad_policy/input_checks.h"
#include "quad_policy/policy_decider.h"
#include "quad_policy/policy_meta.h"
#include "quad_policy/safety.h"
#include "quad_policy/trajectory.h"

#include <stdexcept>
#include <string>
#include <vector>

namespace py = pybind11;
using namespace quad_policy;

namespace {

using DepthArray = py::array_t<float, py::array::c_style | py::array::forcecast>;
using Vec3 = Eigen::Vector3d;

Vec3 ToVec3(const Eigen::VectorXd& v, const char* name) {
  if (v.size() != 3) {
    throw std::invalid_argument(std::string(name) + " must have 3 values, got " + std::to_string(v.size()));
  }
  return v;
}

Eigen::Quaterniond ToQuat(const Eigen::VectorXd& q, const char* name) {  // x, y, z, w (docs/CONVENTIONS.md)
  if (q.size() != 4) {
    throw std::invalid_argument(std::string(name) + " must have 4 values (x, y, z, w), got " +
                                std::to_string(q.size()));
  }
  return Eigen::Quaterniond(q[3], q[0], q[1], q[2]);
}

// An (H, W) float32 array as a view (the array must outlive it).
DepthImageView ToView(const DepthArray& depth) {
  if (depth.ndim() != 2 || depth.shape(0) < 1 || depth.shape(1) < 1) {
    throw std::invalid_argument("depth image must be a non-empty (H, W) array, got " +
                                std::to_string(depth.ndim()) + " dimension(s)");
  }
  return DepthImageView{static_cast<int>(depth.shape(1)), static_cast<int>(depth.shape(0)),
                        static_cast<std::size_t>(depth.shape(1)), depth.data()};
}

VehicleState ToState(const Eigen::VectorXd& p, const Eigen::VectorXd& v, const Eigen::VectorXd& q) {
  VehicleState s;
  s.p_world_body = ToVec3(p, "p_world_body");
  s.v_world = ToVec3(v, "v_world");
  s.q_world_body = ToQuat(q, "q_world_body");
  return s;
}

UniformBspline MakeSpline(double start_time_s, double knot_dt_s, const CtrlPoints& ctrl) {
  UniformBspline s;
  s.start_time_s = start_time_s;
  s.knot_dt_s = knot_dt_s;
  s.ctrl_world = ctrl;
  return s;
}

// Positions at times t_s (seconds after the start), as a (len(t), 3) array.
Eigen::MatrixXd Positions(const UniformBspline& s, const std::vector<double>& t_s) {
  Eigen::MatrixXd out(t_s.size(), 3);
  for (std::size_t i = 0; i < t_s.size(); ++i) out.row(static_cast<Eigen::Index>(i)) = s.Position(t_s[i]);
  return out;
}

std::vector<std::string> VerdictLabels() {
  std::vector<std::string> out;
  for (int i = 0; i < kNumSafetyVerdicts; ++i) out.push_back(ToString(static_cast<SafetyVerdict>(i)));
  return out;
}

// Config structs are compared field by field through their YAML-visible values.
bool SameConfig(const PolicyNodeConfig& a, const PolicyNodeConfig& b) {
  const auto& sa = a.safety;
  const auto& sb = b.safety;
  return a.policy_file == b.policy_file && a.num_threads == b.num_threads &&
         a.replan_rate_hz == b.replan_rate_hz && a.goal_tolerance_m == b.goal_tolerance_m &&
         a.max_odom_age_s == b.max_odom_age_s && a.odom_period_s == b.odom_period_s &&
         a.odom_wait_s == b.odom_wait_s && a.tracker_accept_timeout_s == b.tracker_accept_timeout_s &&
         a.lockstep_consumer == b.lockstep_consumer && a.send_to_tracker == b.send_to_tracker &&
         a.refusal.action == b.refusal.action &&
         a.refusal.stop_max_decel_mps2 == b.refusal.stop_max_decel_mps2 &&
         a.refusal.stop_min_duration_s == b.refusal.stop_min_duration_s &&
         a.recovery.goal_yaw_offsets_deg == b.recovery.goal_yaw_offsets_deg &&
         a.recovery.final_approach_m == b.recovery.final_approach_m &&
         a.recovery.final_approach_acc_mps2 == b.recovery.final_approach_acc_mps2 &&
         a.keeping.commit_s == b.keeping.commit_s && a.keeping.on_refusal == b.keeping.on_refusal &&
         sa.enabled == sb.enabled && sa.max_vel_mps == sb.max_vel_mps && sa.max_acc_mps2 == sb.max_acc_mps2 &&
         sa.max_start_error_m == sb.max_start_error_m && sa.vehicle_radius_m == sb.vehicle_radius_m &&
         sa.sample_dt_s == sb.sample_dt_s && sa.check_horizon_s == sb.check_horizon_s &&
         sa.collision_min_pixels == sb.collision_min_pixels;
}

}  // namespace

PYBIND11_MODULE(quad_policy_py, m) {
  m.doc() =
      "The C++ inference core of quad_il (quad_policy), bound for the Python policy node. docs/inference.md";
  py::register_exception<quad_core::ConfigError>(m, "ConfigError", PyExc_ValueError);
  py::register_exception<PolicyFormatError>(m, "PolicyFormatError", PyExc_ValueError);

  // The frame/odometry pairing rule (quad_core/pairing.h), bound so that its Python twin
  // (quad_il.frame_pairing, dependency-free for the nodes) is tested against it.
  m.def("odometry_covers_frame", &quad_core::OdometryCoversFrame, py::arg("newest_odom_stamp_s"),
        py::arg("frame_stamp_s"), py::arg("odom_period_s"));
  m.def("odometry_not_newer_than_frame", &quad_core::OdometryNotNewerThanFrame, py::arg("odom_stamp_s"),
        py::arg("frame_stamp_s"));

  py::class_<PolicyMeta>(m, "PolicyMeta")
      .def_readonly("input_height", &PolicyMeta::input_height)
      .def_readonly("input_width", &PolicyMeta::input_width)
      .def_readonly("max_depth_m", &PolicyMeta::max_depth_m)
      .def_property_readonly("state_frame", [](const PolicyMeta& x) { return ToString(x.state_frame); })
      .def_readonly("position_scale_m", &PolicyMeta::position_scale_m)
      .def_readonly("velocity_scale_mps", &PolicyMeta::velocity_scale_mps)
      .def_readonly("velocity_input", &PolicyMeta::velocity_input)
      .def_readonly("num_ctrl_pts", &PolicyMeta::num_ctrl_pts)
      .def_readonly("horizon_s", &PolicyMeta::horizon_s)
      .def_property_readonly("output_frame", [](const PolicyMeta& x) { return ToString(x.output_frame); })
      .def_property_readonly("representation", [](const PolicyMeta& x) { return ToString(x.representation); })
      .def_readonly("poly_degree", &PolicyMeta::poly_degree)
      .def_readonly("hypotheses", &PolicyMeta::hypotheses)
      .def_readonly("mean_first", &PolicyMeta::mean_first)
      .def_property_readonly("knot_dt_s", &PolicyMeta::knot_dt_s)
      .def_property_readonly("output_dim", &PolicyMeta::output_dim)
      .def_property_readonly("network_output_dim", &PolicyMeta::network_output_dim);
  m.def(
      "parse_policy_meta", &ParsePolicyMeta, py::arg("json_text"), py::arg("source"),
      "The exported file's quad_il_policy.json, validated (PolicyFormatError naming `source` and the key).");

  py::class_<SafetyConfig>(m, "SafetyConfig")
      .def(py::init<>())
      .def_readwrite("enabled", &SafetyConfig::enabled)
      .def_readwrite("max_vel_mps", &SafetyConfig::max_vel_mps)
      .def_readwrite("max_acc_mps2", &SafetyConfig::max_acc_mps2)
      .def_readwrite("max_start_error_m", &SafetyConfig::max_start_error_m)
      .def_readwrite("vehicle_radius_m", &SafetyConfig::vehicle_radius_m)
      .def_readwrite("sample_dt_s", &SafetyConfig::sample_dt_s)
      .def_readwrite("check_horizon_s", &SafetyConfig::check_horizon_s)
      .def_readwrite("collision_min_pixels", &SafetyConfig::collision_min_pixels);
  py::class_<RefusalConfig>(m, "RefusalConfig")
      .def(py::init<>())
      .def_property_readonly("action", [](const RefusalConfig& r) { return std::string(ToString(r.action)); })
      .def_readonly("stop_max_decel_mps2", &RefusalConfig::stop_max_decel_mps2)
      .def_readonly("stop_min_duration_s", &RefusalConfig::stop_min_duration_s);
  py::class_<RecoveryConfig>(m, "RecoveryConfig")
      .def(py::init<>())
      .def_readonly("goal_yaw_offsets_deg", &RecoveryConfig::goal_yaw_offsets_deg)
      .def_readonly("final_approach_m", &RecoveryConfig::final_approach_m)
      .def_readonly("final_approach_acc_mps2", &RecoveryConfig::final_approach_acc_mps2);
  py::class_<KeepingConfig>(m, "KeepingConfig")
      .def(py::init<>())
      .def_readonly("commit_s", &KeepingConfig::commit_s)
      .def_readonly("on_refusal", &KeepingConfig::on_refusal);
  py::class_<PolicyNodeConfig>(m, "PolicyNodeConfig")
      .def_readwrite("policy_file", &PolicyNodeConfig::policy_file)
      .def_readwrite("num_threads", &PolicyNodeConfig::num_threads)
      .def_readwrite("send_to_tracker", &PolicyNodeConfig::send_to_tracker)
      .def_readonly("replan_rate_hz", &PolicyNodeConfig::replan_rate_hz)
      .def_readonly("goal_tolerance_m", &PolicyNodeConfig::goal_tolerance_m)
      .def_readonly("max_odom_age_s", &PolicyNodeConfig::max_odom_age_s)
      .def_readonly("odom_period_s", &PolicyNodeConfig::odom_period_s)
      .def_readonly("odom_wait_s", &PolicyNodeConfig::odom_wait_s)
      .def_readonly("tracker_accept_timeout_s", &PolicyNodeConfig::tracker_accept_timeout_s)
      .def_readonly("lockstep_consumer", &PolicyNodeConfig::lockstep_consumer)
      .def_readonly("refusal", &PolicyNodeConfig::refusal)
      .def_readonly("recovery", &PolicyNodeConfig::recovery)
      .def_readonly("keeping", &PolicyNodeConfig::keeping)
      .def_readonly("safety", &PolicyNodeConfig::safety)
      .def("__eq__", &SameConfig);
  m.def("load_policy_config", &LoadPolicyNodeConfig, py::arg("path"),
        "The complete policy node config of a file (an overlay merged over its base chain); ConfigError.");
  m.def("policy_config_from_string", &PolicyNodeConfigFromString, py::arg("yaml_text"), py::arg("source"));

  py::class_<CameraModel>(m, "CameraModel")
      .def(py::init([](int width, int height, double fx, double fy, double cx, double cy,
                       const Eigen::Matrix4d& T_world_camera) {
             CameraModel c;
             c.intrinsics = quad_core::CameraIntrinsics{width, height, fx, fy, cx, cy};
             const std::string problem = c.intrinsics.Validate();
             if (!problem.empty()) throw std::invalid_argument("camera intrinsics: " + problem);
             c.T_world_camera.matrix() = T_world_camera;
             return c;
           }),
           py::arg("width"), py::arg("height"), py::arg("fx"), py::arg("fy"), py::arg("cx"), py::arg("cy"),
           py::arg("T_world_camera"))
      .def_property_readonly("width", [](const CameraModel& c) { return c.intrinsics.width; })
      .def_property_readonly("height", [](const CameraModel& c) { return c.intrinsics.height; })
      .def_property_readonly("fx", [](const CameraModel& c) { return c.intrinsics.fx; })
      .def_property_readonly("fy", [](const CameraModel& c) { return c.intrinsics.fy; })
      .def_property_readonly("cx", [](const CameraModel& c) { return c.intrinsics.cx; })
      .def_property_readonly("cy", [](const CameraModel& c) { return c.intrinsics.cy; })
      .def_property_readonly("T_world_camera",
                             [](const CameraModel& c) { return Eigen::Matrix4d(c.T_world_camera.matrix()); });

  py::class_<UniformBspline>(m, "UniformBspline")
      .def(py::init(&MakeSpline), py::arg("start_time_s"), py::arg("knot_dt_s"), py::arg("ctrl_world"))
      .def_readonly("start_time_s", &UniformBspline::start_time_s)
      .def_readonly("knot_dt_s", &UniformBspline::knot_dt_s)
      .def_readonly("ctrl_world", &UniformBspline::ctrl_world)
      .def_property_readonly("duration_s", &UniformBspline::duration_s)
      .def("knots", &UniformBspline::Knots)
      .def("position", &Positions, py::arg("t_s"), "(len(t_s), 3) positions at t_s seconds after the start");

  m.def("verdict_labels", &VerdictLabels, "The safety verdicts' names, indexed by their numbers.");
  py::class_<SafetyResult>(m, "SafetyResult")
      .def_property_readonly("verdict", [](const SafetyResult& r) { return static_cast<int>(r.verdict); })
      .def_property_readonly("label", [](const SafetyResult& r) { return std::string(ToString(r.verdict)); })
      .def_property_readonly("accepted", &SafetyResult::accepted)
      .def_readonly("reason", &SafetyResult::reason)
      .def_readonly("value", &SafetyResult::value);
  m.def(
      "check_trajectory",
      [](const UniformBspline& traj, const Eigen::VectorXd& p, const DepthArray& depth,
         const CameraModel& camera, const SafetyConfig& cfg) {
        const DepthImageView view = ToView(depth);
        return CheckTrajectory(traj, ToVec3(p, "p_world_vehicle"), &view, camera, cfg);
      },
      py::arg("traj"), py::arg("p_world_vehicle"), py::arg("depth_m"), py::arg("camera"), py::arg("cfg"));
  m.def("trajectory_in_view", [](const UniformBspline& t, const CameraModel& c, const SafetyConfig& s) {
    return TrajectoryInView(t, c, s);
  });
  m.def("safety_sample_times",
        [](const UniformBspline& t, const SafetyConfig& s) { return SafetySampleTimes(t, s); });
  m.def(
      "braking_trajectory",
      [](const Eigen::VectorXd& p0, const Eigen::VectorXd& v0, double decel, double min_duration,
         double start) {
        return BrakingTrajectory(ToVec3(p0, "p0_world"), ToVec3(v0, "v0_world"), decel, min_duration, start);
      },
      py::arg("p0_world"), py::arg("v0_world"), py::arg("max_decel_mps2"), py::arg("min_duration_s"),
      py::arg("start_time_s"));

  m.def("depth_layout_problem", [](const std::string& encoding, bool big_endian, uint32_t width,
                                   uint32_t height, uint32_t step, std::size_t data_bytes) {
    return DepthLayoutProblem({encoding, big_endian, width, height, step, data_bytes});
  });
  m.def("depth_size_problem", &DepthSizeProblem);
  m.def("state_problem", [](const Eigen::VectorXd& p, const Eigen::VectorXd& v, const Eigen::VectorXd& q,
                            double stamp_s) { return StateProblem(ToState(p, v, q), stamp_s); });

  py::class_<DecisionTimings>(m, "DecisionTimings")
      .def_readonly("decode_ms", &DecisionTimings::decode_ms)
      .def_readonly("safety_ms", &DecisionTimings::safety_ms);
  py::class_<DecisionSummary>(m, "DecisionSummary")
      .def_readonly("action", &DecisionSummary::action)
      .def_readonly("reason", &DecisionSummary::reason)
      .def_readonly("events", &DecisionSummary::events);
  py::class_<Decision>(m, "Decision")
      .def_readonly("safety", &Decision::safety)
      .def_property_readonly("verdict_label",
                             [](const Decision& d) { return std::string(ToString(d.safety.verdict)); })
      .def_property_readonly("accepted", &Decision::accepted)
      .def_readonly("proposed", &Decision::proposed)
      .def_readonly("proposed_hypothesis", &Decision::proposed_hypothesis)
      .def_readonly("stop", &Decision::stop)
      .def_readonly("recovery", &Decision::recovery)
      .def_readonly("recovery_yaw_deg", &Decision::recovery_yaw_deg)
      .def_readonly("recovery_hypothesis", &Decision::recovery_hypothesis)
      .def_readonly("recovery_tries", &Decision::recovery_tries)
      .def_readonly("final_approach", &Decision::final_approach)
      .def_readonly("kept", &Decision::kept)
      .def_readonly("committed", &Decision::committed)
      .def_readonly("y", &Decision::y)
      .def_readonly("timings", &Decision::timings)
      .def_property_readonly("sent_kind", [](const Decision& d) { return static_cast<int>(d.sent_kind()); })
      .def_property_readonly("to_send",
                             [](const Decision& d) {
                               const UniformBspline* s = d.to_send();
                               return s ? std::optional<UniformBspline>(*s) : std::nullopt;
                             })
      .def("summary", &Summarize, py::arg("num_hypotheses"), py::arg("stamp_s"));

  py::class_<PolicyDecider>(m, "PolicyDecider")
      .def(py::init<const PolicyMeta&, const SafetyConfig&, const RefusalConfig&, const RecoveryConfig&,
                    const KeepingConfig&>(),
           py::arg("meta"), py::arg("safety"), py::arg("refusal"), py::arg("recovery") = RecoveryConfig(),
           py::arg("keeping") = KeepingConfig())
      .def(
          "decide",
          [](PolicyDecider& self, double stamp_s, const DepthArray& depth, const CameraModel& camera,
             const Eigen::VectorXd& p, const Eigen::VectorXd& v, const Eigen::VectorXd& q,
             const Eigen::VectorXd& goal, const std::vector<float>& y,
             const std::function<std::vector<float>(const Vec3&)>& ask) {
            DecisionInputs in;
            in.stamp_s = stamp_s;
            in.depth = ToView(depth);
            in.camera = camera;
            in.state = ToState(p, v, q);
            in.goal_world = ToVec3(goal, "goal_world");
            return self.Decide(in, y, ask);
          },
          py::arg("stamp_s"), py::arg("depth_m"), py::arg("camera"), py::arg("p_world_body"),
          py::arg("v_world"), py::arg("q_world_body"), py::arg("goal_world"), py::arg("y"), py::arg("ask"),
          "One decision from the network's output y for goal_world; ask(turned_goal) -> the network's output "
          "for "
          "a turned goal (the recovery).")
      .def("reset", &PolicyDecider::Reset)
      .def_property_readonly("accepted_count",
                             [](const PolicyDecider& d) { return d.counts()[SafetyVerdict::kAccepted]; })
      .def_property_readonly("refused_count", [](const PolicyDecider& d) { return d.counts().refused(); });
}
