// Step metrics on an analytic second-order response, the Ziegler-Nichols search on a third-order plant with a
// known ultimate gain and period, and the figure-eight reference.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>

#include "kr_tracker/reference_trajectories.h"
#include "kr_tracker/response_metrics.h"
#include "kr_tracker/ziegler_nichols.h"

namespace kr_tracker {
namespace {

// Unit step response of wn^2 / (s^2 + 2 zeta wn s + wn^2), zeta < 1.
double SecondOrderStep(double t, double zeta, double wn) {
  const double wd = wn * std::sqrt(1 - zeta * zeta);
  const double phi = std::acos(zeta);
  return 1.0 - std::exp(-zeta * wn * t) * std::sin(wd * t + phi) / std::sqrt(1 - zeta * zeta);
}

TEST(StepMetrics, MatchTheClosedFormsOfAnUnderdampedSecondOrderSystem) {
  const double zeta = 0.5, wn = 4.0;
  std::vector<double> t, y;
  for (double s = 0.0; s <= 10.0; s += 1e-4) {
    t.push_back(1.0 + s);
    y.push_back(2.0 + 3.0 * SecondOrderStep(s, zeta, wn));  // a step of 3 from 2 at t = 1
  }
  const StepMetrics m = AnalyzeStep(t, y, 2.0, 5.0, 1.0, 0.02, 1.0);
  const double overshoot = 100.0 * std::exp(-zeta * M_PI / std::sqrt(1 - zeta * zeta));
  EXPECT_NEAR(m.overshoot_pct, overshoot, 1e-3);
  EXPECT_TRUE(m.rose);
  EXPECT_TRUE(m.settled);
  // Rise time 10-90 % of this system (solved numerically beforehand from the closed form): 0.4104 s at wn
  // = 4.
  double t10 = 0, t90 = 0;
  for (double s = 0; s < 2; s += 1e-6) {
    if (t10 == 0 && SecondOrderStep(s, zeta, wn) >= 0.1) t10 = s;
    if (t90 == 0 && SecondOrderStep(s, zeta, wn) >= 0.9) t90 = s;
  }
  EXPECT_NEAR(m.rise_time_s, t90 - t10, 2e-4);
  // 2 % settling: the last time the closed form leaves the band, found by dense sampling; the envelope
  // exp(-zeta wn t) / sqrt(1 - zeta^2) bounds it from above.
  double t_settle = 0.0;
  for (double s = 0; s < 10; s += 1e-6) {
    if (std::fabs(SecondOrderStep(s, zeta, wn) - 1.0) > 0.02) t_settle = s;
  }
  EXPECT_NEAR(m.settling_time_s, t_settle, 2e-4);
  EXPECT_LT(m.settling_time_s, -std::log(0.02 * std::sqrt(1 - zeta * zeta)) / (zeta * wn));
  EXPECT_LT(m.steady_state_error, 1e-6);
}

TEST(StepMetrics, ReportsNotSettledAndNegativeStepsAndRejectsBadInput) {
  std::vector<double> t = {0, 1, 2, 3}, y = {0, -0.5, -0.8, -0.85};
  const StepMetrics m = AnalyzeStep(t, y, 0.0, -1.0, 0.0);
  EXPECT_FALSE(m.rose);
  EXPECT_FALSE(m.settled);
  EXPECT_DOUBLE_EQ(m.overshoot_pct, 0.0);
  EXPECT_TRUE(std::isinf(m.settling_time_s));
  EXPECT_THROW(AnalyzeStep({0, 1}, {0}, 0, 1, 0), std::invalid_argument);
  EXPECT_THROW(AnalyzeStep({0, 1}, {0, 1}, 1, 1, 0), std::invalid_argument);
}

TEST(TrackingErrorMetric, RmsAndMaxOfKnownOffsets) {
  std::vector<Eigen::Vector3d> p = {{0, 0, 0}, {1, 0, 0}, {0, 0, 0}, {0, 0, 0}};
  std::vector<Eigen::Vector3d> r = {{0, 0, 0.1}, {1, 0, 0}, {0, 0.3, 0}, {0, 0, 0}};
  const TrackingError e = ComputeTrackingError(p, r);
  EXPECT_NEAR(e.rms_m, std::sqrt((0.01 + 0.09) / 4), 1e-12);
  EXPECT_NEAR(e.max_m, 0.3, 1e-12);
  EXPECT_EQ(e.samples, 4);
}

// y''' tau1 tau2 + y'' (tau1 + tau2) + y' = K (-y): P control of 1 / (s (tau1 s + 1)(tau2 s + 1)).
// Routh: Ku = (tau1 + tau2) / (tau1 tau2), wu = 1 / sqrt(tau1 tau2).
void ThirdOrderExperiment(double k, std::vector<double>* t, std::vector<double>* y) {
  const double tau1 = 0.1, tau2 = 0.05, dt = 1e-4;
  Eigen::Vector3d x(0.01, 0.0, 0.0);
  auto f = [&](const Eigen::Vector3d& s) {
    return Eigen::Vector3d(s(1), s(2), (k * -s(0) - s(1) - (tau1 + tau2) * s(2)) / (tau1 * tau2));
  };
  t->clear();
  y->clear();
  for (int i = 0; i <= 40000; ++i) {
    if (i % 10 == 0) {
      t->push_back(i * dt);
      y->push_back(x(0));
    }
    const Eigen::Vector3d k1 = f(x), k2 = f(x + 0.5 * dt * k1), k3 = f(x + 0.5 * dt * k2),
                          k4 = f(x + dt * k3);
    x += dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4);
  }
}

TEST(ZieglerNichols, FindsTheRouthUltimateGainAndPeriodOfAThirdOrderPlant) {
  UltimateGainSearch search;
  search.k_min = 1.0;
  search.k_max = 500.0;
  search.relative_tol = 0.005;
  search.t_from_s = 0.5;
  search.noise_floor = 1e-9;
  const UltimateGainResult r = FindUltimateGain(ThirdOrderExperiment, search);
  EXPECT_EQ(r.status, UltimateGainStatus::kFound);
  EXPECT_NEAR(r.ku, 30.0, 30.0 * 0.01);
  EXPECT_NEAR(r.tu_s, 2 * M_PI * std::sqrt(0.005), 0.01);
  EXPECT_GT(r.experiments, 5);
}

TEST(ZieglerNichols, ReportsNoInstabilityAndUnstableAtMinimum) {
  const auto stable = [](double, std::vector<double>* t, std::vector<double>* y) {
    for (int i = 0; i < 1000; ++i) {
      t->push_back(i * 0.01);
      y->push_back(std::exp(-i * 0.01) * std::cos(10 * i * 0.01));
    }
  };
  UltimateGainSearch search;
  search.k_max = 10.0;
  EXPECT_EQ(FindUltimateGain(stable, search).status, UltimateGainStatus::kNoInstability);
  const auto unstable = [](double, std::vector<double>* t, std::vector<double>* y) {
    for (int i = 0; i < 1000; ++i) {
      t->push_back(i * 0.01);
      y->push_back(std::exp(i * 0.01) * std::cos(10 * i * 0.01));
    }
  };
  EXPECT_EQ(FindUltimateGain(unstable, search).status, UltimateGainStatus::kUnstableAtMinimum);
}

TEST(ZieglerNichols, OscillationAnalysisMeasuresGrowthAndPeriod) {
  std::vector<double> t, y;
  for (int i = 0; i < 5000; ++i) {
    t.push_back(i * 1e-3);
    y.push_back(std::exp(0.2 * i * 1e-3) * std::sin(2 * M_PI * i * 1e-3 / 0.5));
  }
  const OscillationAnalysis a = AnalyzeOscillation(t, y, 0.0, 1e-6, 100);
  EXPECT_NEAR(a.period_s, 0.5, 2e-3);
  EXPECT_NEAR(a.growth_ratio, std::exp(0.2 * 0.25), 2e-3);  // per half period
  EXPECT_EQ(a.num_peaks, 20);
  // Growth that saturates into a limit cycle: judged on the first extrema, it is unstable.
  std::vector<double> sat(y.size());
  for (size_t i = 0; i < y.size(); ++i)
    sat[i] = std::clamp(std::exp(2.0 * t[i]) * std::sin(4 * M_PI * t[i]), -20.0, 20.0);
  EXPECT_GT(AnalyzeOscillation(t, sat, 0.0, 1e-6, 6).growth_ratio, 1.5);
  EXPECT_LT(AnalyzeOscillation(t, sat, 1.5, 1e-6, 6).growth_ratio, 1.0 + 1e-9);
  const auto rules = ZieglerNicholsRules(30.0, 0.4);
  EXPECT_EQ(rules[1].rule, "PI");
  EXPECT_DOUBLE_EQ(rules[1].kp, 13.5);
  EXPECT_NEAR(rules[1].ti_s, 0.4 / 1.2, 1e-12);
  EXPECT_DOUBLE_EQ(rules[3].kp, 18.0);
  EXPECT_DOUBLE_EQ(rules[3].td_s, 0.05);
}

TEST(FigureEight, StartsAndEndsAtRestAtTheCentreWithTheRequestedPeakSpeed) {
  FigureEightSpec spec;
  const quad_core::NonUniformBspline s = MakeFigureEight(spec, 5.0);
  EXPECT_DOUBLE_EQ(s.tmin(), 5.0);
  EXPECT_NEAR(SampledPeakSpeed(s, 1e-4), 2.0, 1e-3);
  EXPECT_TRUE(s.Evaluate(s.tmin()).isApprox(spec.center_world, 1e-9));
  EXPECT_LT((s.Evaluate(s.tmax()) - spec.center_world).norm(), 1e-9);
  EXPECT_LT(s.Derivative().Evaluate(s.tmin()).norm(), 1e-9);
  EXPECT_LT(s.Derivative().Evaluate(s.tmax()).norm(), 1e-9);
  // It spans the figure: x reaches about +-half_length, y about +-half_width.
  double max_x = 0, max_y = 0;
  for (int i = 0; i <= 1000; ++i) {
    const Eigen::Vector3d p = s.Evaluate(s.tmin() + s.duration() * i / 1000);
    max_x = std::max(max_x, std::fabs(p.x() - spec.center_world.x()));
    max_y = std::max(max_y, std::fabs(p.y() - spec.center_world.y()));
    EXPECT_NEAR(p.z(), spec.center_world.z(), 1e-9);
  }
  EXPECT_NEAR(max_x, spec.half_length_m, 0.1);
  EXPECT_NEAR(max_y, spec.half_width_m, 0.1);
}

}  // namespace
}  // namespace kr_tracker
