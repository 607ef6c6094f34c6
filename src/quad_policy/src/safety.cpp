#include "quad_policy/safety.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <stdexcept>
#include <string>
#include <utility>

namespace quad_policy {

const char* ToString(SafetyVerdict verdict) {
  switch (verdict) {
    case SafetyVerdict::kAccepted:
      return "accepted";
    case SafetyVerdict::kNonFiniteOutput:
      return "non_finite_output";
    case SafetyVerdict::kVelocityLimit:
      return "velocity_limit";
    case SafetyVerdict::kAccelerationLimit:
      return "acceleration_limit";
    case SafetyVerdict::kStartFarFromVehicle:
      return "start_far_from_vehicle";
    case SafetyVerdict::kCollisionInDepth:
      return "collision_in_depth";
  }
  return "unknown";
}

unsigned long VerdictCounts::refused() const {
  unsigned long n = 0;
  for (int i = 1; i < kNumSafetyVerdicts; ++i) n += counts[i];
  return n;
}

void ValidateSafetyConfig(const SafetyConfig& cfg) {
  const auto positive = [](double v, const char* name) {
    if (!(std::isfinite(v) && v > 0.0)) {
      throw std::invalid_argument(std::string("safety.") + name + " must be > 0, got " + std::to_string(v));
    }
  };
  positive(cfg.max_vel_mps, "max_vel_mps");
  positive(cfg.max_acc_mps2, "max_acc_mps2");
  positive(cfg.max_start_error_m, "max_start_error_m");
  positive(cfg.vehicle_radius_m, "vehicle_radius_m");
  positive(cfg.sample_dt_s, "sample_dt_s");
  if (!(std::isfinite(cfg.check_horizon_s) && cfg.check_horizon_s >= 0.0)) {
    throw std::invalid_argument("safety.check_horizon_s must be >= 0, got " +
                                std::to_string(cfg.check_horizon_s));
  }
  if (cfg.collision_min_pixels < 1) {
    throw std::invalid_argument("safety.collision_min_pixels must be >= 1, got " +
                                std::to_string(cfg.collision_min_pixels));
  }
}

namespace {

// Inclusive pixel range [lo, hi] along one image axis that can see a sphere of radius r whose centre has
// lateral coordinate a and depth z (camera frame); false when no ray in front of the camera meets it. The
// rays of this axis are the half-lines a = z tan(angle), z > 0: they meet the sphere's projection on the (a,
// z) plane, a disc, only between its two tangents.
bool AxisRange(double a, double z, double r, double f, double c0, int n, int* lo, int* hi) {
  const double rho2 = a * a + z * z;
  if (rho2 <= r * r) {
    *lo = 0;
    *hi = n - 1;
    return true;
  }
  const double half_pi = 0.5 * M_PI;
  const double theta = std::atan2(a, z);
  const double alpha = std::asin(r / std::sqrt(rho2));
  const double a0 = theta - alpha;
  const double a1 = theta + alpha;
  if (a1 <= -half_pi || a0 >= half_pi) return false;
  const double lo_f = a0 <= -half_pi ? -1.0 : std::floor(c0 + f * std::tan(a0)) - 1.0;
  const double hi_f = a1 >= half_pi ? static_cast<double>(n) : std::ceil(c0 + f * std::tan(a1)) + 1.0;
  *lo = static_cast<int>(std::max(0.0, lo_f));
  *hi = static_cast<int>(std::min(static_cast<double>(n - 1), hi_f));
  return *lo <= *hi;
}

template <typename... Args>
std::string Printf(const char* fmt, Args... args) {
  char buf[384];
  std::snprintf(buf, sizeof(buf), fmt, args...);
  return buf;
}

void CheckFrame(const DepthImageView& depth, const quad_core::CameraIntrinsics& k) {
  if (depth.data == nullptr || depth.width != k.width || depth.height != k.height) {
    throw std::invalid_argument("depth frame: depth image and camera model sizes differ");
  }
  if (!(k.fx > 0.0 && k.fy > 0.0))
    throw std::invalid_argument("depth frame: camera focal lengths must be > 0");
}

// Whether a point (camera frame) is in front of the camera and projects inside the image.
bool CentreInView(const Eigen::Vector3d& c, const quad_core::CameraIntrinsics& k) {
  if (!(c.z() > 0.0)) return false;
  const double u = k.cx + k.fx * c.x() / c.z();
  const double v = k.cy + k.fy * c.y() / c.z();
  return u >= 0.0 && u <= k.width - 1.0 && v >= 0.0 && v <= k.height - 1.0;
}

}  // namespace

DepthCollision FindDepthCollision(const std::vector<Eigen::Vector3d>& samples_world, double radius_m,
                                  int min_pixels, const DepthImageView& depth, const CameraModel& camera) {
  const quad_core::CameraIntrinsics& k = camera.intrinsics;
  CheckFrame(depth, k);
  const Eigen::Isometry3d T_camera_world = camera.T_world_camera.inverse();
  std::vector<double> dx(k.width), dy(k.height);
  for (int u = 0; u < k.width; ++u) dx[u] = (u - k.cx) / k.fx;
  for (int v = 0; v < k.height; ++v) dy[v] = (v - k.cy) / k.fy;
  const double r2 = radius_m * radius_m;
  for (std::size_t j = 0; j < samples_world.size(); ++j) {
    const Eigen::Vector3d c = T_camera_world * samples_world[j];
    const double c2 = c.squaredNorm();
    if (c2 <= r2) continue;  // the sphere holds the camera: the vehicle's own place
    int u0, u1, v0, v1;
    if (!AxisRange(c.x(), c.z(), radius_m, k.fx, k.cx, k.width, &u0, &u1)) continue;
    if (!AxisRange(c.y(), c.z(), radius_m, k.fy, k.cy, k.height, &v0, &v1)) continue;
    int count = 0;
    DepthCollision hit;
    for (int v = v0; v <= v1; ++v) {
      for (int u = u0; u <= u1; ++u) {
        double d = depth.at(v, u);
        if (std::isnan(d) || d == std::numeric_limits<double>::infinity()) continue;
        if (d < 0.0) d = 0.0;  // -inf: nearer than the camera's minimum range
        // Ray t (dx, dy, 1), t = depth along the optical axis: |t dir - c|^2 = r^2.
        const double aa = dx[u] * dx[u] + dy[v] * dy[v] + 1.0;
        const double bb = dx[u] * c.x() + dy[v] * c.y() + c.z();
        const double disc = bb * bb - aa * (c2 - r2);
        if (disc < 0.0) continue;
        const double t_far = (bb + std::sqrt(disc)) / aa;
        if (t_far > d) {
          if (count == 0) {
            hit.u = u;
            hit.v = v;
            hit.measured_depth_m = d;
            hit.sphere_depth_m = t_far;
          }
          ++count;
        }
      }
    }
    if (count >= min_pixels) {
      hit.collides = true;
      hit.sample_index = static_cast<int>(j);
      hit.occupied_pixels = count;
      return hit;
    }
  }
  return DepthCollision{};
}

std::vector<double> SafetySampleTimes(const UniformBspline& traj, const SafetyConfig& cfg, double from_s) {
  const double duration = traj.duration_s() - from_s;
  const double horizon = cfg.check_horizon_s > 0.0 ? std::min(cfg.check_horizon_s, duration) : duration;
  // Integer steps (no accumulated rounding): from_s + j * dt for j = 0 .. n, then the horizon if not
  // reached.
  const long n = static_cast<long>(std::floor(horizon / cfg.sample_dt_s + 1e-9));
  std::vector<double> times;
  times.reserve(n + 2);
  for (long j = 0; j <= n; ++j) times.push_back(from_s + j * cfg.sample_dt_s);
  if (times.back() < from_s + horizon - 1e-9) times.push_back(from_s + horizon);
  return times;
}

bool TrajectoryInView(const UniformBspline& traj, const CameraModel& camera, const SafetyConfig& cfg,
                      double from_s) {
  const Eigen::Isometry3d T_camera_world = camera.T_world_camera.inverse();
  const double r2 = cfg.vehicle_radius_m * cfg.vehicle_radius_m;
  for (double t : SafetySampleTimes(traj, cfg, from_s)) {
    const Eigen::Vector3d c = T_camera_world * traj.Position(t);
    if (c.squaredNorm() <= r2) continue;  // the vehicle's own place, as in FindDepthCollision
    if (!CentreInView(c, camera.intrinsics)) return false;
  }
  return true;
}

bool RestIsClear(const UniformBspline& traj, double now_s, double min_rest_s,
                 const Eigen::Vector3d& p_world_vehicle, const DepthImageView& depth,
                 const CameraModel& camera, const SafetyConfig& cfg) {
  const double elapsed = now_s - traj.start_time_s;
  if (!(std::isfinite(elapsed) && elapsed >= 0.0 && traj.duration_s() - elapsed >= min_rest_s)) return false;
  if (!((traj.Position(elapsed) - p_world_vehicle).norm() <= cfg.max_start_error_m)) return false;
  if (!cfg.enabled) return true;
  const std::vector<double> times = SafetySampleTimes(traj, cfg, elapsed);
  std::vector<Eigen::Vector3d> samples;
  samples.reserve(times.size());
  for (double t : times) samples.push_back(traj.Position(t));
  return !FindDepthCollision(samples, cfg.vehicle_radius_m, cfg.collision_min_pixels, depth, camera)
              .collides &&
         TrajectoryInView(traj, camera, cfg, elapsed);
}

SafetyResult CheckTrajectory(const UniformBspline& traj, const Eigen::Vector3d& p_world_vehicle,
                             const DepthImageView* depth, const CameraModel& camera,
                             const SafetyConfig& cfg) {
  SafetyResult res;
  for (int i = 0; i < traj.ctrl_world.rows(); ++i) {
    if (!traj.ctrl_world.row(i).allFinite()) {
      res.verdict = SafetyVerdict::kNonFiniteOutput;
      res.value = i;
      res.reason = Printf("non_finite_output: control point %d of %d is NaN/Inf", i,
                          static_cast<int>(traj.ctrl_world.rows()));
      return res;
    }
  }
  if (!(std::isfinite(traj.knot_dt_s) && traj.knot_dt_s > 0.0) || !std::isfinite(traj.start_time_s)) {
    res.verdict = SafetyVerdict::kNonFiniteOutput;
    res.reason = "non_finite_output: knot interval or start time not finite and positive";
    return res;
  }
  if (!cfg.enabled) {
    res.reason = "accepted (safety checks disabled)";
    return res;
  }
  const auto largest = [](const CtrlPoints& pts, int* index) {
    double best = 0.0;
    *index = -1;
    for (int i = 0; i < pts.rows(); ++i) {
      const double n = pts.row(i).norm();
      if (n > best) {
        best = n;
        *index = i;
      }
    }
    return best;
  };
  int index;
  const double vmax = largest(traj.VelocityCtrlPts(), &index);
  if (vmax > cfg.max_vel_mps) {
    res.verdict = SafetyVerdict::kVelocityLimit;
    res.value = vmax;
    res.reason = Printf("velocity_limit: control-point speed %.3f m/s > %.3f m/s (velocity control point %d)",
                        vmax, cfg.max_vel_mps, index);
    return res;
  }
  const double amax = largest(traj.AccelerationCtrlPts(), &index);
  if (amax > cfg.max_acc_mps2) {
    res.verdict = SafetyVerdict::kAccelerationLimit;
    res.value = amax;
    res.reason = Printf(
        "acceleration_limit: control-point acceleration %.3f m/s^2 > %.3f m/s^2 (acceleration control point "
        "%d)",
        amax, cfg.max_acc_mps2, index);
    return res;
  }
  const double start_error = (traj.Position(0.0) - p_world_vehicle).norm();
  if (!(start_error <= cfg.max_start_error_m)) {
    res.verdict = SafetyVerdict::kStartFarFromVehicle;
    res.value = start_error;
    res.reason =
        Printf("start_far_from_vehicle: the trajectory starts %.3f m from the vehicle (limit %.3f m)",
               start_error, cfg.max_start_error_m);
    return res;
  }
  if (depth != nullptr) {
    const std::vector<double> times = SafetySampleTimes(traj, cfg);
    std::vector<Eigen::Vector3d> samples;
    samples.reserve(times.size());
    for (double t : times) samples.push_back(traj.Position(t));
    const DepthCollision hit =
        FindDepthCollision(samples, cfg.vehicle_radius_m, cfg.collision_min_pixels, *depth, camera);
    if (hit.collides) {
      res.verdict = SafetyVerdict::kCollisionInDepth;
      res.value = times[hit.sample_index];
      res.reason = Printf(
          "collision_in_depth: at t = %.3f s the vehicle sphere (r = %.2f m) reaches %.3f m deep along "
          "pixel (%d, %d) whose measured depth is %.3f m (%d occupied pixels)",
          res.value, cfg.vehicle_radius_m, hit.sphere_depth_m, hit.u, hit.v, hit.measured_depth_m,
          hit.occupied_pixels);
      return res;
    }
  }
  res.reason = "accepted";
  return res;
}

}  // namespace quad_policy
