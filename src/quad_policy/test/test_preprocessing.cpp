// Preprocessing and decoding against closed forms. Bit-exactness against the exported file (torch) is checked
// by tests/python/test_inference_parity.py, which runs policy_replay.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>

#include "quad_policy/preprocessing.h"
#include "quad_policy/trajectory.h"

namespace quad_policy {
namespace {

constexpr float kInf = std::numeric_limits<float>::infinity();
constexpr float kNan = std::numeric_limits<float>::quiet_NaN();

PolicyMeta Meta(PolicyFrame state_frame, PolicyFrame output_frame, OutputRepresentation rep) {
  PolicyMeta m;
  m.input_height = 8;
  m.input_width = 8;
  m.max_depth_m = 10.0;
  m.state_frame = state_frame;
  m.position_scale_m = 10.0;
  m.velocity_scale_mps = 3.0;
  m.num_ctrl_pts = 10;
  m.horizon_s = 2.0;
  m.output_frame = output_frame;
  m.representation = rep;
  m.poly_degree = 5;
  return m;
}

TEST(RoundToFloat16, MatchesIeeeHalfPrecision) {
  EXPECT_EQ(RoundToFloat16(1.0f), 1.0f);
  EXPECT_EQ(RoundToFloat16(0.1f), 0.0999755859375f);  // nearest half to 0.1
  // 1 + 2^-11 lies halfway between 1 and 1 + 2^-10: ties go to even (1).
  EXPECT_EQ(RoundToFloat16(1.0f + std::ldexp(1.0f, -11)), 1.0f);
  EXPECT_EQ(RoundToFloat16(1.0f + 3.0f * std::ldexp(1.0f, -11)), 1.0f + std::ldexp(1.0f, -9));
  // Subnormal halves are multiples of 2^-24.
  EXPECT_EQ(RoundToFloat16(1e-6f), 17.0f * std::ldexp(1.0f, -24));
  EXPECT_EQ(RoundToFloat16(0.0f), 0.0f);
}

TEST(PreprocessDepth, IntegerFactorIsTheBlockMeanOverMaxDepth) {
  DepthImage img;
  img.width = 4;
  img.height = 4;
  img.depth_m = {1, 2, 3, 4,  //
                 5, 6, 7, 8,  //
                 1, 1, 2, 2,  //
                 1, 1, 2, 2};
  const std::vector<float> x = PreprocessDepth(img.view(), 2, 2, 10.0);
  ASSERT_EQ(x.size(), 4u);
  EXPECT_EQ(x[0], RoundToFloat16(3.5f / 10.0f));
  EXPECT_EQ(x[1], RoundToFloat16(5.5f / 10.0f));
  EXPECT_EQ(x[2], RoundToFloat16(1.0f / 10.0f));
  EXPECT_EQ(x[3], RoundToFloat16(2.0f / 10.0f));
}

TEST(PreprocessDepth, Rep118SpecialsAndRangeAreMappedBeforeAveraging) {
  DepthImage img;
  img.width = 6;
  img.height = 1;
  // +inf (no return) and NaN -> max; -inf (too near) and negatives -> 0; beyond max -> max.
  img.depth_m = {kInf, kNan, -kInf, -2.0f, 25.0f, 5.0f};
  const std::vector<float> x = PreprocessDepth(img.view(), 1, 6, 10.0);
  const std::vector<float> expected = {1.0f, 1.0f, 0.0f, 0.0f, 1.0f, 0.5f};
  for (int i = 0; i < 6; ++i) EXPECT_EQ(x[i], expected[i]) << "pixel " << i;
}

TEST(PreprocessDepth, NonDivisibleSizesUseTorchsOverlappingCells) {
  // 5 columns -> 2: cells [floor(0), ceil(2.5)) = [0, 3) and [floor(2.5), ceil(5)) = [2, 5): column 2 is in
  // both.
  DepthImage img;
  img.width = 5;
  img.height = 1;
  img.depth_m = {1, 2, 3, 4, 5};
  const std::vector<float> x = PreprocessDepth(img.view(), 1, 2, 10.0);
  EXPECT_EQ(x[0], RoundToFloat16(2.0f / 10.0f));
  EXPECT_EQ(x[1], RoundToFloat16(4.0f / 10.0f));
}

TEST(PreprocessDepth, HonoursTheRowStride) {
  const std::vector<float> padded = {1, 3, 99, 99,  //
                                     5, 7, 99, 99};
  const DepthImageView view{2, 2, 4, padded.data()};
  const std::vector<float> x = PreprocessDepth(view, 1, 1, 10.0);
  EXPECT_EQ(x[0], RoundToFloat16(0.4f));
}

TEST(PreprocessDepth, RejectsEmptyImagesAndBadSizes) {
  DepthImage empty;
  EXPECT_THROW(PreprocessDepth(empty.view(), 8, 8, 10.0), std::invalid_argument);
  DepthImage img;
  img.width = 2;
  img.height = 2;
  img.depth_m = {1, 1, 1, 1};
  EXPECT_THROW(PreprocessDepth(img.view(), 0, 8, 10.0), std::invalid_argument);
  try {
    PreprocessDepth(img.view(), 2, 2, 0.0);
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("max_depth_m"), std::string::npos);
  }
}

TEST(EncodeState, WorldFrameScalesPositionVelocityGoalAndKeepsTheQuaternion) {
  const PolicyMeta m = Meta(PolicyFrame::kWorld, PolicyFrame::kWorld, OutputRepresentation::kBspline);
  VehicleState s;
  s.p_world_body = Eigen::Vector3d(1.0, -2.0, 1.5);
  s.v_world = Eigen::Vector3d(3.0, 0.0, -1.5);
  s.q_world_body = Eigen::Quaterniond(Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitZ()));
  const StateVector x = EncodeState(s, Eigen::Vector3d(20.0, 5.0, 2.0), m);
  const std::array<float, 13> expected = {0.1f,
                                          -0.2f,
                                          0.15f,
                                          1.0f,
                                          0.0f,
                                          -0.5f,
                                          0.0f,
                                          0.0f,
                                          static_cast<float>(std::sin(0.15)),
                                          static_cast<float>(std::cos(0.15)),
                                          2.0f,
                                          0.5f,
                                          0.2f};
  for (int i = 0; i < 13; ++i) EXPECT_NEAR(x[i], expected[i], 1e-6) << "element " << i;
}

TEST(EncodeState, QuaternionIsNormalisedWithNonNegativeW) {
  const PolicyMeta m = Meta(PolicyFrame::kWorld, PolicyFrame::kWorld, OutputRepresentation::kBspline);
  VehicleState s;
  s.q_world_body = Eigen::Quaterniond(-2.0, 0.0, 0.0, 0.0);  // -identity, not unit
  const StateVector x = EncodeState(s, Eigen::Vector3d::Zero(), m);
  EXPECT_FLOAT_EQ(x[9], 1.0f);
  EXPECT_FLOAT_EQ(x[6], 0.0f);
}

TEST(EncodeState, LocalFrameRotatesByTheYawOnly) {
  const PolicyMeta m = Meta(PolicyFrame::kLocal, PolicyFrame::kWorld, OutputRepresentation::kBspline);
  VehicleState s;
  s.p_world_body = Eigen::Vector3d(1.0, 1.0, 2.0);
  s.v_world = Eigen::Vector3d(0.0, 3.0, 0.3);  // along the heading (yaw 90 deg)
  const double roll = 0.2;
  s.q_world_body = Eigen::Quaterniond(Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitZ()) *
                                      Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitX()));
  const Eigen::Vector3d goal(1.0, 11.0, 2.0);  // 10 m ahead
  const StateVector x = EncodeState(s, goal, m);
  EXPECT_NEAR(x[0], 0.0, 1e-7);
  EXPECT_NEAR(x[1], 0.0, 1e-7);
  EXPECT_NEAR(x[2], 0.2, 1e-6);  // height / 10
  EXPECT_NEAR(x[3], 1.0, 1e-6);  // forward speed / 3
  EXPECT_NEAR(x[4], 0.0, 1e-6);
  EXPECT_NEAR(x[5], 0.1, 1e-6);
  // q_local: the roll alone.
  EXPECT_NEAR(x[6], std::sin(roll / 2), 1e-6);
  EXPECT_NEAR(x[7], 0.0, 1e-6);
  EXPECT_NEAR(x[8], 0.0, 1e-6);
  EXPECT_NEAR(x[9], std::cos(roll / 2), 1e-6);
  EXPECT_NEAR(x[10], 1.0, 1e-6);  // goal 10 m ahead / 10
  EXPECT_NEAR(x[11], 0.0, 1e-6);
  EXPECT_NEAR(x[12], 0.0, 1e-6);
}

TEST(EncodeState, RejectsNonFiniteInputWithItsName) {
  const PolicyMeta m = Meta(PolicyFrame::kWorld, PolicyFrame::kWorld, OutputRepresentation::kBspline);
  VehicleState s;
  s.v_world.x() = std::nan("");
  try {
    EncodeState(s, Eigen::Vector3d::Zero(), m);
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("v_world"), std::string::npos);
  }
  s = VehicleState();
  s.q_world_body = Eigen::Quaterniond(0, 0, 0, 0);
  EXPECT_THROW(EncodeState(s, Eigen::Vector3d::Zero(), m), std::invalid_argument);
}

TEST(OutputDecoder, WorldBsplineIsTheReshapedOutput) {
  const PolicyMeta m = Meta(PolicyFrame::kWorld, PolicyFrame::kWorld, OutputRepresentation::kBspline);
  std::vector<float> y(30);
  for (int i = 0; i < 30; ++i) y[i] = 0.5f * i;
  const CtrlPoints c = OutputDecoder(m).Decode(y, VehicleState());
  ASSERT_EQ(c.rows(), 10);
  EXPECT_DOUBLE_EQ(c(3, 1), 0.5 * 10);
  EXPECT_THROW(OutputDecoder(m).Decode(std::vector<float>(29), VehicleState()), std::invalid_argument);
}

TEST(OutputDecoder, LocalBsplineIsRotatedByYawAndTranslated) {
  const PolicyMeta m = Meta(PolicyFrame::kWorld, PolicyFrame::kLocal, OutputRepresentation::kBspline);
  VehicleState s;
  s.p_world_body = Eigen::Vector3d(5.0, -1.0, 1.5);
  s.q_world_body = Eigen::Quaterniond(Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitZ()));
  std::vector<float> y(30, 0.0f);
  y[3 * 4 + 0] = 2.0f;  // control point 4: 2 m ahead, 0.5 m up
  y[3 * 4 + 2] = 0.5f;
  const CtrlPoints c = OutputDecoder(m).Decode(y, s);
  EXPECT_NEAR(c(4, 0), 5.0, 1e-6);
  EXPECT_NEAR(c(4, 1), 1.0, 1e-6);
  EXPECT_NEAR(c(4, 2), 2.0, 1e-6);
  EXPECT_NEAR(c(0, 0), 5.0, 1e-6);
  EXPECT_NEAR(c(0, 1), -1.0, 1e-6);
}

TEST(UniformCubicBasis, IsAPartitionOfUnityEndingAtTheLastControlPoints) {
  const Eigen::MatrixXd a = UniformCubicBasis(10, 113);
  for (int j = 0; j < a.rows(); ++j) EXPECT_NEAR(a.row(j).sum(), 1.0, 1e-12);
  // At the domain end (u = 1 of the last segment): (c_{K-3} + 4 c_{K-2} + c_{K-1}) / 6.
  EXPECT_NEAR(a(112, 7), 1.0 / 6, 1e-12);
  EXPECT_NEAR(a(112, 8), 4.0 / 6, 1e-12);
  EXPECT_NEAR(a(112, 9), 1.0 / 6, 1e-12);
}

TEST(OutputDecoder, PolynomialOutputDecodesCubicTrajectoriesExactly) {
  // The polynomial representation describes p(tau), tau = 2 t / horizon - 1. A cubic in tau is reproduced
  // exactly by the decoded uniform cubic B-spline.
  const PolicyMeta m = Meta(PolicyFrame::kWorld, PolicyFrame::kWorld, OutputRepresentation::kPolynomial);
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<double> u(-2.0, 2.0);
  Eigen::Matrix<double, 6, 3> coeff = Eigen::Matrix<double, 6, 3>::Zero();
  for (int d = 0; d <= 3; ++d) {
    for (int c = 0; c < 3; ++c) coeff(d, c) = u(rng);
  }
  std::vector<float> y(18);
  for (int d = 0; d < 6; ++d) {
    for (int c = 0; c < 3; ++c) y[3 * d + c] = static_cast<float>(coeff(d, c));
  }
  const UniformBspline s = PolicyTrajectory(OutputDecoder(m).Decode(y, VehicleState()), m, 0.0);
  for (int j = 0; j <= 20; ++j) {
    const double t = m.horizon_s * j / 20.0;
    const double tau = 2.0 * t / m.horizon_s - 1.0;
    Eigen::Vector3d expected = Eigen::Vector3d::Zero();
    for (int d = 0; d <= 3; ++d)
      expected += std::pow(tau, d) * coeff.row(d).transpose().cast<float>().cast<double>();
    EXPECT_LT((s.Position(t) - expected).norm(), 2e-5) << "t = " << t;
  }
}

}  // namespace
}  // namespace quad_policy
