// The safety layer between the network and the tracker (issue 8): a proposed trajectory is refused when its
// control points are not finite, when the control points of its derivatives exceed the velocity or
// acceleration limit (convex-hull bounds), when it starts far from the vehicle, or when it enters space that
// the latest depth frame shows occupied. The same checks, in the same order, are implemented in Python
// (quad_il/inference/safety.py); docs/inference.md describes them.
#pragma once

#include <Eigen/Geometry>

#include <array>
#include <limits>
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
  // Depth memory (docs/inference.md, "Depth memory"): samples the latest frame does not show are judged by
  // the newest of up to memory_frames earlier decision frames that shows them (0: the latest frame only),
  // kept at least memory_spacing_s apart.
  int memory_frames = 0;
  double memory_spacing_s = 0.2;
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

// An earlier depth frame the safety layer remembers: its stamp, a copy of its image and its camera.
struct DepthFrame {
  double stamp_s = 0.0;
  DepthImage image;
  CameraModel camera;
};

// The remembered frames (SafetyConfig memory_frames, memory_spacing_s): after each decision its frame is kept
// when the newest kept one is at least memory_spacing_s older; at most memory_frames are kept, the oldest
// dropped. A frame older than the newest kept (time went back: a new episode, a replayed bag) empties it
// first. The Python DepthMemory.
class DepthMemory {
 public:
  DepthMemory() = default;
  DepthMemory(int max_frames, double spacing_s);  // throws std::invalid_argument on bad values
  void Clear() { frames_.clear(); }
  // Keeps a copy of the frame if it is due; whether it was kept.
  bool Add(double stamp_s, const DepthImageView& depth, const CameraModel& camera);
  const std::vector<DepthFrame>& frames() const { return frames_; }  // newest first

 private:
  int max_frames_ = 0;
  double spacing_s_ = 0.0;
  std::vector<DepthFrame> frames_;
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
  int frame = 0;                // the frame that judged it: 0 the latest, k >= 1 the k-th remembered
  double frame_stamp_s = std::numeric_limits<double>::quiet_NaN();  // that remembered frame's stamp
};
// With a memory (newest first), a sample whose sphere does not hold the latest camera centre is judged by
// the latest frame when its centre is in that frame's view, else by the newest remembered frame whose view
// holds it, else by the latest frame (which judges the part of the sphere it sees).
DepthCollision FindDepthCollision(const std::vector<Eigen::Vector3d>& samples_world, double radius_m,
                                  int min_pixels, const DepthImageView& depth, const CameraModel& camera,
                                  const std::vector<DepthFrame>& memory = {});

// Sample times from_s + j * sample_dt_s (j = 0, 1, ...) up to the check horizon after from_s (or the
// trajectory's end), and that last time itself. from_s > 0 judges the rest of a trajectory (RestIsClear).
std::vector<double> SafetySampleTimes(const UniformBspline& traj, const SafetyConfig& cfg,
                                      double from_s = 0.0);

// All checks in order: non-finite control points; velocity; acceleration; start far from the vehicle;
// collision in the depth image (skipped when depth is null). The first failure is the verdict.
SafetyResult CheckTrajectory(const UniformBspline& traj, const Eigen::Vector3d& p_world_vehicle,
                             const DepthImageView* depth, const CameraModel& camera, const SafetyConfig& cfg,
                             const std::vector<DepthFrame>& memory = {});

// Whether the trajectory stays where the depth frame looked: every sample up to the check horizon (the times
// of SafetySampleTimes) whose sphere does not hold the camera centre has its centre in front of the camera
// and projecting inside the image. The recovery's plans must pass this besides CheckTrajectory: a plan
// turned away from the goal may leave the field of view, where the depth check cannot judge it. With a
// memory, a sample a remembered frame shows counts as in view (that frame judges it).
// from_s: judge the samples from that trajectory time on (SafetySampleTimes).
bool TrajectoryInView(const UniformBspline& traj, const CameraModel& camera, const SafetyConfig& cfg,
                      const std::vector<DepthFrame>& memory = {}, double from_s = 0.0);

// Whether the rest of a trajectory sent before (from the time now_s on) may still be flown: at least
// min_rest_s of it is left, the vehicle is within max_start_error_m of where it should be now, and from now
// up to the check horizon no sample enters what the depth frames show occupied (FindDepthCollision) or leaves
// their view (TrajectoryInView): the test a recovery plan passes. Its velocity and acceleration were judged
// when it was sent. The Python twin is quad_il.inference.safety.rest_is_clear.
bool RestIsClear(const UniformBspline& traj, double now_s, double min_rest_s,
                 const Eigen::Vector3d& p_world_vehicle, const DepthImageView& depth,
                 const CameraModel& camera, const SafetyConfig& cfg,
                 const std::vector<DepthFrame>& memory = {});

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
