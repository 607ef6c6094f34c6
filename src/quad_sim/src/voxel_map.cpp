#include "quad_sim/voxel_map.h"

#include <octomap/OcTree.h>

#include <cmath>
#include <stdexcept>

namespace quad_sim {

VoxelMap VoxelMap::FromWorld(const World& world, const VoxelMapConfig& config) {
  if (!(config.resolution_m > 0.0) || !std::isfinite(config.resolution_m)) {
    throw std::invalid_argument("VoxelMapConfig: resolution_m must be > 0");
  }
  VoxelMap m;
  const double res = config.resolution_m;
  m.resolution_m_ = res;
  Eigen::Vector3i lo, hi;
  for (int i = 0; i < 3; ++i) {
    lo(i) = static_cast<int>(std::floor(world.bounds_min_m(i) / res));
    hi(i) = static_cast<int>(std::ceil(world.bounds_max_m(i) / res));
  }
  m.dims_ = hi - lo;
  if ((m.dims_.array() <= 0).any()) throw std::invalid_argument("VoxelMap: empty bounds");
  m.origin_center_m_ = (lo.cast<double>().array() + 0.5).matrix() * res;
  m.occupied_.assign(static_cast<size_t>(m.dims_.x()) * m.dims_.y() * m.dims_.z(), 0);
  const Eigen::Vector3d half_voxel = Eigen::Vector3d::Constant(0.5 * res);
  const double voxel_radius = half_voxel.norm();
  for (const OrientedBox& box : world.boxes) {
    Eigen::Vector3d mn, mx;
    box.Aabb(&mn, &mx);
    const Eigen::Matrix3d Rt = box.q_world_box.toRotationMatrix().transpose();
    const Eigen::Vector3d h = box.HalfExtents();
    Eigen::Vector3i a, b;
    for (int i = 0; i < 3; ++i) {
      a(i) = std::max(0, static_cast<int>(std::floor(mn(i) / res)) - lo(i));
      b(i) = std::min(m.dims_(i) - 1, static_cast<int>(std::floor(mx(i) / res)) - lo(i));
    }
    OrientedBox voxel;
    voxel.size_m = Eigen::Vector3d::Constant(res);
    for (int iz = a.z(); iz <= b.z(); ++iz) {
      for (int iy = a.y(); iy <= b.y(); ++iy) {
        for (int ix = a.x(); ix <= b.x(); ++ix) {
          uint8_t& cell = m.occupied_[m.Index(ix, iy, iz)];
          if (cell) continue;
          const Eigen::Vector3d c = m.origin_center_m_ + res * Eigen::Vector3d(ix, iy, iz);
          // Cheap accept/reject by the voxel's bounding sphere, exact separating-axis test in between.
          const Eigen::Vector3d q = Rt * (c - box.center_world_m);
          const Eigen::Vector3d outside = (q.cwiseAbs() - h).cwiseMax(0.0);
          const double dist = outside.norm();
          if (dist > voxel_radius) continue;
          bool hit = (q.cwiseAbs() - h).maxCoeff() <= -voxel_radius || dist == 0.0;
          if (!hit) {
            voxel.center_world_m = c;
            hit = BoxesOverlap(voxel, box);
          }
          if (hit) cell = 1;
        }
      }
    }
  }
  for (uint8_t c : m.occupied_) m.num_occupied_ += c;
  return m;
}

bool VoxelMap::IsOccupied(int ix, int iy, int iz) const {
  if (ix < 0 || iy < 0 || iz < 0 || ix >= dims_.x() || iy >= dims_.y() || iz >= dims_.z()) return false;
  return occupied_[Index(ix, iy, iz)] != 0;
}

bool VoxelMap::IsOccupiedAt(const Eigen::Vector3d& p) const {
  const Eigen::Vector3d f = (p - origin_center_m_) / resolution_m_;
  return IsOccupied(static_cast<int>(std::floor(f.x() + 0.5)), static_cast<int>(std::floor(f.y() + 0.5)),
                    static_cast<int>(std::floor(f.z() + 0.5)));
}

std::vector<Eigen::Vector3f> VoxelMap::OccupiedCenters() const {
  std::vector<Eigen::Vector3f> out;
  out.reserve(num_occupied_);
  for (int iz = 0; iz < dims_.z(); ++iz) {
    for (int iy = 0; iy < dims_.y(); ++iy) {
      for (int ix = 0; ix < dims_.x(); ++ix) {
        if (occupied_[Index(ix, iy, iz)]) {
          out.push_back((origin_center_m_ + resolution_m_ * Eigen::Vector3d(ix, iy, iz)).cast<float>());
        }
      }
    }
  }
  return out;
}

void VoxelMap::WriteOctomap(const std::string& path) const {
  octomap::OcTree tree(resolution_m_);
  for (int iz = 0; iz < dims_.z(); ++iz) {
    for (int iy = 0; iy < dims_.y(); ++iy) {
      for (int ix = 0; ix < dims_.x(); ++ix) {
        if (!occupied_[Index(ix, iy, iz)]) continue;
        const Eigen::Vector3d c = origin_center_m_ + resolution_m_ * Eigen::Vector3d(ix, iy, iz);
        tree.updateNode(octomap::point3d(c.x(), c.y(), c.z()), true, true);
      }
    }
  }
  tree.updateInnerOccupancy();
  tree.prune();
  if (!tree.writeBinary(path)) throw std::runtime_error("VoxelMap: cannot write OctoMap file '" + path + "'");
}

}  // namespace quad_sim
