// Exact geometry of oriented boxes in double precision: ray intersection, point/box and box/box distances.
//
// Bullet's own queries run in single precision with collision margins; the depth camera (1 mm accuracy) and
// the planner's clearance metric need exact distances, so these few closed-form routines are written here.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <array>
#include <limits>

namespace quad_sim {

struct OrientedBox {
  Eigen::Vector3d center_world_m = Eigen::Vector3d::Zero();
  Eigen::Quaterniond q_world_box = Eigen::Quaterniond::Identity();
  Eigen::Vector3d size_m = Eigen::Vector3d::Ones();  // full edge lengths along the box's own axes

  Eigen::Vector3d HalfExtents() const { return 0.5 * size_m; }
  std::array<Eigen::Vector3d, 8> Corners() const;
  // Axis-aligned bounding box in the world frame.
  void Aabb(Eigen::Vector3d* min_world, Eigen::Vector3d* max_world) const;
};

// Smallest t >= 0 at which o + t d enters the box (0 when o is inside), +Inf when the ray misses. d need not
// be unit length: t is in units of |d|.
double RayBoxEntry(const Eigen::Vector3d& o_world, const Eigen::Vector3d& d_world, const OrientedBox& box);

// Euclidean distance from a point to the solid box (0 inside).
double PointBoxDistance(const Eigen::Vector3d& p_world, const OrientedBox& box);

// Separating-axis test (15 axes): true when the solid boxes intersect or touch.
bool BoxesOverlap(const OrientedBox& a, const OrientedBox& b);

// Exact minimum Euclidean distance between two solid boxes (0 when they overlap). For separated convex
// polyhedra the closest pair is realised by a vertex of one against the other solid, or by two edges, so the
// minimum over 16 vertex/box and 144 edge/edge distances is exact.
double BoxBoxDistance(const OrientedBox& a, const OrientedBox& b);

// Minimum distance between segments [p0, p1] and [q0, q1].
double SegmentSegmentDistance(const Eigen::Vector3d& p0, const Eigen::Vector3d& p1, const Eigen::Vector3d& q0,
                              const Eigen::Vector3d& q1);

}  // namespace quad_sim
