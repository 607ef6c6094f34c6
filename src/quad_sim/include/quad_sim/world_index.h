// Spatial index of a world's boxes: Bullet's dynamic AABB tree (btDbvt) as broadphase, exact double-precision
// box tests at the leaves. Used for depth rays (front-to-back traversal with early termination) and for the
// exact clearance between the vehicle box and the world.
#pragma once

#include "quad_sim/geometry.h"
#include "quad_sim/world.h"

#include <Eigen/Core>

#include <memory>
#include <vector>

class btDbvt;

namespace quad_sim {

// Box id conventions shared with the collision status (as quad_msgs/EpisodeStatus).
constexpr int kHitNone = -1;
constexpr int kHitGround = -2;

struct RayHit {
  double t = 0.0;            // ray parameter of the hit (units of |d|); +Inf when nothing was hit
  int box_index = kHitNone;  // index of the world box, kHitGround, or kHitNone
};

struct ClearanceResult {
  double distance_m = 0.0;   // exact minimum distance to any world box (+Inf for an empty world)
  int box_index = kHitNone;  // the nearest box
};

class WorldIndex {
 public:
  WorldIndex();
  ~WorldIndex();
  WorldIndex(const WorldIndex&) = delete;
  WorldIndex& operator=(const WorldIndex&) = delete;

  void Build(const World& world);

  // First hit of o + t d for t in [0, t_max] against the boxes and the ground plane z = 0 (the ground is only
  // hit from above).
  RayHit CastRay(const Eigen::Vector3d& o_world, const Eigen::Vector3d& d_world, double t_max) const;

  // Exact minimum distance from a box to the world's boxes (ground excluded).
  ClearanceResult Clearance(const OrientedBox& box) const;

  // Indices (ascending) of the boxes whose tree AABB is not entirely outside the convex region
  // {x : n_i . x + offset_i >= 0 for all planes i} (planes as (n, offset)); a conservative frustum cull.
  std::vector<int> QueryConvex(const std::vector<Eigen::Vector4d>& planes) const;

  size_t size() const { return boxes_.size(); }
  const std::vector<OrientedBox>& boxes() const { return boxes_; }

 private:
  // Per-box data laid out for the ray test: centre, rotation rows (world -> box) and half extents.
  struct BoxData {
    Eigen::Vector3d center;
    Eigen::Matrix3d Rt;
    Eigen::Vector3d half;
  };
  static bool RayBox(const BoxData& b, const Eigen::Vector3d& o, const Eigen::Vector3d& d, double t_best,
                     double* t_hit);

  std::unique_ptr<btDbvt> tree_;
  std::vector<OrientedBox> boxes_;
  std::vector<BoxData> data_;
};

}  // namespace quad_sim
