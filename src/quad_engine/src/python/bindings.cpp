// quad_engine_py: the rollout engine bound into Python (quad_il.engine wraps it; docs/engine.md). Episodes
// run with the GIL released, so several Python threads (or Ray actors, one process each) fly in parallel.
#include <pybind11/eigen.h>
#include <pybind11/functional.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <array>

#include "quad_engine/dataset_sink.h"
#include "quad_engine/expert_worker.h"
#include "quad_engine/policy_vec.h"
#include "quad_engine/run_codec.h"

namespace py = pybind11;
using namespace quad_engine;  // NOLINT(google-build-using-namespace)

namespace {

Eigen::Vector3d V3(const std::array<double, 3>& a) { return Eigen::Vector3d(a[0], a[1], a[2]); }

py::dict RecordDict(const OwnedRecord& o) {
  const cpp_data_collector::PlanRecord& r = o.record;
  py::dict d;
  d["episode_id"] = r.episode_id;
  d["world_seed"] = r.world_seed;
  d["sim_time_s"] = r.sim_time_s;
  d["depth_stamp_s"] = r.depth_stamp_s;
  d["traj_id"] = r.bspline.traj_id;
  d["start_time_s"] = r.bspline.start_time_s;
  d["num_ctrl_pts"] = r.bspline.ctrl_pts_world.size();
  d["p_world_body"] = r.odom.p_world_body;
  d["goal_world"] = r.goal_world;
  d["status"] = o.status_text;
  return d;
}

EpisodeSpec SpecOf(const py::tuple& t) {
  if (t.size() != 5)
    throw std::invalid_argument("an episode spec is (index, seed, start, start_yaw_rad, goal)");
  return EpisodeSpec{t[0].cast<int64_t>(), t[1].cast<uint64_t>(), V3(t[2].cast<std::array<double, 3>>()),
                     t[3].cast<double>(), V3(t[4].cast<std::array<double, 3>>())};
}

py::dict ResultDict(const PolicyEpisodeResult& r, const quad_sim::World& world) {
  py::dict d;
  d["points"] = r.points;
  d["t_goal_s"] = r.t_goal_s;
  d["t_end_s"] = r.t_end_s;
  py::list boxes;  // center, quaternion x y z w, size (the world markers' fields)
  for (const quad_sim::OrientedBox& b : world.boxes) {
    const auto& q = b.q_world_box;
    boxes.append(py::make_tuple(
        std::array<double, 3>{b.center_world_m.x(), b.center_world_m.y(), b.center_world_m.z()},
        std::array<double, 4>{q.x(), q.y(), q.z(), q.w()},
        std::array<double, 3>{b.size_m.x(), b.size_m.y(), b.size_m.z()}));
  }
  d["boxes"] = boxes;
  d["outcome"] = r.outcome;
  d["reason"] = r.reason;
  d["time_to_goal_s"] = r.time_to_goal_s;
  d["flight_time_s"] = r.flight_time_s;
  d["path_length_m"] = r.path_length_m;
  d["min_clearance_m"] = r.min_clearance_m;
  d["decisions"] = r.decisions;
  d["counts"] = r.counts;
  d["trajectory"] = r.trajectory;
  d["sim_s"] = r.sim_s;
  d["steps"] = r.steps;
  return d;
}

py::array_t<float> FloatArray(const std::vector<float>& v, std::vector<py::ssize_t> shape) {
  py::array_t<float> a(shape);
  std::copy(v.begin(), v.end(), a.mutable_data());
  return a;
}

py::dict RequestDict(const DecisionRequest& r, const quad_policy::PolicyMeta& m) {
  py::dict d;
  d["stamp_s"] = r.stamp_s;
  d["depth"] = FloatArray(r.depth_x, {m.input_height, m.input_width});
  d["state"] = FloatArray(std::vector<float>(r.state_x.begin(), r.state_x.end()), {quad_policy::kStateDim});
  d["goal"] = std::array<double, 3>{r.goal_world.x(), r.goal_world.y(), r.goal_world.z()};
  d["p_world_body"] =
      std::array<double, 3>{r.state.p_world_body.x(), r.state.p_world_body.y(), r.state.p_world_body.z()};
  d["v_world"] = std::array<double, 3>{r.state.v_world.x(), r.state.v_world.y(), r.state.v_world.z()};
  const auto& q = r.state.q_world_body;
  d["q_world_body_xyzw"] = std::array<double, 4>{q.x(), q.y(), q.z(), q.w()};
  d["has_label"] = r.has_label;
  d["label_knots"] = r.label_knots;
  py::array_t<double> ctrl({static_cast<py::ssize_t>(r.label_ctrl_pts.rows()), static_cast<py::ssize_t>(3)});
  for (Eigen::Index i = 0; i < r.label_ctrl_pts.rows(); ++i)
    for (int j = 0; j < 3; ++j) ctrl.mutable_at(i, j) = r.label_ctrl_pts(i, j);
  d["label_ctrl_pts"] = ctrl;
  d["label_reason"] = r.label_reason;
  return d;
}

EpisodeRun LabelRun(PolicyEpisode& e) {
  EpisodeRun run;
  run.records = e.TakeLabelRecords();
  for (OwnedRecord& r : run.records) r.Rebind();
  run.intrinsics = e.intrinsics();
  run.outcome = e.result().outcome;
  run.reason = e.result().reason;
  run.samples = run.records.size();
  return run;
}

}  // namespace

PYBIND11_MODULE(quad_engine_py, m) {
  m.doc() = "The rollout engine's C++ core (issue 32): keyed episodes of the simulator, tracker and expert.";

  py::class_<Configs>(m, "Configs", "The configs of collect.launch, loaded strictly once.");
  m.def(
      "load_configs",
      [](const std::string& sim, const std::string& planner, const std::string& tracker,
         const std::string& vehicle) {
        return LoadConfigs(ConfigPaths{sim, planner, tracker, vehicle});
      },
      py::arg("sim"), py::arg("planner"), py::arg("tracker"), py::arg("vehicle"),
      "Loads config/sim.yaml, planner.yaml, tracker.yaml and vehicle.yaml (errors name the file and key).");
  m.def(
      "sim_camera_mount",
      [](const std::string& sim) {
        const quad_sim::SimConfig c = quad_sim::LoadSimConfig(sim);
        Eigen::Matrix4d T = Eigen::Matrix4d::Identity();
        T.topLeftCorner<3, 3>() = c.camera.q_body_camera.normalized().toRotationMatrix();
        T.topRightCorner<3, 1>() = c.camera.p_body_camera_m;
        return T;
      },
      py::arg("sim"),
      "T_body_camera (4 x 4) of a sim config: the depth camera's optical frame (z forward) in base_link, as "
      "the "
      "simulator publishes it on /tf_static.");

  py::class_<EpisodeRun>(m, "EpisodeRun", "A flown episode: outcome, statistics and its records.")
      .def_property_readonly("index", [](const EpisodeRun& r) { return r.spec.index; })
      .def_property_readonly("seed", [](const EpisodeRun& r) { return r.spec.seed; })
      .def_readonly("outcome", &EpisodeRun::outcome)
      .def_readonly("reason", &EpisodeRun::reason)
      .def_readonly("sim_duration_s", &EpisodeRun::sim_duration_s)
      .def_readonly("samples", &EpisodeRun::samples)
      .def_readonly("steps", &EpisodeRun::steps)
      .def_readonly("frames", &EpisodeRun::frames)
      .def_readonly("plans", &EpisodeRun::plans)
      .def_readonly("plan_failures", &EpisodeRun::plan_failures)
      .def_readonly("sim_s", &EpisodeRun::sim_s)
      .def_readonly("wall_s", &EpisodeRun::wall_s)
      .def_property_readonly("num_records", [](const EpisodeRun& r) { return r.records.size(); })
      .def(
          "records",
          [](const EpisodeRun& r) {
            py::list out;
            for (const OwnedRecord& o : r.records) out.append(RecordDict(o));
            return out;
          },
          "A summary of each record (times, trajectory id, position, goal, status).")
      .def("to_bytes", [](const EpisodeRun& r) { return py::bytes(EncodeRun(r)); })
      .def_static(
          "from_bytes", [](const py::bytes& b) { return DecodeRun(std::string(b)); }, py::arg("data"))
      .def(py::pickle([](const EpisodeRun& r) { return py::bytes(EncodeRun(r)); },
                      [](const py::bytes& b) { return DecodeRun(std::string(b)); }));

  py::class_<ExpertWorker>(m, "ExpertWorker",
                           "Simulator + tracker + expert as collect.launch connects them, in one thread.")
      .def(py::init<const Configs&>(), py::arg("configs"))
      .def(
          "run",
          [](ExpertWorker& w, int64_t index, uint64_t seed, const std::array<double, 3>& start,
             double start_yaw_rad, const std::array<double, 3>& goal, double takeoff_timeout_s,
             double episode_timeout_s, uint64_t max_samples, uint64_t samples_before) {
            EpisodeSpec spec{index, seed, V3(start), start_yaw_rad, V3(goal)};
            EpisodeLimits limits{takeoff_timeout_s, episode_timeout_s, max_samples, samples_before};
            py::gil_scoped_release release;
            return w.Run(spec, limits);
          },
          py::arg("index"), py::arg("seed"), py::arg("start"), py::arg("start_yaw_rad"), py::arg("goal"),
          py::arg("takeoff_timeout_s"), py::arg("episode_timeout_s"), py::arg("max_samples") = 0,
          py::arg("samples_before") = 0, "Flies the keyed episode to its end; returns an EpisodeRun.");

  py::class_<DatasetSink>(m, "DatasetSink", "The expert collector's writer, fed with flown episodes.")
      .def(py::init<const std::string&, const std::string&, const std::string&,
                    std::vector<std::pair<std::string, std::string>>, bool>(),
           py::arg("collector_config"), py::arg("output_dir"), py::arg("commit"), py::arg("run_info"),
           py::arg("append"))
      .def(
          "write",
          [](DatasetSink& s, const EpisodeRun& r) {
            py::gil_scoped_release release;
            s.Write(r);
          },
          py::arg("run"))
      .def("finalize",
           [](DatasetSink& s) {
             const auto f = s.Finalize();
             return py::make_tuple(f.ok, f.text);
           })
      .def("stats_line", &DatasetSink::StatsLine)
      .def_property_readonly("warnings", &DatasetSink::warnings)
      .def_property_readonly("last_warning", &DatasetSink::last_warning);

  py::class_<quad_policy::PolicyNodeConfig>(m, "PolicyConfig", py::module_local(),
                                            "config/policy.yaml (overlays merged).")
      .def_readwrite("replan_rate_hz", &quad_policy::PolicyNodeConfig::replan_rate_hz)
      .def_readwrite("goal_tolerance_m", &quad_policy::PolicyNodeConfig::goal_tolerance_m)
      .def_readwrite("policy_file", &quad_policy::PolicyNodeConfig::policy_file)
      .def_readwrite("num_threads", &quad_policy::PolicyNodeConfig::num_threads);
  m.def("configure_torch_threads", &quad_policy::ConfigureTorchThreads, py::arg("num_threads"),
        "LibTorch's intra-op threads (inter-op: 1), once per process before the first forward pass.");
  m.def("load_policy_config", &quad_policy::LoadPolicyNodeConfig, py::arg("path"),
        "Loads a policy config (an overlay is merged over its base); errors name the file and key.");

  py::class_<quad_policy::PolicyMeta>(m, "PolicyMeta", py::module_local(),
                                      "An exported policy's interface (quad_il_policy.json).")
      .def_readonly("input_height", &quad_policy::PolicyMeta::input_height)
      .def_readonly("input_width", &quad_policy::PolicyMeta::input_width)
      .def_readonly("num_ctrl_pts", &quad_policy::PolicyMeta::num_ctrl_pts)
      .def_readonly("horizon_s", &quad_policy::PolicyMeta::horizon_s)
      .def_readonly("hypotheses", &quad_policy::PolicyMeta::hypotheses)
      .def_property_readonly("output_dim", &quad_policy::PolicyMeta::output_dim)
      .def_property_readonly("network_output_dim", &quad_policy::PolicyMeta::network_output_dim);
  m.def("parse_policy_meta", &quad_policy::ParsePolicyMeta, py::arg("json_text"), py::arg("source"));

  py::class_<quad_policy::TorchPolicy, std::shared_ptr<quad_policy::TorchPolicy>>(
      m, "TorchPolicy", py::module_local(), "An exported policy (LibTorch).")
      .def(py::init<const std::string&>(), py::arg("path"))
      .def_property_readonly("meta", &quad_policy::TorchPolicy::meta)
      .def_property_readonly("path", &quad_policy::TorchPolicy::path);

  py::class_<PolicyVec>(m, "PolicyVec", "N keyed evaluation episodes of the policy, decided in batches.")
      .def(py::init<const Configs&, const quad_policy::PolicyNodeConfig&, const quad_policy::PolicyMeta&, int,
                    bool>(),
           py::arg("configs"), py::arg("policy_config"), py::arg("meta"), py::arg("num_slots"),
           py::arg("with_labeller") = false)
      .def_property_readonly("size", &PolicyVec::size)
      .def(
          "reset",
          [](PolicyVec& v, int i, const py::tuple& spec, double takeoff_timeout_s, double episode_timeout_s) {
            const EpisodeSpec s = SpecOf(spec);
            py::gil_scoped_release release;
            v.slot(i).Reset(s, EvalLimits{takeoff_timeout_s, episode_timeout_s});
          },
          py::arg("slot"), py::arg("spec"), py::arg("takeoff_timeout_s"), py::arg("episode_timeout_s"))
      .def(
          "advance_all",
          [](PolicyVec& v) {
            py::gil_scoped_release release;
            return v.AdvanceAll();
          },
          "Steps every running slot to its next decision; returns the slots waiting for one.")
      .def(
          "advance",
          [](PolicyVec& v, int i) {
            py::gil_scoped_release release;
            return v.slot(i).Advance();
          },
          py::arg("slot"))
      .def(
          "request", [](PolicyVec& v, int i) { return RequestDict(v.slot(i).request(), v.slot(i).meta()); },
          py::arg("slot"))
      .def(
          "decide",
          [](PolicyVec& v, int i, const py::array_t<float, py::array::c_style | py::array::forcecast>& y,
             const std::optional<std::function<py::array_t<float>(std::array<double, 3>)>>& ask) {
            std::vector<float> yv(y.data(), y.data() + y.size());
            quad_policy::PolicyDecider::AskNetwork net;
            if (ask) {
              net = [ask](const Eigen::Vector3d& g) {
                py::gil_scoped_acquire acquire;
                const py::array_t<float, py::array::c_style | py::array::forcecast> out =
                    (*ask)(std::array<double, 3>{g.x(), g.y(), g.z()});
                return std::vector<float>(out.data(), out.data() + out.size());
              };
            }
            PolicyEpisode::Outcome o;
            {
              py::gil_scoped_release release;
              o = v.slot(i).Decide(std::move(yv), net);
            }
            py::dict d;
            d["action"] = o.action;
            d["reason"] = o.reason;
            d["verdict"] = o.verdict;
            d["accepted"] = o.accepted;
            return d;
          },
          py::arg("slot"), py::arg("y"), py::arg("ask") = py::none())
      .def(
          "done", [](PolicyVec& v, int i) { return v.slot(i).done(); }, py::arg("slot"))
      .def(
          "result", [](PolicyVec& v, int i) { return ResultDict(v.slot(i).result(), v.slot(i).world()); },
          py::arg("slot"))
      .def(
          "take_label_run", [](PolicyVec& v, int i) { return LabelRun(v.slot(i)); }, py::arg("slot"),
          "The labeller's records of the slot's episode so far, as an EpisodeRun (DatasetSink.write).")
      .def(
          "run_torch",
          [](PolicyVec& v, const quad_policy::TorchPolicy& policy, const std::vector<py::tuple>& specs,
             double takeoff_timeout_s, double episode_timeout_s,
             const std::function<void(size_t, py::dict, EpisodeRun)>& on_done) {
            std::vector<EpisodeSpec> s;
            for (const py::tuple& t : specs) s.push_back(SpecOf(t));
            py::gil_scoped_release release;
            v.RunTorch(policy, s, EvalLimits{takeoff_timeout_s, episode_timeout_s},
                       [&](size_t k, PolicyEpisode& e) {
                         EpisodeRun labels = LabelRun(e);
                         py::gil_scoped_acquire acquire;
                         on_done(k, ResultDict(e.result(), e.world()), std::move(labels));
                       });
          },
          py::arg("policy"), py::arg("specs"), py::arg("takeoff_timeout_s"), py::arg("episode_timeout_s"),
          py::arg("on_done"),
          "Flies the specs with the LibTorch policy, one batched forward pass per round of decisions.")
      .def_static(
          "experts", [](const Configs& c, int n) { return std::make_unique<PolicyVec>(c, n); },
          py::arg("configs"), py::arg("num_slots"), "num_slots expert controllers (the expert's evaluation).")
      .def(
          "run_expert",
          [](PolicyVec& v, const std::vector<py::tuple>& specs, double takeoff_timeout_s,
             double episode_timeout_s, const std::function<void(size_t, py::dict)>& on_done) {
            std::vector<EpisodeSpec> s;
            for (const py::tuple& t : specs) s.push_back(SpecOf(t));
            py::gil_scoped_release release;
            v.RunExpert(s, EvalLimits{takeoff_timeout_s, episode_timeout_s}, [&](size_t k, PolicyEpisode& e) {
              py::gil_scoped_acquire acquire;
              on_done(k, ResultDict(e.result(), e.world()));
            });
          },
          py::arg("specs"), py::arg("takeoff_timeout_s"), py::arg("episode_timeout_s"), py::arg("on_done"))
      .def(
          "set_label_stride",
          [](PolicyVec& v, int n) {
            for (int i = 0; i < v.size(); ++i) v.slot(i).set_label_stride(n);
          },
          py::arg("n"), "Keep the labels of every n-th frame (the labeller still integrates every frame).")
      .def_property_readonly("forward_passes", &PolicyVec::forward_passes)
      .def_property_readonly("batched_decisions", &PolicyVec::batched_decisions)
      .def_property_readonly("recovery_passes", &PolicyVec::recovery_passes)
      .def_property_readonly("speculated_decisions", &PolicyVec::speculated_decisions);
}
