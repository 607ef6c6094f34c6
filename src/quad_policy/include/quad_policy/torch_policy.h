// The exported TorchScript policy, loaded with LibTorch. No torch type appears here: the nodes and tools that
// include this header compile as C++17 with the ROS headers (PLATFORM.md), only torch_policy.cpp sees torch.
#pragma once

#include <Eigen/Core>

#include <memory>
#include <string>
#include <vector>

#include "quad_policy/policy_meta.h"
#include "quad_policy/preprocessing.h"

namespace quad_policy {

// Process-wide LibTorch settings, called once at start-up before the first forward pass: intra-op threads
// (inter-op threads are set to 1; a no-op if already set). Throws std::invalid_argument for num_threads < 1.
void ConfigureTorchThreads(int num_threads);
int TorchThreads();

// glibc: raise the mmap and trim thresholds so the forward pass's large temporary buffers are reused instead
// of being mapped and unmapped (and page-faulted) on every call (PLATFORM.md: up to 25 % faster).
void TuneMallocForInference();

class TorchPolicy {
 public:
  // Loads the file and its metadata (`quad_il_policy.json`). Throws PolicyFormatError (not a policy export,
  // unsupported format, bad metadata, metadata disagreeing with the file's attributes) or std::runtime_error
  // (unreadable file).
  explicit TorchPolicy(const std::string& path);
  ~TorchPolicy();
  TorchPolicy(TorchPolicy&&) noexcept;
  TorchPolicy& operator=(TorchPolicy&&) noexcept;
  TorchPolicy(const TorchPolicy&) = delete;
  TorchPolicy& operator=(const TorchPolicy&) = delete;

  const PolicyMeta& meta() const;
  const std::string& path() const;
  const std::string& metadata_json() const;
  // True when the file has `forward_net(depth_x, state_x)` (the network alone): the state vector of
  // EncodeState is then the network's input. Otherwise `forward_prepared(depth_x, p, v, q, goal)` is used and
  // the file encodes the state itself (exports before that method existed).
  bool has_forward_net() const;
  // The first forward passes of a TorchScript module are slower (profiling executor): runs `passes` of them
  // on a neutral input before flying. Throws std::runtime_error naming the file when the forward pass fails
  // (a file whose methods exist but do not take a policy's inputs, issue 30).
  void WarmUp(int passes = 3) const;

  // The network's flat output (training representation) from the preprocessed depth (input_height x
  // input_width) and the state. One sample, InferenceMode. Throws std::invalid_argument on wrong sizes.
  std::vector<float> Run(const std::vector<float>& depth_x, const StateVector& state_x,
                         const VehicleState& state, const Eigen::Vector3d& goal_world) const;

  // One forward pass for a batch (the rollout engine's episodes deciding at the same sim time): depth_x holds
  // n preprocessed depth inputs one after the other, state_x n state vectors (files with forward_net only).
  // Returns n * network_output_dim values, sample by sample. A file without forward_net (older exports) is
  // run once per sample with the samples' odometry and goals (`states`, `goals`; std::logic_error without
  // them). Throws std::invalid_argument on wrong sizes.
  std::vector<float> RunBatch(const std::vector<float>& depth_x, const std::vector<StateVector>& state_x,
                              const std::vector<VehicleState>* states = nullptr,
                              const std::vector<Eigen::Vector3d>* goals = nullptr) const;

  // The file's own preprocessing, decoding and end-to-end forward: references for the parity tests.
  std::vector<float> FilePreprocessDepth(const DepthImageView& depth) const;
  CtrlPoints FileDecode(const std::vector<float>& y, const VehicleState& state) const;
  // The file's choice of the plan flown (its `select`: output_dim values); files without it: y itself.
  std::vector<float> FileSelect(const std::vector<float>& y) const;
  CtrlPoints FileForward(const DepthImageView& depth, const VehicleState& state,
                         const Eigen::Vector3d& goal_world) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace quad_policy
