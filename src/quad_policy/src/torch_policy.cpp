// The only translation unit of quad_policy that includes LibTorch (torch/script.h, not torch/torch.h: it
// compiles in about half the time, PLATFORM.md).
#include "quad_policy/torch_policy.h"

#include <ATen/Parallel.h>
#include <malloc.h>
#include <torch/script.h>

#include <stdexcept>
#include <string>
#include <unordered_map>
#include <utility>

namespace quad_policy {

void ConfigureTorchThreads(int num_threads) {
  if (num_threads < 1)
    throw std::invalid_argument("num_threads must be >= 1, got " + std::to_string(num_threads));
  try {
    at::set_num_interop_threads(1);
  } catch (const c10::Error&) {
    // Already set (it may be set once per process, before any inter-op work): keep it.
  }
  at::set_num_threads(num_threads);
}

int TorchThreads() { return at::get_num_threads(); }

void TuneMallocForInference() {
  // 256 MiB: above any buffer of one forward pass, so freed buffers stay in the heap for the next call.
  mallopt(M_MMAP_THRESHOLD, 256 * 1024 * 1024);
  mallopt(M_TRIM_THRESHOLD, 512 * 1024 * 1024);
}

namespace {

at::Tensor Row(const Eigen::Vector3d& v) {
  return torch::tensor({static_cast<float>(v.x()), static_cast<float>(v.y()), static_cast<float>(v.z())},
                       torch::kFloat32)
      .reshape({1, 3});
}

at::Tensor QuatRow(const Eigen::Quaterniond& q) {
  // Exchanged as (x, y, z, w) (docs/CONVENTIONS.md).
  return torch::tensor({static_cast<float>(q.x()), static_cast<float>(q.y()), static_cast<float>(q.z()),
                        static_cast<float>(q.w())},
                       torch::kFloat32)
      .reshape({1, 4});
}

at::Tensor DepthTensor(const DepthImageView& depth) {
  if (depth.data == nullptr || depth.width <= 0 || depth.height <= 0) {
    throw std::invalid_argument("depth image is empty");
  }
  at::Tensor t = torch::empty({1, depth.height, depth.width}, torch::kFloat32);
  float* dst = t.data_ptr<float>();
  for (int r = 0; r < depth.height; ++r) {
    const float* src = depth.data + static_cast<std::size_t>(r) * depth.row_stride;
    std::copy(src, src + depth.width, dst + static_cast<std::size_t>(r) * depth.width);
  }
  return t;
}

CtrlPoints ToCtrl(const at::Tensor& t) {
  const at::Tensor c = t.to(torch::kFloat64).contiguous().reshape({-1, 3});
  CtrlPoints out(c.size(0), 3);
  const double* p = c.data_ptr<double>();
  for (int i = 0; i < c.size(0); ++i) {
    for (int j = 0; j < 3; ++j) out(i, j) = p[3 * i + j];
  }
  return out;
}

std::vector<float> ToVector(const at::Tensor& t) {
  const at::Tensor c = t.to(torch::kFloat32).contiguous().reshape({-1});
  return std::vector<float>(c.data_ptr<float>(), c.data_ptr<float>() + c.numel());
}

}  // namespace

struct TorchPolicy::Impl {
  std::string path;
  std::string json;
  PolicyMeta meta;
  mutable torch::jit::Module module;
  bool has_forward_net = false;
};

TorchPolicy::TorchPolicy(const std::string& path) : impl_(std::make_unique<Impl>()) {
  impl_->path = path;
  std::unordered_map<std::string, std::string> extra{{kPolicyMetaFile, ""}};
  try {
    impl_->module = torch::jit::load(path, torch::kCPU, extra);
  } catch (const c10::Error& e) {
    // Truncated, not a TorchScript archive at all (a text file, a zip of something else), or unreadable.
    throw std::runtime_error(path + ": cannot load the TorchScript policy: " + e.what_without_backtrace());
  } catch (const std::exception& e) {
    throw std::runtime_error(path + ": cannot load the TorchScript policy: " + e.what());
  }
  impl_->json = extra[kPolicyMetaFile];
  if (impl_->json.empty()) {
    throw PolicyFormatError(path + ": not a quad_il policy export (no " + std::string(kPolicyMetaFile) + ")");
  }
  impl_->meta = ParsePolicyMeta(impl_->json, path);
  // The metadata must describe this very file: compare with the attributes the export preserved.
  const PolicyMeta& m = impl_->meta;
  try {
    const auto check = [&](const char* attr, double file_value, double meta_value) {
      if (file_value != meta_value) {
        throw PolicyFormatError(path + ": attribute " + attr + " = " + std::to_string(file_value) +
                                " disagrees with the metadata's " + std::to_string(meta_value));
      }
    };
    check("input_height", impl_->module.attr("input_height").toInt(), m.input_height);
    check("input_width", impl_->module.attr("input_width").toInt(), m.input_width);
    check("max_depth_m", impl_->module.attr("max_depth_m").toDouble(), m.max_depth_m);
    check("num_ctrl_pts", impl_->module.attr("num_ctrl_pts").toInt(), m.num_ctrl_pts);
    check("horizon_s", impl_->module.attr("horizon_s").toDouble(), m.horizon_s);
    // Files from before multiple hypotheses have no such attribute: one plan.
    const int file_hypotheses =
        impl_->module.hasattr("num_hypotheses") ? impl_->module.attr("num_hypotheses").toInt() : 1;
    if (file_hypotheses != m.hypotheses) {
      throw PolicyFormatError(path + ": attribute num_hypotheses = " + std::to_string(file_hypotheses) +
                              " disagrees with the metadata's output.hypotheses " +
                              std::to_string(m.hypotheses));
    }
    const bool file_mean_first =
        impl_->module.hasattr("mean_first") && impl_->module.attr("mean_first").toBool();
    if (file_mean_first != m.mean_first) {
      throw PolicyFormatError(path + ": attribute mean_first = " + (file_mean_first ? "true" : "false") +
                              " disagrees with the metadata's output.hypotheses_first");
    }
  } catch (const PolicyFormatError&) {
    throw;
  } catch (const c10::Error& e) {
    throw PolicyFormatError(path + ": missing policy attribute: " + e.what_without_backtrace());
  } catch (const std::exception& e) {
    // A module without the attribute (torch::jit::ObjectAttributeError is no c10::Error).
    throw PolicyFormatError(path + ": missing policy attribute: " + e.what());
  }
  impl_->has_forward_net = impl_->module.find_method("forward_net").has_value();
  if (!impl_->has_forward_net && !impl_->module.find_method("forward_prepared").has_value()) {
    throw PolicyFormatError(path + ": the file has neither forward_net nor forward_prepared");
  }
}

TorchPolicy::~TorchPolicy() = default;
TorchPolicy::TorchPolicy(TorchPolicy&&) noexcept = default;
TorchPolicy& TorchPolicy::operator=(TorchPolicy&&) noexcept = default;

const PolicyMeta& TorchPolicy::meta() const { return impl_->meta; }
const std::string& TorchPolicy::path() const { return impl_->path; }
const std::string& TorchPolicy::metadata_json() const { return impl_->json; }
bool TorchPolicy::has_forward_net() const { return impl_->has_forward_net; }

void TorchPolicy::WarmUp(int passes) const {
  const PolicyMeta& m = meta();
  const std::vector<float> depth_x(static_cast<std::size_t>(m.input_height) * m.input_width, 0.5f);
  StateVector s{};
  s[9] = 1.0f;  // the identity quaternion's w
  try {
    for (int i = 0; i < passes; ++i) Run(depth_x, s, VehicleState(), Eigen::Vector3d::Zero());
  } catch (const std::exception& e) {
    throw std::runtime_error(path() + ": the policy's forward pass fails on a test input: " + e.what());
  }
}

std::vector<float> TorchPolicy::Run(const std::vector<float>& depth_x, const StateVector& state_x,
                                    const VehicleState& state, const Eigen::Vector3d& goal_world) const {
  const PolicyMeta& m = impl_->meta;
  if (static_cast<int>(depth_x.size()) != m.input_height * m.input_width) {
    throw std::invalid_argument("network depth input has " + std::to_string(depth_x.size()) +
                                " values, expected " + std::to_string(m.input_height * m.input_width));
  }
  c10::InferenceMode guard;
  // from_blob: no copy; the tensors do not outlive this call.
  const at::Tensor depth = torch::from_blob(const_cast<float*>(depth_x.data()),
                                            {1, 1, m.input_height, m.input_width}, torch::kFloat32);
  at::Tensor y;
  if (impl_->has_forward_net) {
    const at::Tensor s =
        torch::from_blob(const_cast<float*>(state_x.data()), {1, kStateDim}, torch::kFloat32);
    y = impl_->module.get_method("forward_net")({depth, s}).toTensor();
  } else {
    y = impl_->module
            .get_method("forward_prepared")({depth, Row(state.p_world_body), Row(state.v_world),
                                             QuatRow(state.q_world_body), Row(goal_world)})
            .toTensor();
  }
  if (y.numel() != m.network_output_dim()) {
    throw std::runtime_error(impl_->path + ": the network returned " + std::to_string(y.numel()) +
                             " values, the metadata declares " + std::to_string(m.network_output_dim()));
  }
  return ToVector(y);
}

std::vector<float> TorchPolicy::RunBatch(const std::vector<float>& depth_x,
                                         const std::vector<StateVector>& state_x,
                                         const std::vector<VehicleState>* states,
                                         const std::vector<Eigen::Vector3d>* goals) const {
  const PolicyMeta& m = impl_->meta;
  const int64_t n = static_cast<int64_t>(state_x.size());
  const int64_t per = static_cast<int64_t>(m.input_height) * m.input_width;
  if (static_cast<int64_t>(depth_x.size()) != n * per) {
    throw std::invalid_argument("batched depth input has " + std::to_string(depth_x.size()) +
                                " values, expected " + std::to_string(n) + " x " + std::to_string(per));
  }
  if (n == 0) return {};
  if (!impl_->has_forward_net) {  // older exports encode the state themselves: one pass per sample
    if (states == nullptr || goals == nullptr || states->size() != state_x.size() ||
        goals->size() != state_x.size()) {
      throw std::logic_error(impl_->path +
                             ": without forward_net a batch needs each sample's state and goal");
    }
    std::vector<float> out;
    out.reserve(static_cast<size_t>(n * m.network_output_dim()));
    for (int64_t i = 0; i < n; ++i) {
      const std::vector<float> d(depth_x.begin() + i * per, depth_x.begin() + (i + 1) * per);
      const std::vector<float> y = Run(d, state_x[static_cast<size_t>(i)], (*states)[static_cast<size_t>(i)],
                                       (*goals)[static_cast<size_t>(i)]);
      out.insert(out.end(), y.begin(), y.end());
    }
    return out;
  }
  c10::InferenceMode guard;
  const at::Tensor depth = torch::from_blob(const_cast<float*>(depth_x.data()),
                                            {n, 1, m.input_height, m.input_width}, torch::kFloat32);
  const at::Tensor s =
      torch::from_blob(const_cast<float*>(state_x.front().data()), {n, kStateDim}, torch::kFloat32);
  const at::Tensor y = impl_->module.get_method("forward_net")({depth, s}).toTensor();
  if (y.numel() != n * m.network_output_dim()) {
    throw std::runtime_error(impl_->path + ": the network returned " + std::to_string(y.numel()) +
                             " values for a batch of " + std::to_string(n) + ", the metadata declares " +
                             std::to_string(m.network_output_dim()) + " per sample");
  }
  return ToVector(y);
}

std::vector<float> TorchPolicy::FilePreprocessDepth(const DepthImageView& depth) const {
  c10::InferenceMode guard;
  return ToVector(impl_->module.get_method("preprocess_depth")({DepthTensor(depth)}).toTensor());
}

CtrlPoints TorchPolicy::FileDecode(const std::vector<float>& y, const VehicleState& state) const {
  c10::InferenceMode guard;
  const at::Tensor yt = torch::tensor(y, torch::kFloat32).reshape({1, -1});
  return ToCtrl(impl_->module.get_method("decode")({yt, Row(state.p_world_body), QuatRow(state.q_world_body)})
                    .toTensor());
}

std::vector<float> TorchPolicy::FileSelect(const std::vector<float>& y) const {
  if (!impl_->module.find_method("select").has_value()) return y;
  c10::InferenceMode guard;
  const at::Tensor yt = torch::tensor(y, torch::kFloat32).reshape({1, -1});
  return ToVector(impl_->module.get_method("select")({yt}).toTensor());
}

CtrlPoints TorchPolicy::FileForward(const DepthImageView& depth, const VehicleState& state,
                                    const Eigen::Vector3d& goal_world) const {
  c10::InferenceMode guard;
  return ToCtrl(impl_->module
                    .forward({DepthTensor(depth), Row(state.p_world_body), Row(state.v_world),
                              QuatRow(state.q_world_body), Row(goal_world)})
                    .toTensor());
}

}  // namespace quad_policy
