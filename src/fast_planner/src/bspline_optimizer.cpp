#include "fast_planner/bspline_optimizer.h"

#include <Eigen/QR>
#include <nlopt.hpp>

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <vector>

namespace fast_planner {

namespace {
constexpr int kFixedStart = 3;
constexpr int kMinSpans = 3;
}  // namespace

Eigen::Matrix3d ControlPointsFromState(const Eigen::Vector3d& p, const Eigen::Vector3d& v,
                                       const Eigen::Vector3d& a, double ts) {
  // Value (Q0 + 4 Q1 + Q2) / 6, derivative (Q2 - Q0) / (2 ts), second derivative (Q0 - 2 Q1 + Q2) / ts^2.
  const Eigen::Vector3d q1 = p - a * ts * ts / 6.0;
  Eigen::Matrix3d q;
  q.row(0) = (q1 + 0.5 * a * ts * ts - ts * v).transpose();
  q.row(1) = q1.transpose();
  q.row(2) = (q1 + 0.5 * a * ts * ts + ts * v).transpose();
  return q;
}

Eigen::MatrixXd FitUniformBspline(const PolyPath& path, double ts_nominal_s, const Eigen::Vector3d& start_acc,
                                  bool fix_end, double* ts_s) {
  if (path.empty() || !(path.duration_s() > 0.0)) {
    throw std::invalid_argument("FitUniformBspline: the path is empty");
  }
  if (!(ts_nominal_s > 0.0)) throw std::invalid_argument("FitUniformBspline: the knot span must be positive");
  const double T = path.duration_s();
  const int K = std::max(kMinSpans, static_cast<int>(std::ceil(T / ts_nominal_s - 1e-9)));
  const double ts = T / K;
  *ts_s = ts;
  const int N = K + 3;
  Eigen::MatrixXd q = Eigen::MatrixXd::Zero(N, 3);
  q.topRows(3) = ControlPointsFromState(path.Position(0.0), path.Velocity(0.0), start_acc, ts);
  const int num_fixed_end = fix_end ? 3 : 0;
  if (fix_end) {
    q.bottomRows(3) =
        ControlPointsFromState(path.Position(T), Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero(), ts);
  }
  const int first_free = kFixedStart;
  const int num_free = N - kFixedStart - num_fixed_end;
  if (num_free <= 0) return q;

  // Rows: the positions at knots 1..K, then (when the end is free) the end velocity and acceleration, scaled
  // by ts and ts^2 so that every row is in metres.
  const int rows = K + (fix_end ? 0 : 2);
  Eigen::MatrixXd A = Eigen::MatrixXd::Zero(rows, num_free);
  Eigen::MatrixXd b = Eigen::MatrixXd::Zero(rows, 3);
  auto add = [&](int row, int ctrl, double coeff) {
    if (ctrl >= first_free && ctrl < first_free + num_free) {
      A(row, ctrl - first_free) += coeff;
    } else {
      b.row(row) -= coeff * q.row(ctrl);  // a fixed control point moves to the right-hand side
    }
  };
  for (int i = 1; i <= K; ++i) {
    const int row = i - 1;
    b.row(row) += path.Position(i * ts).transpose();
    add(row, i, 1.0 / 6.0);
    add(row, i + 1, 4.0 / 6.0);
    add(row, i + 2, 1.0 / 6.0);
  }
  if (!fix_end) {
    b.row(K) += (path.Velocity(T) * ts).transpose();
    add(K, K, -0.5);
    add(K, K + 2, 0.5);
    b.row(K + 1) += (path.Acceleration(T) * ts * ts).transpose();
    add(K + 1, K, 1.0);
    add(K + 1, K + 1, -2.0);
    add(K + 1, K + 2, 1.0);
  }
  q.middleRows(first_free, num_free) = A.colPivHouseholderQr().solve(b);
  return q;
}

BsplineCost EvaluateBsplineCost(const BsplineCostParams& prm, const Esdf& esdf, const Eigen::MatrixXd& q,
                                Eigen::MatrixXd* grad) {
  const int N = static_cast<int>(q.rows());
  if (N < 4 || q.cols() != 3)
    throw std::invalid_argument("EvaluateBsplineCost: need at least 4 control points");
  const int first_free = kFixedStart;
  const int end_free = prm.fix_end ? N - 3 : N;  // exclusive
  BsplineCost c;
  Eigen::MatrixXd g_s = Eigen::MatrixXd::Zero(N, 3), g_d = g_s, g_f = g_s, g_e = g_s;

  for (int i = 0; i + 3 < N; ++i) {
    const Eigen::Vector3d j = q.row(i + 3) - 3.0 * q.row(i + 2) + 3.0 * q.row(i + 1) - q.row(i);
    c.smooth += j.squaredNorm();
    g_s.row(i + 3) += 2.0 * j.transpose();
    g_s.row(i + 2) -= 6.0 * j.transpose();
    g_s.row(i + 1) += 6.0 * j.transpose();
    g_s.row(i) -= 2.0 * j.transpose();
  }

  for (int i = first_free; i < end_free; ++i) {
    Eigen::Vector3d dgrad;
    const double d = esdf.DistanceAndGradient(q.row(i).transpose(), &dgrad);
    if (d < prm.safe_distance_m) {
      const double e = d - prm.safe_distance_m;
      c.distance += e * e;
      g_d.row(i) += 2.0 * e * dgrad.transpose();
    }
  }

  const double inv_ts = 1.0 / prm.ts_s;
  const double inv_ts2 = inv_ts * inv_ts;
  // The excess is relative to the limit (dimensionless): an absolute quartic penalty on accelerations, scaled
  // by 1/ts^8 in the control points, made the problem so stiff that L-BFGS's line search failed.
  const double vm2 = prm.max_vel_mps * prm.max_vel_mps;
  const double am2 = prm.max_acc_mps2 * prm.max_acc_mps2;
  for (int i = 0; i + 1 < N; ++i) {
    const Eigen::Vector3d v = (q.row(i + 1) - q.row(i)).transpose() * inv_ts;
    const double e = (v.squaredNorm() - vm2) / vm2;
    if (e > 0.0) {
      c.feasibility += e * e;
      const Eigen::Vector3d dv = 4.0 * e * v * inv_ts / vm2;
      g_f.row(i + 1) += dv.transpose();
      g_f.row(i) -= dv.transpose();
    }
  }
  for (int i = 0; i + 2 < N; ++i) {
    const Eigen::Vector3d a = (q.row(i + 2) - 2.0 * q.row(i + 1) + q.row(i)).transpose() * inv_ts2;
    const double e = (a.squaredNorm() - am2) / am2;
    if (e > 0.0) {
      c.feasibility += e * e;
      const Eigen::Vector3d da = 4.0 * e * a * inv_ts2 / am2;
      g_f.row(i + 2) += da.transpose();
      g_f.row(i + 1) -= 2.0 * da.transpose();
      g_f.row(i) += da.transpose();
    }
  }

  if (!prm.fix_end) {
    const Eigen::Vector3d e =
        (q.row(N - 3) + 4.0 * q.row(N - 2) + q.row(N - 1)).transpose() / 6.0 - prm.end_target;
    c.endpoint = e.squaredNorm();
    g_e.row(N - 3) += (2.0 / 6.0) * e.transpose();
    g_e.row(N - 2) += (8.0 / 6.0) * e.transpose();
    g_e.row(N - 1) += (2.0 / 6.0) * e.transpose();
  }

  c.total = prm.w_smooth * c.smooth + prm.w_distance * c.distance + prm.w_feasibility * c.feasibility +
            prm.w_endpoint * c.endpoint;
  if (grad) {
    *grad = prm.w_smooth * g_s + prm.w_distance * g_d + prm.w_feasibility * g_f + prm.w_endpoint * g_e;
    grad->topRows(first_free).setZero();
    if (prm.fix_end) grad->bottomRows(3).setZero();
  }
  return c;
}

BsplineOptimizer::BsplineOptimizer(const OptimizerConfig& cfg, const LimitsConfig& limits)
    : cfg_(cfg), limits_(limits) {
  ValidateOptimizerConfig(cfg);
  ValidateLimitsConfig(limits);
}

BsplineCostParams BsplineOptimizer::Params(double ts_s, bool fix_end, const Eigen::Vector3d& end_target,
                                           double distance_weight_scale) const {
  BsplineCostParams p;
  p.ts_s = ts_s;
  p.w_smooth = cfg_.w_smooth;
  p.w_distance = cfg_.w_distance * distance_weight_scale;
  p.w_feasibility = cfg_.w_feasibility;
  p.w_endpoint = cfg_.w_endpoint;
  p.safe_distance_m = cfg_.safe_distance_m;
  p.max_vel_mps = limits_.max_vel_mps;
  p.max_acc_mps2 = limits_.max_acc_mps2;
  p.fix_end = fix_end;
  p.end_target = end_target;
  return p;
}

namespace {

struct ObjectiveData {
  const BsplineCostParams* params;
  const Esdf* esdf;
  Eigen::MatrixXd q;  // full control points; the free rows are overwritten from x
  Eigen::MatrixXd grad;
  int first_free;
  int num_free;
  int evaluations = 0;
  double best_cost = std::numeric_limits<double>::infinity();
  std::vector<double> best_x;
};

double Objective(const std::vector<double>& x, std::vector<double>& grad, void* data_ptr) {
  auto* d = static_cast<ObjectiveData*>(data_ptr);
  for (int i = 0; i < d->num_free; ++i) {
    for (int a = 0; a < 3; ++a) d->q(d->first_free + i, a) = x[3 * i + a];
  }
  const double cost =
      EvaluateBsplineCost(*d->params, *d->esdf, d->q, grad.empty() ? nullptr : &d->grad).total;
  if (!grad.empty()) {
    for (int i = 0; i < d->num_free; ++i) {
      for (int a = 0; a < 3; ++a) grad[3 * i + a] = d->grad(d->first_free + i, a);
    }
  }
  ++d->evaluations;
  if (cost < d->best_cost && std::isfinite(cost)) {
    d->best_cost = cost;
    d->best_x = x;
  }
  return cost;
}

}  // namespace

OptimizationResult BsplineOptimizer::Optimize(const Eigen::MatrixXd& ctrl_pts, double ts_s, const Esdf& esdf,
                                              bool fix_end, const Eigen::Vector3d& end_target,
                                              double distance_weight_scale) const {
  if (!ctrl_pts.allFinite() || ctrl_pts.cols() != 3) {
    throw std::invalid_argument("BsplineOptimizer::Optimize: control points must be finite N x 3");
  }
  const BsplineCostParams params = Params(ts_s, fix_end, end_target, distance_weight_scale);
  OptimizationResult result;
  result.ctrl_pts = ctrl_pts;
  result.initial = EvaluateBsplineCost(params, esdf, ctrl_pts, nullptr);
  const int N = static_cast<int>(ctrl_pts.rows());
  ObjectiveData data;
  data.params = &params;
  data.esdf = &esdf;
  data.q = ctrl_pts;
  data.first_free = kFixedStart;
  data.num_free = N - kFixedStart - (fix_end ? 3 : 0);
  if (data.num_free <= 0) {
    result.final = result.initial;
    result.nlopt_result = "nothing to optimise";
    return result;
  }
  std::vector<double> x(3 * data.num_free);
  for (int i = 0; i < data.num_free; ++i) {
    for (int a = 0; a < 3; ++a) x[3 * i + a] = ctrl_pts(kFixedStart + i, a);
  }
  nlopt::opt opt(nlopt::LD_LBFGS, static_cast<unsigned>(x.size()));
  opt.set_min_objective(Objective, &data);
  opt.set_maxeval(cfg_.max_iterations);
  opt.set_xtol_rel(1e-5);
  double f = 0.0;
  try {
    const nlopt::result r = opt.optimize(x, f);
    switch (r) {
      case nlopt::SUCCESS:
        result.nlopt_result = "success";
        break;
      case nlopt::FTOL_REACHED:
        result.nlopt_result = "ftol reached";
        break;
      case nlopt::XTOL_REACHED:
        result.nlopt_result = "xtol reached";
        break;
      case nlopt::MAXEVAL_REACHED:
        result.nlopt_result = "max evaluations reached";
        break;
      default:
        result.nlopt_result = "stopped (" + std::to_string(static_cast<int>(r)) + ")";
    }
  } catch (const std::exception& e) {
    // L-BFGS ends with "roundoff limited" near flat minima; the best point seen is still a valid result.
    result.nlopt_result = std::string("nlopt: ") + e.what();
  }
  if (!data.best_x.empty()) x = data.best_x;
  for (int i = 0; i < data.num_free; ++i) {
    for (int a = 0; a < 3; ++a) result.ctrl_pts(kFixedStart + i, a) = x[3 * i + a];
  }
  result.evaluations = data.evaluations;
  result.final = EvaluateBsplineCost(params, esdf, result.ctrl_pts, nullptr);
  return result;
}

}  // namespace fast_planner
