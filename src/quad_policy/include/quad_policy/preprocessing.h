// The exported policy's preprocessing and output decoding, implemented in C++ from the parameters stored in
// the file (PolicyMeta). The reference is the training code,
// src/quad_il/src/quad_il/learning/preprocessing.py (DepthPreprocessor, StateEncoder, OutputCodec), whose
// preprocessing the Python node runs; tests/python/test_inference_parity.py requires this code to give the
// same depth input bit for bit, the same state vector and the same control points within 1e-4.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <array>
#include <cstddef>
#include <vector>

#include <quad_core/depth_image.h>
#include <quad_core/vehicle_state.h>

#include "quad_policy/policy_meta.h"

namespace quad_policy {

// The shared vocabulary (quad_core): depth images in metres (REP 118) and the vehicle's odometry.
using quad_core::DepthImage;
using quad_core::DepthImageView;
using quad_core::VehicleState;

using StateVector = std::array<float, kStateDim>;
// World-frame control points, one per row.
using CtrlPoints = Eigen::Matrix<double, Eigen::Dynamic, 3>;

// IEEE binary16 round-to-nearest-even of a float, back as a float (the training cache's precision).
float RoundToFloat16(float value);

// Depth -> network input (out_height x out_width, row-major) exactly as DepthPreprocessor: NaN and +inf ->
// max_depth_m, -inf -> 0, clamp to [0, max_depth_m]; area resize as torch's adaptive_avg_pool2d (cells
// [floor(i H / h), ceil((i + 1) H / h)), float sum in row-major order, then / rows / cols); / max_depth_m in
// float; rounded to float16. Bit-identical to the file's preprocess_depth. Throws std::invalid_argument on an
// empty image or bad sizes.
std::vector<float> PreprocessDepth(const DepthImageView& depth, int out_height, int out_width,
                                   double max_depth_m);

// The 13-value state vector of StateEncoder (float32 arithmetic as the reference): world frame
// [p / s_p, v / s_v, q, goal / s_p]; local frame [(0, 0, z) / s_p, R^T v / s_v, q without yaw, R^T (goal - p)
// / s_p], R = R_z(yaw); quaternions normalised with w >= 0. Throws std::invalid_argument on non-finite input
// or a zero quaternion.
StateVector EncodeState(const VehicleState& state, const Eigen::Vector3d& goal_world, const PolicyMeta& meta);

// Yaw (rad) of a quaternion as learning/preprocessing.py: atan2(2 (w z + x y), w^2 + x^2 - y^2 - z^2).
double YawOf(const Eigen::Quaterniond& q);

// Network output (training representation) -> world-frame control points (K x 3), as OutputCodec.decode: for
// the polynomial representation the fixed least-squares map D = pinv(A) T (computed here in double, as the
// reference computes it), then the local -> world transform for the local output frame.
class OutputDecoder {
 public:
  explicit OutputDecoder(const PolicyMeta& meta);
  // Throws std::invalid_argument when y has the wrong length.
  CtrlPoints Decode(const std::vector<float>& y, const VehicleState& state) const;
  const Eigen::MatrixXd& polynomial_decode_matrix() const { return poly_decode_; }

 private:
  PolicyMeta meta_;
  Eigen::MatrixXd poly_decode_;  // K x (degree + 1), empty for the B-spline representation
};

// One plan of the network's output: the hypothesis' index and its output_dim values.
struct HypothesisPlan {
  int index = 0;
  std::vector<float> y;
};

// The network's flat output (network_output_dim values) -> its plans, most confident first: the largest
// logit, equal logits in index order (as the file's `select`), NaN logits last; with meta.mean_first plan 0
// first and the others after it in that order; one plan: {0, y}. The Python `ordered_plans` makes the same
// order. Throws std::invalid_argument when y has the wrong length.
std::vector<HypothesisPlan> OrderedPlans(const std::vector<float>& y, const PolicyMeta& meta);

// The matrices of learning/preprocessing.py: uniform_cubic_basis (S x K) and the decode map pinv(A) T.
Eigen::MatrixXd UniformCubicBasis(int num_ctrl_pts, int num_samples);
Eigen::MatrixXd PolynomialDecodeMatrix(int num_ctrl_pts, int degree);

}  // namespace quad_policy
