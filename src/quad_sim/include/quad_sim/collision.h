// Collision detection with Bullet: the vehicle's box against the world's boxes and the ground plane, through
// a btCollisionWorld (Dbvt broadphase, box/box and convex/plane narrowphase) queried with contactTest.
#pragma once

#include "quad_sim/world.h"

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <memory>
#include <vector>

class btCollisionConfiguration;
class btCollisionDispatcher;
class btBroadphaseInterface;
class btCollisionWorld;
class btCollisionShape;
class btCollisionObject;

namespace quad_sim {

struct Contact {
  int box_index = -1;  // world box index, or kHitGround (-2) for the ground plane
  Eigen::Vector3d point_world_m = Eigen::Vector3d::Zero();  // midpoint of the two witness points
  double penetration_m = 0.0;                               // > 0
};

class CollisionChecker {
 public:
  explicit CollisionChecker(const Eigen::Vector3d& vehicle_box_m);
  ~CollisionChecker();
  CollisionChecker(const CollisionChecker&) = delete;
  CollisionChecker& operator=(const CollisionChecker&) = delete;

  void SetWorld(const World& world);

  // Every penetrating contact of the vehicle box at pose (p_world_body, q_world_body), deepest first per
  // object.
  std::vector<Contact> Check(const Eigen::Vector3d& p_world_body, const Eigen::Quaterniond& q_world_body);

 private:
  void ClearWorldObjects();

  std::unique_ptr<btCollisionConfiguration> config_;
  std::unique_ptr<btCollisionDispatcher> dispatcher_;
  std::unique_ptr<btBroadphaseInterface> broadphase_;
  std::unique_ptr<btCollisionWorld> world_;
  std::unique_ptr<btCollisionShape> vehicle_shape_;
  std::unique_ptr<btCollisionObject> vehicle_;
  std::unique_ptr<btCollisionShape> ground_shape_;
  std::unique_ptr<btCollisionObject> ground_;
  std::vector<std::unique_ptr<btCollisionShape>> box_shapes_;
  std::vector<std::unique_ptr<btCollisionObject>> box_objects_;
};

}  // namespace quad_sim
