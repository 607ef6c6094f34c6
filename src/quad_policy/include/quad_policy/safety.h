// The safety layer between the network and the tracker (issue 8): a proposed trajectory is refused when its
// control points are not finite, when the control points of its derivatives exceed the velocity or
// acceleration limit (convex-hull bounds), when it starts far from the vehicle, or when it enters space that
// the depth frame shows occupied. Python uses these through the bindings (quad_policy_py); docs/inference.md
// describes them.
#pragma once

#include <Eigen/Geometry>

#include <array>
#include <limits>
#include <string>
#include <vector>

#include <quad_core/camera.h>

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

// The depth frame's camera: its intrinsics (CameraInfo K; pixel centres at integer coordinates) and its pose
// in the world at the frame's time.
struct CameraModel {
  quad_core::CameraIntrinsics intrinsics;
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
// pixel). Samples beside or behind the camera are not judged: earlier frames are not remembered (a depth
// memory was measured to give nothing, docs/notebook/2026-12_closed_loop_issue8.md, "Depth memory").
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

// Sample times from_s + j * sample_dt_s (j = 0, 1, ...) up to the check horizon after from_s (or the
// trajectory's end), and that last time itself. from_s > 0 judges the rest of a trajectory (RestIsClear).
std::vector<double> SafetySampleTimes(const UniformBspline& traj, const SafetyConfig& cfg,
                                      double from_s = 0.0);

// All checks in order: non-finite control points; velocity; acceleration; start far from the vehicle;
// collision in the depth image (skipped when depth is null). The first failure is the verdict.
SafetyResult CheckTrajectory(const UniformBspline& traj, const Eigen::Vector3d& p_world_vehicle,
                             const DepthImageView* depth, const CameraModel& camera, const SafetyConfig& cfg);

// Whether the trajectory stays where the depth frame looked: every sample up to the check horizon (the times
// of SafetySampleTimes) whose sphere does not hold the camera centre has its centre in front of the camera
// and projecting inside the image. The recovery's plans must pass this besides CheckTrajectory: a plan
// turned away from the goal may leave the field of view, where the depth check cannot judge it.
// from_s: judge the samples from that trajectory time on (SafetySampleTimes).
bool TrajectoryInView(const UniformBspline& traj, const CameraModel& camera, const SafetyConfig& cfg,
                      double from_s = 0.0);

// Whether the rest of a trajectory sent before (from the time now_s on) may still be flown: at least
// min_rest_s of it is left, the vehicle is within max_start_error_m of where it should be now, and from now
// up to the check horizon no sample enters what the depth frame shows occupied (FindDepthCollision) or leaves
// its view (TrajectoryInView): the test a recovery plan passes. Its velocity and acceleration were judged
// when it was sent.
bool RestIsClear(const UniformBspline& traj, double now_s, double min_rest_s,
                 const Eigen::Vector3d& p_world_vehicle, const DepthImageView& depth,
                 const CameraModel& camera, const SafetyConfig& cfg);

// Counts of verdicts (index: SafetyVerdict value).
struct VerdictCounts {
  std::array<unsigned long, kNumSafetyVerdicts> counts{};
  void Add(SafetyVerdict v) { ++counts[static_cast<int>(v)]; }
  unsigned long operator[](SafetyVerdict v) const { return counts[static_cast<int>(v)]; }
  unsigned long refused() const;
};

}  // namespace quad_policy
