#include "quad_policy/preprocessing.h"

#include <Eigen/Cholesky>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <stdexcept>
#include <string>

namespace quad_policy {

float RoundToFloat16(float value) {
  // GCC's _Float16 conversion is IEEE round-to-nearest-even with subnormals, as torch's .to(torch.float16).
  return static_cast<float>(static_cast<_Float16>(value));
}

namespace {

// torch's adaptive pooling cell bounds (aten/src/ATen/native/AdaptivePooling.h): [floor(i n / m), ceil((i+1)
// n / m)).
inline int CellStart(int i, int out, int in) {
  return static_cast<int>((static_cast<int64_t>(i) * in) / out);
}
inline int CellEnd(int i, int out, int in) {
  return static_cast<int>(((static_cast<int64_t>(i) + 1) * in + out - 1) / out);
}

inline float Sanitise(float v, float max_depth) {
  // clamp_(0, max) keeps NaN (then nan_to_num -> max); +inf -> max, -inf -> 0.
  if (std::isnan(v)) return max_depth;
  return std::min(std::max(v, 0.0f), max_depth);
}

void CheckFinite(const Eigen::Vector3d& v, const char* name) {
  if (!v.allFinite()) throw std::invalid_argument(std::string(name) + " has a NaN/Inf element");
}

struct QuatF {
  float x, y, z, w;
};

// learning/preprocessing.py _canonical_unit_quaternion, in float.
QuatF Canonical(QuatF q) {
  const float n = std::max(std::sqrt(q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w), 1e-12f);
  const float s = (q.w / n) < 0.0f ? -1.0f : 1.0f;
  return QuatF{q.x / n * s, q.y / n * s, q.z / n * s, q.w / n * s};
}

float YawOfF(const QuatF& q) {
  return std::atan2(2.0f * (q.w * q.z + q.x * q.y), q.w * q.w + q.x * q.x - q.y * q.y - q.z * q.z);
}

QuatF ToQuatF(const Eigen::Quaterniond& q) {
  return QuatF{static_cast<float>(q.x()), static_cast<float>(q.y()), static_cast<float>(q.z()),
               static_cast<float>(q.w())};
}

}  // namespace

std::vector<float> PreprocessDepth(const DepthImageView& depth, int out_height, int out_width,
                                   double max_depth_m) {
  if (depth.data == nullptr || depth.width <= 0 || depth.height <= 0) {
    throw std::invalid_argument("depth image is empty");
  }
  if (depth.row_stride < static_cast<std::size_t>(depth.width)) {
    throw std::invalid_argument("depth image row stride is smaller than its width");
  }
  if (out_height < 1 || out_width < 1) throw std::invalid_argument("network input size must be positive");
  if (!(std::isfinite(max_depth_m) && max_depth_m > 0.0))
    throw std::invalid_argument("max_depth_m must be > 0");
  const float max_depth = static_cast<float>(max_depth_m);
  std::vector<int> col0(out_width), col1(out_width);
  for (int j = 0; j < out_width; ++j) {
    col0[j] = CellStart(j, out_width, depth.width);
    col1[j] = CellEnd(j, out_width, depth.width);
  }
  std::vector<float> out(static_cast<std::size_t>(out_height) * out_width);
  for (int i = 0; i < out_height; ++i) {
    const int r0 = CellStart(i, out_height, depth.height);
    const int r1 = CellEnd(i, out_height, depth.height);
    const int64_t kh = r1 - r0;
    for (int j = 0; j < out_width; ++j) {
      const int64_t kw = col1[j] - col0[j];
      // Float accumulation in row-major order, then / kh / kw: the order and precision of torch's CPU kernel
      // (cpu_adaptive_avg_pool2d), so the result is bit-identical to the file's preprocess_depth.
      float sum = 0.0f;
      for (int r = r0; r < r1; ++r) {
        const float* row = depth.data + static_cast<std::size_t>(r) * depth.row_stride;
        for (int c = col0[j]; c < col1[j]; ++c) sum += Sanitise(row[c], max_depth);
      }
      const float mean = sum / static_cast<float>(kh) / static_cast<float>(kw);
      out[static_cast<std::size_t>(i) * out_width + j] = RoundToFloat16(mean / max_depth);
    }
  }
  return out;
}

double YawOf(const Eigen::Quaterniond& q) {
  return std::atan2(2.0 * (q.w() * q.z() + q.x() * q.y()),
                    q.w() * q.w() + q.x() * q.x() - q.y() * q.y() - q.z() * q.z());
}

StateVector EncodeState(const VehicleState& state, const Eigen::Vector3d& goal_world,
                        const PolicyMeta& meta) {
  CheckFinite(state.p_world_body, "p_world_body");
  CheckFinite(state.v_world, "v_world");
  CheckFinite(goal_world, "goal_world");
  if (!state.q_world_body.coeffs().allFinite())
    throw std::invalid_argument("q_world_body has a NaN/Inf element");
  if (state.q_world_body.coeffs().squaredNorm() < 1e-24) throw std::invalid_argument("q_world_body is zero");
  const Eigen::Vector3f p = state.p_world_body.cast<float>();
  const Eigen::Vector3f g = goal_world.cast<float>();
  const float sp = static_cast<float>(meta.position_scale_m);
  const float sv = static_cast<float>(meta.velocity_scale_mps);
  const Eigen::Vector3f v =
      meta.velocity_input ? Eigen::Vector3f(state.v_world.cast<float>()) : Eigen::Vector3f::Zero();
  const QuatF q = Canonical(ToQuatF(state.q_world_body));
  StateVector s{};
  if (meta.state_frame == PolicyFrame::kWorld) {
    s = {p.x() / sp, p.y() / sp, p.z() / sp, v.x() / sv, v.y() / sv, v.z() / sv, q.x,
         q.y,        q.z,        q.w,        g.x() / sp, g.y() / sp, g.z() / sp};
    return s;
  }
  const float yaw = YawOfF(q);
  const float c = std::cos(yaw);
  const float sn = std::sin(yaw);
  const float vx = c * v.x() + sn * v.y();
  const float vy = -sn * v.x() + c * v.y();
  const float dx = g.x() - p.x();
  const float dy = g.y() - p.y();
  const float dz = g.z() - p.z();
  const float gx = c * dx + sn * dy;
  const float gy = -sn * dx + c * dy;
  // q_local = q_yaw^-1 * q (Hamilton product, xyzw), q_yaw^-1 = (0, 0, -sin(yaw/2), cos(yaw/2)).
  const float ch = std::cos(0.5f * yaw);
  const float sh = std::sin(0.5f * yaw);
  const QuatF ql =
      Canonical(QuatF{ch * q.x + sh * q.y, ch * q.y - sh * q.x, ch * q.z - sh * q.w, ch * q.w + sh * q.z});
  s = {0.0f / sp, 0.0f / sp, p.z() / sp, vx / sv, vy / sv, v.z() / sv, ql.x,
       ql.y,      ql.z,      ql.w,       gx / sp, gy / sp, dz / sp};
  return s;
}

Eigen::MatrixXd UniformCubicBasis(int num_ctrl_pts, int num_samples) {
  if (num_ctrl_pts < 4) throw std::invalid_argument("a cubic B-spline needs num_ctrl_pts >= 4");
  if (num_samples < 2) throw std::invalid_argument("num_samples must be >= 2");
  // p(u) = [1 u u^2 u^3] M [c_k .. c_k+3]^T (Qin 2000), as learning/preprocessing.py _CUBIC_M.
  Eigen::Matrix4d m;
  m << 1, 4, 1, 0, -3, 0, 3, 0, 3, -6, 3, 0, -1, 3, -3, 1;
  m /= 6.0;
  const int segments = num_ctrl_pts - 3;
  Eigen::MatrixXd a = Eigen::MatrixXd::Zero(num_samples, num_ctrl_pts);
  for (int j = 0; j < num_samples; ++j) {
    const double x = static_cast<double>(segments) * j / (num_samples - 1);
    const int k = std::min(static_cast<int>(std::floor(x)), segments - 1);
    const double u = x - k;
    const Eigen::RowVector4d w = Eigen::RowVector4d(1.0, u, u * u, u * u * u) * m;
    for (int i = 0; i < 4; ++i) a(j, k + i) = w(i);
  }
  return a;
}

Eigen::MatrixXd PolynomialDecodeMatrix(int num_ctrl_pts, int degree) {
  if (degree < 1) throw std::invalid_argument("poly_degree must be >= 1");
  const int num_samples = 16 * (num_ctrl_pts - 3) + 1;
  if (degree + 1 > num_samples) throw std::invalid_argument("poly_degree is too high for the control points");
  const Eigen::MatrixXd a = UniformCubicBasis(num_ctrl_pts, num_samples);
  Eigen::MatrixXd t(num_samples, degree + 1);
  for (int j = 0; j < num_samples; ++j) {
    const double tau = -1.0 + 2.0 * j / (num_samples - 1);
    double pw = 1.0;
    for (int d = 0; d <= degree; ++d) {
      t(j, d) = pw;
      pw *= tau;
    }
  }
  // D = pinv(A) T: A (a B-spline collocation matrix with more samples than control points) has full column
  // rank, so pinv(A) T is the least-squares solution of A D = T: the normal equations, A^T A being small,
  // symmetric positive definite and well conditioned (uniform cubic basis functions overlap little).
  return (a.transpose() * a).ldlt().solve(a.transpose() * t);
}

OutputDecoder::OutputDecoder(const PolicyMeta& meta) : meta_(meta) {
  if (meta.num_ctrl_pts < 4) throw std::invalid_argument("the policy must have at least 4 control points");
  if (meta.representation == OutputRepresentation::kPolynomial) {
    poly_decode_ = PolynomialDecodeMatrix(meta.num_ctrl_pts, meta.poly_degree);
  }
}

std::vector<HypothesisPlan> OrderedPlans(const std::vector<float>& y, const PolicyMeta& meta) {
  const int d = meta.output_dim();
  const int m = meta.hypotheses;
  if (static_cast<int>(y.size()) != meta.network_output_dim()) {
    throw std::invalid_argument("network output has " + std::to_string(y.size()) +
                                " values, the policy declares " + std::to_string(meta.network_output_dim()));
  }
  if (m == 1) return {HypothesisPlan{0, y}};
  std::vector<int> order(m);
  std::iota(order.begin(), order.end(), 0);
  const float* logits = y.data() + static_cast<std::size_t>(m) * d;
  // A strict weak order even with NaN: NaN logits rank after every number, then by index. With mean_first
  // plan 0 stays first.
  std::stable_sort(order.begin() + (meta.mean_first ? 1 : 0), order.end(), [logits](int a, int b) {
    const bool na = std::isnan(logits[a]), nb = std::isnan(logits[b]);
    if (na != nb) return nb;
    return !na && logits[a] > logits[b];
  });
  std::vector<HypothesisPlan> out;
  out.reserve(m);
  for (int i : order) {
    const auto first = y.begin() + static_cast<std::ptrdiff_t>(i) * d;
    out.push_back(HypothesisPlan{i, std::vector<float>(first, first + d)});
  }
  return out;
}

CtrlPoints OutputDecoder::Decode(const std::vector<float>& y, const VehicleState& state) const {
  if (static_cast<int>(y.size()) != meta_.output_dim()) {
    throw std::invalid_argument("network output has " + std::to_string(y.size()) +
                                " values, the policy declares " + std::to_string(meta_.output_dim()));
  }
  const int k = meta_.num_ctrl_pts;
  Eigen::Matrix<float, Eigen::Dynamic, 3> pts(k, 3);
  if (meta_.representation == OutputRepresentation::kPolynomial) {
    Eigen::Matrix<double, Eigen::Dynamic, 3> coeffs(meta_.poly_degree + 1, 3);
    for (int r = 0; r <= meta_.poly_degree; ++r) {
      for (int c = 0; c < 3; ++c) coeffs(r, c) = y[3 * r + c];
    }
    pts = (poly_decode_ * coeffs).cast<float>();
  } else {
    for (int r = 0; r < k; ++r) {
      for (int c = 0; c < 3; ++c) pts(r, c) = y[3 * r + c];
    }
  }
  if (meta_.output_frame == PolicyFrame::kLocal) {
    // local_to_world_points with the yaw of the raw quaternion, in float as the reference.
    const Eigen::Vector3f p = state.p_world_body.cast<float>();
    const float yaw = YawOfF(ToQuatF(state.q_world_body));
    const float c = std::cos(yaw);
    const float s = std::sin(yaw);
    for (int r = 0; r < k; ++r) {
      const float lx = pts(r, 0);
      const float ly = pts(r, 1);
      pts(r, 0) = c * lx - s * ly + p.x();
      pts(r, 1) = s * lx + c * ly + p.y();
      pts(r, 2) = pts(r, 2) + p.z();
    }
  }
  return pts.cast<double>();
}

}  // namespace quad_policy
