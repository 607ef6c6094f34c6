// policy_replay: runs the C++ decision pipeline (quad_policy::PolicyDecider, what policy_node runs) on
// recorded inputs (a DecisionFixture directory) and writes every intermediate result as .npy, together with
// the exported file's own preprocessing, decoding and end-to-end forward on the same inputs.
// tests/python/test_inference_parity.py compares these with the Python pipeline (docs/inference.md,
// "Parity").
//
//   policy_replay --policy policy.ts --fixture DIR --config config/policy.yaml --out DIR [--threads N]
//                 [--trajectories ctrl.npy]
//
// With --trajectories (an (N, K, 3) array of world-frame control points, one trajectory per frame, knot
// interval --knot-dt, default the policy's), the safety layer alone also judges those trajectories against
// frame i's depth, camera and odometry: traj_verdict.npy, traj_value.npy (designed cases for every refusal
// reason) and traj_in_view.npy (TrajectoryInView). The decisions: sent_kind.npy (Decision::sent_kind: 0
// nothing, 1 the policy's plan, 2 the stopping trajectory, 3 the recovery's, 5 the final approach, 6 the plan
// sent before kept on a refusal, 7 committed to; 4 was steering, removed), recovery_tries.npy,
// recovery_yaw_deg.npy (NaN: not recovered), recovery_ctrl.npy (zeros: not recovered), final_ctrl.npy and
// final_knot_dt.npy (zeros: none), stop_ctrl.npy and stop_knot_dt.npy (zeros: none). With several hypotheses
// (model.hypotheses), y.npy holds the whole network output, proposed_hypothesis.npy the index of the plan
// proposed and recovery_hypothesis.npy that of the recovery's plan (-1: not recovered); file_decode.npy
// decodes the file's own `select`. The frames are decided in order by one decider, as a node decides an
// episode. reason.txt: the decision's words (Summarize), one line per frame.
//
// Exit status: 0 done, 1 bad input (message on stderr), 2 usage.
#include <filesystem>
#include <fstream>
#include <iostream>
#include <limits>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "quad_policy/config.h"
#include "quad_policy/fixture.h"
#include "quad_policy/npy.h"
#include "quad_policy/policy_decider.h"
#include "quad_policy/torch_policy.h"

namespace {

int Usage() {
  std::cerr
      << "usage: policy_replay --policy FILE --fixture DIR --config policy.yaml --out DIR [--threads N]\n"
         "                     [--trajectories CTRL.npy [--knot-dt S]]\n";
  return 2;
}

void AppendCtrl(const quad_policy::CtrlPoints& c, std::vector<double>* out) {
  for (int i = 0; i < c.rows(); ++i) {
    for (int j = 0; j < 3; ++j) out->push_back(c(i, j));
  }
}

}  // namespace

int main(int argc, char** argv) {
  std::map<std::string, std::string> args;
  for (int i = 1; i < argc; i += 2) {
    const std::string key = argv[i];
    if (key.rfind("--", 0) != 0 || i + 1 >= argc) return Usage();
    args[key.substr(2)] = argv[i + 1];
  }
  for (const char* required : {"policy", "fixture", "config", "out"}) {
    if (!args.count(required)) return Usage();
  }
  try {
    using namespace quad_policy;
    const PolicyNodeConfig cfg = LoadPolicyNodeConfig(args["config"]);
    ConfigureTorchThreads(args.count("threads") ? std::stoi(args["threads"]) : 1);
    auto policy = std::make_shared<const TorchPolicy>(args["policy"]);
    PolicyDecider decider(policy, cfg.safety, cfg.refusal, cfg.recovery, cfg.keeping);
    const DecisionFixture fx = ReadDecisionFixture(args["fixture"]);
    std::filesystem::create_directories(args["out"]);
    const PolicyMeta& m = policy->meta();
    const std::size_t n = fx.frames.size();
    const std::size_t k = static_cast<std::size_t>(m.num_ctrl_pts);
    std::vector<float> depth_x, file_depth_x, state_x, y;
    std::vector<double> ctrl, file_decode, file_forward, safety_value, stop_ctrl, stop_dt, knots;
    std::vector<double> recovery_yaw, recovery_ctrl, final_ctrl, final_dt;
    std::ofstream reasons(args["out"] + "/reason.txt");
    std::vector<int32_t> verdict, sent_kind, recovery_tries, proposed_hypothesis, recovery_hypothesis;
    for (std::size_t i = 0; i < n; ++i) {
      const RecordedFrame& f = fx.frames[i];
      DecisionInputs in;
      in.stamp_s = f.stamp_s;
      in.depth = f.depth.view();
      in.camera = fx.Camera(i);
      in.state = f.state;
      in.goal_world = f.goal_world;
      const Decision d = decider.Decide(in);
      depth_x.insert(depth_x.end(), d.depth_x.begin(), d.depth_x.end());
      const std::vector<float> ref = policy->FilePreprocessDepth(in.depth);
      file_depth_x.insert(file_depth_x.end(), ref.begin(), ref.end());
      state_x.insert(state_x.end(), d.state_x.begin(), d.state_x.end());
      y.insert(y.end(), d.y.begin(), d.y.end());
      AppendCtrl(d.proposed.ctrl_world, &ctrl);
      AppendCtrl(policy->FileDecode(policy->FileSelect(d.y), f.state), &file_decode);
      proposed_hypothesis.push_back(d.proposed_hypothesis);
      recovery_hypothesis.push_back(d.recovery_hypothesis);
      AppendCtrl(policy->FileForward(in.depth, f.state, f.goal_world), &file_forward);
      verdict.push_back(static_cast<int32_t>(d.safety.verdict));
      safety_value.push_back(d.safety.value);
      sent_kind.push_back(static_cast<int32_t>(d.sent_kind()));
      reasons << Summarize(d, m.hypotheses, f.stamp_s).reason << "\n";
      if (d.final_approach) {
        AppendCtrl(d.final_approach->ctrl_world, &final_ctrl);
        final_dt.push_back(d.final_approach->knot_dt_s);
      } else {
        final_ctrl.insert(final_ctrl.end(), 12, 0.0);
        final_dt.push_back(0.0);
      }
      recovery_tries.push_back(d.recovery_tries);
      if (d.recovery) {
        recovery_yaw.push_back(d.recovery_yaw_deg);
        AppendCtrl(d.recovery->ctrl_world, &recovery_ctrl);
      } else {
        recovery_yaw.push_back(std::numeric_limits<double>::quiet_NaN());
        recovery_ctrl.insert(recovery_ctrl.end(), k * 3, 0.0);
      }
      if (d.stop) {
        AppendCtrl(d.stop->ctrl_world, &stop_ctrl);
        stop_dt.push_back(d.stop->knot_dt_s);
      } else {
        stop_ctrl.insert(stop_ctrl.end(), 12, 0.0);
        stop_dt.push_back(0.0);
      }
      if (i == 0) knots = d.proposed.Knots();
      std::cerr << "[policy_replay] frame " << i << ": " << d.safety.reason << "\n";
    }
    const std::string out = args["out"];
    const std::size_t h = static_cast<std::size_t>(m.input_height),
                      w = static_cast<std::size_t>(m.input_width);
    WriteNpy(out + "/depth_x.npy", NpyArray::FromFloat(depth_x, {n, h, w}));
    WriteNpy(out + "/file_depth_x.npy", NpyArray::FromFloat(file_depth_x, {n, h, w}));
    WriteNpy(out + "/state_x.npy", NpyArray::FromFloat(state_x, {n, static_cast<std::size_t>(kStateDim)}));
    WriteNpy(out + "/y.npy", NpyArray::FromFloat(y, {n, static_cast<std::size_t>(m.network_output_dim())}));
    WriteNpy(out + "/proposed_hypothesis.npy", NpyArray::FromInt32(proposed_hypothesis, {n}));
    WriteNpy(out + "/recovery_hypothesis.npy", NpyArray::FromInt32(recovery_hypothesis, {n}));
    WriteNpy(out + "/ctrl_world.npy", NpyArray::FromDouble(ctrl, {n, k, 3}));
    WriteNpy(out + "/file_decode.npy", NpyArray::FromDouble(file_decode, {n, k, 3}));
    WriteNpy(out + "/file_forward.npy", NpyArray::FromDouble(file_forward, {n, k, 3}));
    WriteNpy(out + "/verdict.npy", NpyArray::FromInt32(verdict, {n}));
    WriteNpy(out + "/safety_value.npy", NpyArray::FromDouble(safety_value, {n}));
    WriteNpy(out + "/sent_kind.npy", NpyArray::FromInt32(sent_kind, {n}));
    WriteNpy(out + "/stop_ctrl.npy", NpyArray::FromDouble(stop_ctrl, {n, 4, 3}));
    WriteNpy(out + "/stop_knot_dt.npy", NpyArray::FromDouble(stop_dt, {n}));
    WriteNpy(out + "/recovery_tries.npy", NpyArray::FromInt32(recovery_tries, {n}));
    WriteNpy(out + "/recovery_yaw_deg.npy", NpyArray::FromDouble(recovery_yaw, {n}));
    WriteNpy(out + "/recovery_ctrl.npy", NpyArray::FromDouble(recovery_ctrl, {n, k, 3}));
    WriteNpy(out + "/final_ctrl.npy", NpyArray::FromDouble(final_ctrl, {n, 4, 3}));
    WriteNpy(out + "/final_knot_dt.npy", NpyArray::FromDouble(final_dt, {n}));
    WriteNpy(out + "/knots.npy", NpyArray::FromDouble(knots, {knots.size()}));
    WriteNpy(out + "/has_forward_net.npy", NpyArray::FromInt32({policy->has_forward_net() ? 1 : 0}, {1}));
    if (args.count("trajectories")) {
      const NpyArray t = ReadNpy(args["trajectories"]);
      if (t.shape.size() != 3 || t.shape[0] != n || t.shape[2] != 3) {
        throw std::invalid_argument(args["trajectories"] + ": expected (N frames, K, 3) control points");
      }
      const std::vector<double> c = t.as_double();
      const std::size_t kk = t.shape[1];
      std::vector<int32_t> tv, in_view;
      std::vector<double> tval;
      for (std::size_t i = 0; i < n; ++i) {
        UniformBspline s;
        s.start_time_s = fx.frames[i].stamp_s;
        s.knot_dt_s = args.count("knot-dt") ? std::stod(args["knot-dt"]) : m.knot_dt_s();
        s.ctrl_world.resize(static_cast<int>(kk), 3);
        for (std::size_t r = 0; r < kk; ++r) {
          for (int j = 0; j < 3; ++j) s.ctrl_world(static_cast<int>(r), j) = c[(i * kk + r) * 3 + j];
        }
        const DepthImageView view = fx.frames[i].depth.view();
        const SafetyResult res =
            CheckTrajectory(s, fx.frames[i].state.p_world_body, &view, fx.Camera(i), cfg.safety);
        tv.push_back(static_cast<int32_t>(res.verdict));
        tval.push_back(res.value);
        in_view.push_back(TrajectoryInView(s, fx.Camera(i), cfg.safety) ? 1 : 0);
        std::cerr << "[policy_replay] trajectory " << i << ": " << res.reason << "\n";
      }
      WriteNpy(out + "/traj_verdict.npy", NpyArray::FromInt32(tv, {n}));
      WriteNpy(out + "/traj_value.npy", NpyArray::FromDouble(tval, {n}));
      WriteNpy(out + "/traj_in_view.npy", NpyArray::FromInt32(in_view, {n}));
    }
  } catch (const std::exception& e) {
    std::cerr << "policy_replay: " << e.what() << "\n";
    return 1;
  }
  return 0;
}
