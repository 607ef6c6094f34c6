#include "quad_engine/policy_vec.h"

#include <stdexcept>

namespace quad_engine {
namespace {

// The rows of one batched forward pass.
struct Batch {
  std::vector<float> depth;
  std::vector<quad_policy::StateVector> states;
  std::vector<quad_core::VehicleState> odometry;
  std::vector<Eigen::Vector3d> goals;

  void Clear() {
    depth.clear();
    states.clear();
    odometry.clear();
    goals.clear();
  }
  // The request's own decision.
  void Add(const DecisionRequest& r) {
    depth.insert(depth.end(), r.depth_x.begin(), r.depth_x.end());
    states.push_back(r.state_x);
    odometry.push_back(r.state);
    goals.push_back(r.goal_world);
  }
  // The request's frame with another goal (a recovery turn).
  void Add(const DecisionRequest& r, const Eigen::Vector3d& goal, const quad_policy::PolicyMeta& m) {
    depth.insert(depth.end(), r.depth_x.begin(), r.depth_x.end());
    states.push_back(quad_policy::EncodeState(r.state, goal, m));
    odometry.push_back(r.state);
    goals.push_back(goal);
  }
};

// The goals the recovery of episode `e` turns to from the request's state, in its order.
std::vector<Eigen::Vector3d> TurnedGoals(const PolicyEpisode& e, const DecisionRequest& r) {
  std::vector<Eigen::Vector3d> goals;
  for (double yaw : e.recovery_yaws_deg())
    goals.push_back(quad_policy::TurnedGoal(r.state.p_world_body, r.goal_world, yaw));
  return goals;
}

}  // namespace

PolicyVec::PolicyVec(const Configs& configs, const quad_policy::PolicyNodeConfig& policy,
                     const quad_policy::PolicyMeta& meta, int num_slots, bool with_labeller) {
  if (num_slots < 1)
    throw std::invalid_argument("PolicyVec: num_slots " + std::to_string(num_slots) + " < 1");
  for (int i = 0; i < num_slots; ++i)
    slots_.push_back(std::make_unique<PolicyEpisode>(configs, policy, meta, with_labeller));
}

PolicyVec::PolicyVec(const Configs& configs, int num_slots) {
  if (num_slots < 1)
    throw std::invalid_argument("PolicyVec: num_slots " + std::to_string(num_slots) + " < 1");
  for (int i = 0; i < num_slots; ++i) slots_.push_back(std::make_unique<PolicyEpisode>(configs));
}

void PolicyVec::RunExpert(const std::vector<EpisodeSpec>& specs, const EvalLimits& limits,
                          const OnDone& on_done) {
  for (size_t k = 0; k < specs.size(); ++k) {
    PolicyEpisode& e = *slots_[k % slots_.size()];
    e.Reset(specs[k], limits);
    while (e.Advance()) {
      throw std::logic_error("PolicyVec::RunExpert: the expert controller asked for a policy decision");
    }
    on_done(k, e);
  }
}

std::vector<int> PolicyVec::AdvanceAll() {
  std::vector<int> waiting;
  for (int i = 0; i < size(); ++i) {
    PolicyEpisode& e = *slots_[static_cast<size_t>(i)];
    if (e.done()) continue;
    if (e.Advance()) waiting.push_back(i);
  }
  return waiting;
}

void PolicyVec::RunTorch(const quad_policy::TorchPolicy& policy, const std::vector<EpisodeSpec>& specs,
                         const EvalLimits& limits, const OnDone& on_done) {
  const quad_policy::PolicyMeta& m = policy.meta();
  std::vector<long> running(slots_.size(), -1);           // the spec index each slot flies, -1: none
  std::vector<uint8_t> recovered_last(slots_.size(), 0);  // the slot's previous decision ran the recovery
  size_t next = 0;
  auto refill = [&] {
    for (size_t s = 0; s < slots_.size(); ++s) {
      while (running[s] < 0 && next < specs.size()) {
        slots_[s]->Reset(specs[next], limits);
        running[s] = static_cast<long>(next++);
        recovered_last[s] = 0;
        if (slots_[s]->done()) {  // a refused reset
          on_done(static_cast<size_t>(running[s]), *slots_[s]);
          running[s] = -1;
        }
      }
    }
  };
  refill();
  Batch batch;
  while (true) {
    bool any = false;
    for (long r : running) any = any || r >= 0;
    if (!any) break;
    std::vector<int> waiting;
    for (size_t s = 0; s < slots_.size(); ++s) {
      if (running[s] < 0) continue;
      if (slots_[s]->Advance()) {
        waiting.push_back(static_cast<int>(s));
      } else {
        on_done(static_cast<size_t>(running[s]), *slots_[s]);
        running[s] = -1;
      }
    }
    if (!waiting.empty()) {
      batch.Clear();
      for (int s : waiting) batch.Add(slots_[static_cast<size_t>(s)]->request());
      // Refusals come in runs (a vehicle stuck in front of a box is refused again): the turned goals of a
      // slot whose previous decision ran the recovery join this pass, rows after the decisions' own.
      std::vector<std::vector<std::pair<Eigen::Vector3d, size_t>>> turned(waiting.size());
      for (size_t j = 0; j < waiting.size(); ++j) {
        const size_t s = static_cast<size_t>(waiting[j]);
        if (!recovered_last[s]) continue;
        const DecisionRequest& r = slots_[s]->request();
        for (const Eigen::Vector3d& g : TurnedGoals(*slots_[s], r)) {
          turned[j].emplace_back(g, batch.goals.size());
          batch.Add(r, g, m);
        }
        ++speculated_decisions_;
      }
      const std::vector<float> y = policy.RunBatch(batch.depth, batch.states, &batch.odometry, &batch.goals);
      ++forward_passes_;
      batched_decisions_ += waiting.size();
      const size_t dim = static_cast<size_t>(m.network_output_dim());
      auto row = [&](const std::vector<float>& ys, size_t i) {
        return std::vector<float>(ys.begin() + i * dim, ys.begin() + (i + 1) * dim);
      };
      for (size_t j = 0; j < waiting.size(); ++j) {
        const size_t slot = static_cast<size_t>(waiting[j]);
        PolicyEpisode& e = *slots_[slot];
        const DecisionRequest req = e.request();
        // The recovery asks for the turned goals one after the other until one is accepted: they are answered
        // from this pass's rows, or else by one batched pass over all of them at the first question (a cache
        // keyed by the goal).
        std::vector<std::pair<Eigen::Vector3d, std::vector<float>>> answers;
        for (const auto& [g, i] : turned[j]) answers.emplace_back(g, row(y, i));
        bool asked = false;
        auto ask = [&, req](const Eigen::Vector3d& goal) {
          asked = true;
          if (answers.empty()) {
            Batch fallback;
            fallback.Add(req, goal, m);
            for (const Eigen::Vector3d& g : TurnedGoals(e, req)) {
              if (g != goal) fallback.Add(req, g, m);
            }
            const std::vector<float> ys =
                policy.RunBatch(fallback.depth, fallback.states, &fallback.odometry, &fallback.goals);
            ++recovery_passes_;
            for (size_t g = 0; g < fallback.goals.size(); ++g)
              answers.emplace_back(fallback.goals[g], row(ys, g));
          }
          for (const auto& [g, a] : answers) {
            if (g == goal) return a;
          }
          ++recovery_passes_;  // a goal the batch did not hold (not one of the configured turns)
          return policy.Run(req.depth_x, quad_policy::EncodeState(req.state, goal, m), req.state, goal);
        };
        e.Decide(row(y, j), ask);
        recovered_last[slot] = asked ? 1 : 0;
      }
    }
    refill();
  }
}

}  // namespace quad_engine
