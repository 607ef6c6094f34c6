// Piecewise-cubic paths in 3-D: the front end's output (motion primitives and the analytic "shot").
#pragma once

#include <Eigen/Core>

#include <vector>

namespace fast_planner {

// p(t) = c0 + c1 t + c2 t^2 + c3 t^3 (columns of coeffs), t in [0, duration_s].
struct PolySegment {
  Eigen::Matrix<double, 3, 4> coeffs = Eigen::Matrix<double, 3, 4>::Zero();
  double duration_s = 0.0;

  Eigen::Vector3d Position(double t) const {
    return coeffs.col(0) + t * (coeffs.col(1) + t * (coeffs.col(2) + t * coeffs.col(3)));
  }
  Eigen::Vector3d Velocity(double t) const {
    return coeffs.col(1) + t * (2.0 * coeffs.col(2) + 3.0 * t * coeffs.col(3));
  }
  Eigen::Vector3d Acceleration(double t) const { return 2.0 * coeffs.col(2) + 6.0 * t * coeffs.col(3); }

  // Constant-acceleration motion from (p, v) under u for tau seconds (a double-integrator primitive).
  static PolySegment Primitive(const Eigen::Vector3d& p, const Eigen::Vector3d& v, const Eigen::Vector3d& u,
                               double tau_s) {
    PolySegment s;
    s.coeffs.col(0) = p;
    s.coeffs.col(1) = v;
    s.coeffs.col(2) = 0.5 * u;
    s.duration_s = tau_s;
    return s;
  }
};

// A sequence of segments flown back to back from t = 0.
class PolyPath {
 public:
  void Append(const PolySegment& s) {
    segments_.push_back(s);
    duration_s_ += s.duration_s;
  }
  void Clear() {
    segments_.clear();
    duration_s_ = 0.0;
  }
  bool empty() const { return segments_.empty(); }
  double duration_s() const { return duration_s_; }
  const std::vector<PolySegment>& segments() const { return segments_; }

  // t is clamped to [0, duration].
  Eigen::Vector3d Position(double t) const { return Locate(&t).Position(t); }
  Eigen::Vector3d Velocity(double t) const { return Locate(&t).Velocity(t); }
  Eigen::Vector3d Acceleration(double t) const { return Locate(&t).Acceleration(t); }

 private:
  // The segment containing t; t becomes the local time in it.
  const PolySegment& Locate(double* t) const {
    double rest = *t < 0.0 ? 0.0 : *t;
    for (size_t i = 0; i + 1 < segments_.size(); ++i) {
      if (rest <= segments_[i].duration_s) {
        *t = rest;
        return segments_[i];
      }
      rest -= segments_[i].duration_s;
    }
    *t = rest < segments_.back().duration_s ? rest : segments_.back().duration_s;
    return segments_.back();
  }

  std::vector<PolySegment> segments_;
  double duration_s_ = 0.0;
};

}  // namespace fast_planner
