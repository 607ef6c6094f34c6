#include "quad_sim/geometry.h"

#include <algorithm>
#include <cmath>

namespace quad_sim {

std::array<Eigen::Vector3d, 8> OrientedBox::Corners() const {
  const Eigen::Matrix3d R = q_world_box.toRotationMatrix();
  const Eigen::Vector3d h = HalfExtents();
  std::array<Eigen::Vector3d, 8> out;
  int k = 0;
  for (int sx = -1; sx <= 1; sx += 2) {
    for (int sy = -1; sy <= 1; sy += 2) {
      for (int sz = -1; sz <= 1; sz += 2) {
        out[k++] = center_world_m + R * Eigen::Vector3d(sx * h.x(), sy * h.y(), sz * h.z());
      }
    }
  }
  return out;
}

void OrientedBox::Aabb(Eigen::Vector3d* min_world, Eigen::Vector3d* max_world) const {
  const Eigen::Matrix3d R = q_world_box.toRotationMatrix();
  const Eigen::Vector3d extent = R.cwiseAbs() * HalfExtents();
  *min_world = center_world_m - extent;
  *max_world = center_world_m + extent;
}

double RayBoxEntry(const Eigen::Vector3d& o_world, const Eigen::Vector3d& d_world, const OrientedBox& box) {
  const Eigen::Matrix3d Rt = box.q_world_box.toRotationMatrix().transpose();
  const Eigen::Vector3d o = Rt * (o_world - box.center_world_m);
  const Eigen::Vector3d d = Rt * d_world;
  const Eigen::Vector3d h = box.HalfExtents();
  double t_enter = 0.0;
  double t_exit = std::numeric_limits<double>::infinity();
  for (int i = 0; i < 3; ++i) {
    if (d(i) == 0.0) {
      if (std::abs(o(i)) > h(i)) return std::numeric_limits<double>::infinity();
      continue;
    }
    const double inv = 1.0 / d(i);
    double t0 = (-h(i) - o(i)) * inv;
    double t1 = (h(i) - o(i)) * inv;
    if (t0 > t1) std::swap(t0, t1);
    t_enter = std::max(t_enter, t0);
    t_exit = std::min(t_exit, t1);
    if (t_enter > t_exit) return std::numeric_limits<double>::infinity();
  }
  return t_enter;
}

double PointBoxDistance(const Eigen::Vector3d& p_world, const OrientedBox& box) {
  const Eigen::Vector3d q = box.q_world_box.toRotationMatrix().transpose() * (p_world - box.center_world_m);
  const Eigen::Vector3d h = box.HalfExtents();
  const Eigen::Vector3d outside = (q.cwiseAbs() - h).cwiseMax(0.0);
  return outside.norm();
}

bool BoxesOverlap(const OrientedBox& a, const OrientedBox& b) {
  // Gottschalk, Lin, Manocha, "OBBTree", SIGGRAPH 1996: separating axis test in a's frame.
  const Eigen::Matrix3d Ra = a.q_world_box.toRotationMatrix();
  const Eigen::Matrix3d Rb = b.q_world_box.toRotationMatrix();
  const Eigen::Matrix3d C = Ra.transpose() * Rb;  // b's axes in a's frame
  const Eigen::Vector3d T = Ra.transpose() * (b.center_world_m - a.center_world_m);
  const Eigen::Vector3d ha = a.HalfExtents();
  const Eigen::Vector3d hb = b.HalfExtents();
  // A small epsilon keeps near-parallel edge cross products from producing false separations.
  const Eigen::Matrix3d absC = C.cwiseAbs().array() + 1e-12;
  for (int i = 0; i < 3; ++i) {
    if (std::abs(T(i)) > ha(i) + absC.row(i).dot(hb)) return false;
  }
  for (int j = 0; j < 3; ++j) {
    if (std::abs(T.dot(C.col(j))) > ha.dot(absC.col(j)) + hb(j)) return false;
  }
  for (int i = 0; i < 3; ++i) {
    const int i1 = (i + 1) % 3;
    const int i2 = (i + 2) % 3;
    for (int j = 0; j < 3; ++j) {
      const int j1 = (j + 1) % 3;
      const int j2 = (j + 2) % 3;
      const double ra = ha(i1) * absC(i2, j) + ha(i2) * absC(i1, j);
      const double rb = hb(j1) * absC(i, j2) + hb(j2) * absC(i, j1);
      const double t = std::abs(T(i2) * C(i1, j) - T(i1) * C(i2, j));
      if (t > ra + rb) return false;
    }
  }
  return true;
}

double SegmentSegmentDistance(const Eigen::Vector3d& p0, const Eigen::Vector3d& p1, const Eigen::Vector3d& q0,
                              const Eigen::Vector3d& q1) {
  // Closest points of two segments (Ericson, Real-Time Collision Detection, 5.1.9), with clamping.
  const Eigen::Vector3d d1 = p1 - p0;
  const Eigen::Vector3d d2 = q1 - q0;
  const Eigen::Vector3d r = p0 - q0;
  const double a = d1.squaredNorm();
  const double e = d2.squaredNorm();
  const double f = d2.dot(r);
  double s = 0.0;
  double t = 0.0;
  if (a <= 0.0 && e <= 0.0) return r.norm();
  if (a <= 0.0) {
    t = std::clamp(f / e, 0.0, 1.0);
  } else {
    const double c = d1.dot(r);
    if (e <= 0.0) {
      s = std::clamp(-c / a, 0.0, 1.0);
    } else {
      const double b = d1.dot(d2);
      const double denom = a * e - b * b;
      s = denom > 1e-14 * a * e ? std::clamp((b * f - c * e) / denom, 0.0, 1.0) : 0.0;
      t = (b * s + f) / e;
      if (t < 0.0) {
        t = 0.0;
        s = std::clamp(-c / a, 0.0, 1.0);
      } else if (t > 1.0) {
        t = 1.0;
        s = std::clamp((b - c) / a, 0.0, 1.0);
      }
    }
  }
  return ((p0 + s * d1) - (q0 + t * d2)).norm();
}

namespace {

// Edges of a box as corner index pairs (corners ordered by (sx, sy, sz) bits as in Corners()).
constexpr std::array<std::array<int, 2>, 12> kEdges = {
    {{0, 1}, {2, 3}, {4, 5}, {6, 7}, {0, 2}, {1, 3}, {4, 6}, {5, 7}, {0, 4}, {1, 5}, {2, 6}, {3, 7}}};

}  // namespace

double BoxBoxDistance(const OrientedBox& a, const OrientedBox& b) {
  if (BoxesOverlap(a, b)) return 0.0;
  const auto ca = a.Corners();
  const auto cb = b.Corners();
  double best = std::numeric_limits<double>::infinity();
  for (const auto& c : ca) best = std::min(best, PointBoxDistance(c, b));
  for (const auto& c : cb) best = std::min(best, PointBoxDistance(c, a));
  for (const auto& ea : kEdges) {
    for (const auto& eb : kEdges) {
      best = std::min(best, SegmentSegmentDistance(ca[ea[0]], ca[ea[1]], cb[eb[0]], cb[eb[1]]));
    }
  }
  return best;
}

}  // namespace quad_sim
