#include "quad_sim/world_index.h"

#include <BulletCollision/BroadphaseCollision/btDbvt.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <queue>

namespace quad_sim {

namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();
// The tree's float AABBs are grown by this much so that float rounding never culls an exact hit.
constexpr double kAabbPad_m = 1e-4;

int LeafIndex(const btDbvtNode* node) { return static_cast<int>(reinterpret_cast<intptr_t>(node->data)); }

// Slab test of o + t d against a float AABB, t in [0, t_max]: the entry parameter or +Inf.
inline double RayAabbEntry(const btDbvtVolume& v, const Eigen::Vector3d& o, const Eigen::Vector3d& inv_d,
                           double t_max) {
  const btVector3& mn = v.Mins();
  const btVector3& mx = v.Maxs();
  double t0 = 0.0;
  double t1 = t_max;
  for (int i = 0; i < 3; ++i) {
    double a = (static_cast<double>(mn[i]) - o(i)) * inv_d(i);
    double b = (static_cast<double>(mx[i]) - o(i)) * inv_d(i);
    if (a > b) std::swap(a, b);
    // NaN (0 * Inf on a slab boundary) compares false and leaves the interval unchanged: conservative.
    if (a > t0) t0 = a;
    if (b < t1) t1 = b;
    if (t0 > t1) return kInf;
  }
  return t0;
}

inline double AabbAabbDistance(const btDbvtVolume& v, const Eigen::Vector3d& mn, const Eigen::Vector3d& mx) {
  double d2 = 0.0;
  for (int i = 0; i < 3; ++i) {
    const double gap =
        std::max({0.0, static_cast<double>(v.Mins()[i]) - mx(i), mn(i) - static_cast<double>(v.Maxs()[i])});
    d2 += gap * gap;
  }
  return std::sqrt(d2);
}

}  // namespace

WorldIndex::WorldIndex() : tree_(std::make_unique<btDbvt>()) {}
WorldIndex::~WorldIndex() = default;

void WorldIndex::Build(const World& world) {
  tree_ = std::make_unique<btDbvt>();
  boxes_ = world.boxes;
  data_.clear();
  data_.reserve(boxes_.size());
  for (size_t i = 0; i < boxes_.size(); ++i) {
    const OrientedBox& b = boxes_[i];
    data_.push_back({b.center_world_m, b.q_world_box.toRotationMatrix().transpose(), b.HalfExtents()});
    Eigen::Vector3d mn, mx;
    b.Aabb(&mn, &mx);
    mn.array() -= kAabbPad_m + 1e-6 * mn.cwiseAbs().array();
    mx.array() += kAabbPad_m + 1e-6 * mx.cwiseAbs().array();
    const btDbvtVolume vol =
        btDbvtVolume::FromMM(btVector3(mn.x(), mn.y(), mn.z()), btVector3(mx.x(), mx.y(), mx.z()));
    tree_->insert(vol, reinterpret_cast<void*>(static_cast<intptr_t>(i)));
  }
  // A top-down rebuild gives a balanced tree (the incremental inserts above are order dependent).
  tree_->optimizeTopDown();
}

bool WorldIndex::RayBox(const BoxData& b, const Eigen::Vector3d& o_world, const Eigen::Vector3d& d_world,
                        double t_best, double* t_hit) {
  const Eigen::Vector3d o = b.Rt * (o_world - b.center);
  const Eigen::Vector3d d = b.Rt * d_world;
  double t_enter = 0.0;
  double t_exit = t_best;
  for (int i = 0; i < 3; ++i) {
    if (d(i) == 0.0) {
      if (std::abs(o(i)) > b.half(i)) return false;
      continue;
    }
    const double inv = 1.0 / d(i);
    double t0 = (-b.half(i) - o(i)) * inv;
    double t1 = (b.half(i) - o(i)) * inv;
    if (t0 > t1) std::swap(t0, t1);
    if (t0 > t_enter) t_enter = t0;
    if (t1 < t_exit) t_exit = t1;
    if (t_enter > t_exit) return false;
  }
  if (t_enter >= t_best) return false;
  *t_hit = t_enter;
  return true;
}

RayHit WorldIndex::CastRay(const Eigen::Vector3d& o, const Eigen::Vector3d& d, double t_max) const {
  RayHit hit;
  hit.t = kInf;
  double best = t_max;
  // Ground plane z = 0, hit from above only.
  if (d.z() < 0.0 && o.z() >= 0.0) {
    const double t = -o.z() / d.z();
    if (t <= best) {
      best = t;
      hit.t = t;
      hit.box_index = kHitGround;
    }
  }
  const btDbvtNode* root = tree_->m_root;
  if (root == nullptr) return hit;
  Eigen::Vector3d inv_d;
  for (int i = 0; i < 3; ++i) inv_d(i) = d(i) != 0.0 ? 1.0 / d(i) : std::copysign(1e300, d(i));
  // Front-to-back traversal: the nearer child is visited first and subtrees entered beyond the best hit so
  // far are skipped (Bullet's own rayTestInternal keeps the full ray length and visits every leaf it
  // crosses).
  struct Entry {
    const btDbvtNode* node;
    double t_entry;
  };
  Entry stack[128];
  int top = 0;
  const double t_root = RayAabbEntry(root->volume, o, inv_d, best);
  if (t_root == kInf) return hit;
  stack[top++] = {root, t_root};
  while (top > 0) {
    const Entry e = stack[--top];
    if (e.t_entry > best) continue;
    if (e.node->isleaf()) {
      const int idx = LeafIndex(e.node);
      double t;
      if (RayBox(data_[idx], o, d, best, &t)) {
        best = t;
        hit.t = t;
        hit.box_index = idx;
      }
      continue;
    }
    const btDbvtNode* c0 = e.node->childs[0];
    const btDbvtNode* c1 = e.node->childs[1];
    double t0 = RayAabbEntry(c0->volume, o, inv_d, best);
    double t1 = RayAabbEntry(c1->volume, o, inv_d, best);
    if (t0 > t1) {
      std::swap(t0, t1);
      std::swap(c0, c1);
    }
    // Push the farther child first so the nearer one is popped next; the stack never exceeds the tree depth.
    if (t1 != kInf && top < 127) stack[top++] = {c1, t1};
    if (t0 != kInf && top < 127) stack[top++] = {c0, t0};
  }
  return hit;
}

std::vector<int> WorldIndex::QueryConvex(const std::vector<Eigen::Vector4d>& planes) const {
  // Tree traversal culling every node whose AABB lies entirely on the outer side of one plane (the same test
  // as btDbvt::collideKDOP, whose inlined Bullet code trips -Wmaybe-uninitialized).
  std::vector<int> out;
  const btDbvtNode* root = tree_->m_root;
  if (root == nullptr) return out;
  std::vector<const btDbvtNode*> stack{root};
  while (!stack.empty()) {
    const btDbvtNode* node = stack.back();
    stack.pop_back();
    const btVector3& mn = node->volume.Mins();
    const btVector3& mx = node->volume.Maxs();
    bool outside = false;
    for (const Eigen::Vector4d& p : planes) {
      // The AABB corner furthest along the plane normal; if even it is outside, the whole box is.
      double best = p.w();
      for (int i = 0; i < 3; ++i)
        best += p(i) * (p(i) >= 0.0 ? static_cast<double>(mx[i]) : static_cast<double>(mn[i]));
      if (best < 0.0) {
        outside = true;
        break;
      }
    }
    if (outside) continue;
    if (node->isleaf()) {
      out.push_back(LeafIndex(node));
    } else {
      stack.push_back(node->childs[0]);
      stack.push_back(node->childs[1]);
    }
  }
  std::sort(out.begin(), out.end());
  return out;
}

ClearanceResult WorldIndex::Clearance(const OrientedBox& box) const {
  ClearanceResult out;
  out.distance_m = kInf;
  const btDbvtNode* root = tree_->m_root;
  if (root == nullptr) return out;
  Eigen::Vector3d mn, mx;
  box.Aabb(&mn, &mx);
  // Best-first search on the AABB distance lower bound; exact box/box distance at the leaves.
  using Item = std::pair<double, const btDbvtNode*>;
  std::priority_queue<Item, std::vector<Item>, std::greater<Item>> open;
  open.push({AabbAabbDistance(root->volume, mn, mx), root});
  while (!open.empty()) {
    const auto [bound, node] = open.top();
    open.pop();
    if (bound >= out.distance_m) break;
    if (node->isleaf()) {
      const int idx = LeafIndex(node);
      const double d = BoxBoxDistance(box, boxes_[idx]);
      if (d < out.distance_m) {
        out.distance_m = d;
        out.box_index = idx;
      }
      continue;
    }
    for (const btDbvtNode* c : node->childs) {
      // The padded AABB may underestimate by the pad: subtract it so the bound stays a lower bound.
      const double b = std::max(0.0, AabbAabbDistance(c->volume, mn, mx) - 2.0 * kAabbPad_m);
      if (b < out.distance_m) open.push({b, c});
    }
  }
  return out;
}

}  // namespace quad_sim
