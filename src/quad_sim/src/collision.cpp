#include "quad_sim/collision.h"

#include "quad_sim/world_index.h"

#include <btBulletCollisionCommon.h>

#include <algorithm>
#include <map>

namespace quad_sim {

namespace {

btVector3 ToBt(const Eigen::Vector3d& v) { return btVector3(v.x(), v.y(), v.z()); }
btQuaternion ToBt(const Eigen::Quaterniond& q) { return btQuaternion(q.x(), q.y(), q.z(), q.w()); }

// Collects penetrating contacts of the vehicle object, keeping the deepest per other object.
struct DeepestContacts : public btCollisionWorld::ContactResultCallback {
  explicit DeepestContacts(const btCollisionObject* vehicle) : vehicle_(vehicle) {}
  btScalar addSingleResult(btManifoldPoint& cp, const btCollisionObjectWrapper* a, int, int,
                           const btCollisionObjectWrapper* b, int, int) override {
    if (cp.getDistance() >= 0.0)
      return 0;  // touching or separated within the contact threshold: no collision
    const btCollisionObject* other =
        a->getCollisionObject() == vehicle_ ? b->getCollisionObject() : a->getCollisionObject();
    const int id = other->getUserIndex();
    const btVector3 mid = 0.5 * (cp.getPositionWorldOnA() + cp.getPositionWorldOnB());
    Contact c;
    c.box_index = id;
    c.point_world_m = Eigen::Vector3d(mid.x(), mid.y(), mid.z());
    c.penetration_m = -cp.getDistance();
    auto it = by_object.find(id);
    if (it == by_object.end() || it->second.penetration_m < c.penetration_m) by_object[id] = c;
    return 0;
  }
  const btCollisionObject* vehicle_;
  std::map<int, Contact> by_object;  // ordered by id: deterministic output order
};

}  // namespace

CollisionChecker::CollisionChecker(const Eigen::Vector3d& vehicle_box_m)
    : config_(std::make_unique<btDefaultCollisionConfiguration>()),
      dispatcher_(std::make_unique<btCollisionDispatcher>(config_.get())),
      broadphase_(std::make_unique<btDbvtBroadphase>()),
      world_(std::make_unique<btCollisionWorld>(dispatcher_.get(), broadphase_.get(), config_.get())) {
  // Zero margins: the box/box detector and the plane test then see the exact boxes.
  auto* box = new btBoxShape(ToBt(0.5 * vehicle_box_m));
  box->setMargin(0.0);
  vehicle_shape_.reset(box);
  vehicle_ = std::make_unique<btCollisionObject>();
  vehicle_->setCollisionShape(vehicle_shape_.get());
  vehicle_->setUserIndex(kHitNone);
  world_->addCollisionObject(vehicle_.get());

  auto* plane = new btStaticPlaneShape(btVector3(0, 0, 1), 0.0);
  plane->setMargin(0.0);
  ground_shape_.reset(plane);
  ground_ = std::make_unique<btCollisionObject>();
  ground_->setCollisionShape(ground_shape_.get());
  ground_->setUserIndex(kHitGround);
  world_->addCollisionObject(ground_.get());
  // Static objects never move: only the vehicle's AABB is refreshed before each query.
  world_->setForceUpdateAllAabbs(false);
}

CollisionChecker::~CollisionChecker() {
  ClearWorldObjects();
  world_->removeCollisionObject(ground_.get());
  world_->removeCollisionObject(vehicle_.get());
}

void CollisionChecker::ClearWorldObjects() {
  for (auto& o : box_objects_) world_->removeCollisionObject(o.get());
  box_objects_.clear();
  box_shapes_.clear();
}

void CollisionChecker::SetWorld(const World& world) {
  ClearWorldObjects();
  for (size_t i = 0; i < world.boxes.size(); ++i) {
    const OrientedBox& b = world.boxes[i];
    auto* shape = new btBoxShape(ToBt(b.HalfExtents()));
    shape->setMargin(0.0);
    box_shapes_.emplace_back(shape);
    auto obj = std::make_unique<btCollisionObject>();
    obj->setCollisionShape(shape);
    obj->setWorldTransform(btTransform(ToBt(b.q_world_box), ToBt(b.center_world_m)));
    obj->setUserIndex(static_cast<int>(i));
    world_->addCollisionObject(obj.get(), btBroadphaseProxy::StaticFilter,
                               btBroadphaseProxy::AllFilter ^ btBroadphaseProxy::StaticFilter);
    box_objects_.push_back(std::move(obj));
  }
}

std::vector<Contact> CollisionChecker::Check(const Eigen::Vector3d& p_world_body,
                                             const Eigen::Quaterniond& q_world_body) {
  vehicle_->setWorldTransform(btTransform(ToBt(q_world_body), ToBt(p_world_body)));
  world_->updateSingleAabb(vehicle_.get());
  DeepestContacts cb(vehicle_.get());
  world_->contactTest(vehicle_.get(), cb);
  std::vector<Contact> out;
  out.reserve(cb.by_object.size());
  for (const auto& kv : cb.by_object) out.push_back(kv.second);
  return out;
}

}  // namespace quad_sim
