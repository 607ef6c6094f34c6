// The safety layer between the network and the tracker (issue 8): a proposed trajectory is refused when its
// control points are not finite, when the control points of its derivatives exceed the velocity or
// acceleration limit (convex-hull bounds), when it starts far from the vehicle, or when it enters space that
// the latest depth frame shows occupied. The same checks, in the same order, are implemented in Python
// (quad_il/inference/safety.py); docs/inference.md describes them.
#pragma once

#include <Eigen/Geometry>

#include <array>
#include <string>
#include <vector>

#include "quad_policy/preprocessing.h"
#include "quad_policy/trajectory.h"

namespace quad_policy {

enum class SafetyVerdict {
  kAccepted = 0,
  kNonFiniteOutput = 1,
  kVelocityLimit = 2,
  kAccelerationLimit = 3,
  kStartFarFromVehicle = 4,
  kCollisionInDepth = 5,
};
inline constexpr int kNumSafetyVerdicts = 6;
// "accepted", "non_finite_output", "velocity_limit", "acceleration_limit", "start_far_from_vehicle",
// "collision_in_depth" (the names published and counted by both nodes).
const char* ToString(SafetyVerdict verdict);

struct SafetyConfig {
  bool enabled = true;         // false: every finite trajectory is accepted (non-finite is always refused)
  double max_vel_mps = 5.0;    // limit on |V_i|, the velocity control points
  double max_acc_mps2 = 10.0;  // limit on |A_i|, the acceleration control points
  double max_start_error_m = 1.0;  // limit on |p(0) - p_vehicle|
  double vehicle_radius_m = 0.25;  // sphere around each sample tested against the depth image
  double sample_dt_s = 0.05;       // spacing of the samples tested against the depth image
  double check_horizon_s = 0.0;    // samples up to this time; 0 = the whole trajectory
  int collision_min_pixels = 1;    // occupied pixels needed to call a sample colliding
};
// Throws std::invalid_argument naming the bad field.
void ValidateSafetyConfig(const SafetyConfig& cfg);

// Pinhole camera of the depth frame (CameraInfo K; pixel centres at integer coordinates) and its pose in the
// world at the frame's time.
struct CameraModel {
  int width = 0;
  int height = 0;
  double fx = 0.0;
  double fy = 0.0;
  double cx = 0.0;
  double cy = 0.0;
  Eigen::Isometry3d T_world_camera = Eigen::Isometry3d::Identity();  // camera optical frame (z forward)
};

struct SafetyResult {
  SafetyVerdict verdict = SafetyVerdict::kAccepted;
  std::string reason;  // printable: "accepted" or the refusal with its numbers
  double value =
      0.0;  // the offending quantity (speed, acceleration, distance, or the colliding sample's time)
  bool accepted() const { return verdict == SafetyVerdict::kAccepted; }
};

// Collision of trajectory samples with the depth image. A sample p (sphere of radius r) collides when at
// least min_pixels pixels (u, v) have a measured depth d with d < t_far, where t_far is the depth (along the
// optical axis) at which the pixel's ray leaves the sphere: the sphere reaches into or behind the surface the
// pixel saw. d = +inf (no return) and NaN (invalid) are free, -inf (nearer than the camera's minimum) counts
// as d = 0. Samples whose sphere contains the camera centre (the vehicle's own position) and samples that no
// ray of the image meets are not judged. Only the pixels of the sphere's bounding rectangle in the image are
// tested (exactly: the rectangle comes from the sphere's tangents in the x-z and y-z planes, widened by one
// pixel).
struct DepthCollision {
  bool collides = false;
  int sample_index = -1;
  int occupied_pixels = 0;
  int u = -1;  // one occupied pixel of the colliding sample
  int v = -1;
  double measured_depth_m = 0.0;
  double sphere_depth_m = 0.0;  // t_far of that pixel
};
DepthCollision FindDepthCollision(const std::vector<Eigen::Vector3d>& samples_world, double radius_m,
                                  int min_pixels, const DepthImageView& depth, const CameraModel& camera);

// Sample times j * sample_dt_s (j = 0, 1, ...) up to the check horizon, and the last time itself.
std::vector<double> SafetySampleTimes(const UniformBspline& traj, const SafetyConfig& cfg);

// All checks in order: non-finite control points; velocity; acceleration; start far from the vehicle;
// collision in the depth image (skipped when depth is null). The first failure is the verdict.
SafetyResult CheckTrajectory(const UniformBspline& traj, const Eigen::Vector3d& p_world_vehicle,
                             const DepthImageView* depth, const CameraModel& camera, const SafetyConfig& cfg);

// Whether the trajectory stays where the depth frame looked: every sample up to the check horizon (the times
// of SafetySampleTimes) whose sphere does not hold the camera centre has its centre in front of the camera
// and projecting inside the image. The recovery's plans must pass this besides CheckTrajectory: a plan
// turned away from the goal may leave the field of view, where the depth check cannot judge it.
bool TrajectoryInView(const UniformBspline& traj, const CameraModel& camera, const SafetyConfig& cfg);

// The smallest depth (along the optical axis, m) among the pixels that show a surface: -inf (nearer than the
// camera's minimum range) counts as 0, NaN and +inf show none. +inf when no pixel shows a surface.
double NearestDepth(const DepthImageView& depth);

// Counts of verdicts (index: SafetyVerdict value).
struct VerdictCounts {
  std::array<unsigned long, kNumSafetyVerdicts> counts{};
  void Add(SafetyVerdict v) { ++counts[static_cast<int>(v)]; }
  unsigned long operator[](SafetyVerdict v) const { return counts[static_cast<int>(v)]; }
  unsigned long refused() const;
};

}  // namespace quad_policy
