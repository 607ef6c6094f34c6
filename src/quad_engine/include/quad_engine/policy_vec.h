// N policy episodes stepped side by side (issue 32): every episode waiting for a decision at the same time is
// answered by one batched forward pass, either LibTorch's (RunTorch, all in C++) or the caller's (Python:
// Advance, the requests, Decide: quad_il.engine.policy and the Gymnasium environments).
#pragma once

#include <quad_policy/torch_policy.h>

#include <functional>
#include <memory>
#include <vector>

#include "quad_engine/policy_worker.h"

namespace quad_engine {

class PolicyVec {
 public:
  PolicyVec(const Configs& configs, const quad_policy::PolicyNodeConfig& policy,
            const quad_policy::PolicyMeta& meta, int num_slots, bool with_labeller);

  // num_slots expert controllers (the expert's evaluation on the engine; see RunExpert).
  PolicyVec(const Configs& configs, int num_slots);

  int size() const { return static_cast<int>(slots_.size()); }
  PolicyEpisode& slot(int i) { return *slots_.at(static_cast<size_t>(i)); }

  // Advances every slot that is neither done nor waiting to its next decision; returns the slots waiting.
  std::vector<int> AdvanceAll();

  // Flies `specs` with the LibTorch policy: each slot takes the next episode when its episode ends; each
  // round the waiting slots are answered by one RunBatch. The recovery's turned goals join that batch for the
  // slots whose previous decision ran the recovery, and are otherwise asked in one pass per refused decision.
  // on_done is called with each finished episode's index in `specs` and its result (and labels) as it ends.
  using OnDone = std::function<void(size_t spec_index, PolicyEpisode& episode)>;
  void RunTorch(const quad_policy::TorchPolicy& policy, const std::vector<EpisodeSpec>& specs,
                const EvalLimits& limits, const OnDone& on_done);

  // Flies `specs` with the expert controllers, one episode per slot at a time.
  void RunExpert(const std::vector<EpisodeSpec>& specs, const EvalLimits& limits, const OnDone& on_done);

  // Statistics of RunTorch: batched forward passes and the decisions they answered; the recovery's passes
  // outside the round's batch (one batch of every turned goal per refused decision that asks); the decisions
  // whose turned goals were answered in the round's batch.
  uint64_t forward_passes() const { return forward_passes_; }
  uint64_t batched_decisions() const { return batched_decisions_; }
  uint64_t recovery_passes() const { return recovery_passes_; }
  uint64_t speculated_decisions() const { return speculated_decisions_; }

 private:
  std::vector<std::unique_ptr<PolicyEpisode>> slots_;
  uint64_t forward_passes_ = 0, batched_decisions_ = 0, recovery_passes_ = 0, speculated_decisions_ = 0;
};

}  // namespace quad_engine
