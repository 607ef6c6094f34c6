// The interface parameters of an exported quad_il policy (issue 7's `policy.ts`), read from the JSON file
// `quad_il_policy.json` stored inside it. Everything the inference nodes do around the network (depth
// preprocessing, state vector, output decoding, B-spline layout) is driven by these values, in C++ and in
// Python, so a policy trained with other settings runs without code changes (docs/inference.md).
#pragma once

#include <stdexcept>
#include <string>

namespace quad_policy {

inline constexpr const char* kPolicyMetaFile = "quad_il_policy.json";
inline constexpr const char* kPolicyMetaFormat = "quad_il_policy/1";
// The B-spline layout of the dataset and of the policy's output (docs/data_format.md): uniform, cubic.
inline constexpr int kPolicyBsplineOrder = 3;
// (position 3, velocity 3, quaternion xyzw 4, goal 3): learning/preprocessing.py STATE_DIM.
inline constexpr int kStateDim = 13;
// model.hypotheses' bound (learning/config.py).
inline constexpr int kMaxHypotheses = 8;

// An exported policy file is unusable; what() names the file and the key or problem.
class PolicyFormatError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

enum class PolicyFrame { kWorld, kLocal };
enum class OutputRepresentation { kBspline, kPolynomial };
const char* ToString(PolicyFrame frame);
const char* ToString(OutputRepresentation representation);

struct PolicyMeta {
  // preprocessing
  int input_height = 0;
  int input_width = 0;
  double max_depth_m = 0.0;
  PolicyFrame state_frame = PolicyFrame::kWorld;
  double position_scale_m = 1.0;
  double velocity_scale_mps = 1.0;
  bool velocity_input = true;  // false: the state's velocity entries are zero (preprocessing.velocity_input)
  // output
  int num_ctrl_pts = 0;
  double horizon_s = 0.0;
  PolicyFrame output_frame = PolicyFrame::kWorld;
  OutputRepresentation representation = OutputRepresentation::kBspline;
  int poly_degree = 0;  // used with kPolynomial only
  int hypotheses = 1;   // plans per forward pass (output.hypotheses; files without the key: 1)
  // Plan 0 (the regression) first, the others by logit (output.hypotheses_first "mean"); false: all by logit
  // ("confidence", and files without the key).
  bool mean_first = false;

  // Knot interval of the uniform cubic B-spline: horizon_s / (K - 3).
  double knot_dt_s() const { return horizon_s / (num_ctrl_pts - kPolicyBsplineOrder); }
  // Length of one plan: 3 K (bspline) or 3 (degree + 1) (polynomial); what OutputDecoder::Decode takes.
  int output_dim() const;
  // Length of the network's flat output: one plan, or M plans followed by their M confidence logits.
  int network_output_dim() const;
};

// Parses and validates the metadata (JSON). Throws PolicyFormatError naming `source` and the missing or bad
// key.
PolicyMeta ParsePolicyMeta(const std::string& json_text, const std::string& source);

}  // namespace quad_policy
