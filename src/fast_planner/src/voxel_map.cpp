#include "fast_planner/voxel_map.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>

namespace fast_planner {

namespace {

float LogOddsOf(double p) { return static_cast<float>(std::log(p / (1.0 - p))); }

constexpr uint8_t kHitBit = 1;
constexpr uint8_t kMissBit = 2;

}  // namespace

std::string ValidateDepthFrame(const DepthFrame& f) {
  std::ostringstream s;
  const auto& k = f.intrinsics;
  if (k.width <= 0 || k.height <= 0) {
    s << "image size " << k.width << "x" << k.height << " is not positive";
    return s.str();
  }
  if (f.image.width != k.width || f.image.height != k.height) {
    s << "depth image is " << f.image.width << "x" << f.image.height << ", the intrinsics are " << k.width
      << "x" << k.height;
    return s.str();
  }
  if (f.image.depth_m.size() != static_cast<size_t>(k.width) * static_cast<size_t>(k.height)) {
    s << "depth has " << f.image.depth_m.size() << " values for a " << k.width << "x" << k.height << " image";
    return s.str();
  }
  if (!(std::isfinite(k.fx) && std::isfinite(k.fy) && k.fx > 0.0 && k.fy > 0.0)) {
    s << "focal lengths fx=" << k.fx << " fy=" << k.fy << " must be finite and positive";
    return s.str();
  }
  if (!(std::isfinite(k.cx) && std::isfinite(k.cy))) return "principal point is not finite";
  if (!f.p_world_camera.allFinite()) return "camera position is not finite";
  if (!f.q_world_camera.coeffs().allFinite() || f.q_world_camera.norm() < 1e-6) {
    return "camera orientation is not a finite non-zero quaternion";
  }
  if (!std::isfinite(f.stamp_s)) return "stamp is not finite";
  return "";
}

VoxelMap::VoxelMap(const MapConfig& cfg) : cfg_(cfg) {
  ValidateMapConfig(cfg);

  resolution_ = cfg.resolution_m;
  inv_resolution_ = 1.0 / resolution_;
  origin_ = cfg.origin_m;
  size_ = (cfg.size_m / resolution_).array().round().cast<int>();
  ground_layer_ = static_cast<int>(std::floor((cfg.ground_z_m - origin_.z()) * inv_resolution_ - 0.5 + 1e-9));
  ceiling_layer_ =
      static_cast<int>(std::ceil((cfg.ceiling_z_m - origin_.z()) * inv_resolution_ - 0.5 - 1e-9));
  const double r_vox = cfg.inflation_m * inv_resolution_;
  inflation_voxels_ = static_cast<int>(std::floor(r_vox + 1e-9));
  for (int dz = -inflation_voxels_; dz <= inflation_voxels_; ++dz) {
    for (int dy = -inflation_voxels_; dy <= inflation_voxels_; ++dy) {
      for (int dx = -inflation_voxels_; dx <= inflation_voxels_; ++dx) {
        if (dx * dx + dy * dy + dz * dz <= r_vox * r_vox + 1e-9) inflation_offsets_.emplace_back(dx, dy, dz);
      }
    }
  }
  const auto& d = cfg.depth;
  l_hit_ = LogOddsOf(d.prob_hit);
  l_miss_ = LogOddsOf(d.prob_miss);
  l_min_ = LogOddsOf(d.prob_min);
  l_max_ = LogOddsOf(d.prob_max);
  l_occupied_ = LogOddsOf(d.prob_occupied);

  // inflation_offsets_ is ordered by (dz, dy, dx) and a ball's x extent is contiguous for every (dy, dz).
  for (size_t i = 0; i < inflation_offsets_.size();) {
    size_t j = i;
    while (j < inflation_offsets_.size() && inflation_offsets_[j].y() == inflation_offsets_[i].y() &&
           inflation_offsets_[j].z() == inflation_offsets_[i].z()) {
      ++j;
    }
    inflation_runs_.emplace_back(Linear(inflation_offsets_[i]), static_cast<int>(j - i));
    i = j;
  }

  const size_t n = static_cast<size_t>(size_.x()) * size_.y() * size_.z();
  log_odds_.assign(n, 0.0f);
  occupied_.assign(n, 0);
  inflate_count_.assign(n, 0);
}

void VoxelMap::Reset() {
  std::fill(log_odds_.begin(), log_odds_.end(), 0.0f);
  std::fill(occupied_.begin(), occupied_.end(), 0);
  std::fill(inflate_count_.begin(), inflate_count_.end(), 0);
}

bool VoxelMap::InMap(const Eigen::Vector3d& p) const {
  const Eigen::Vector3d hi = max_corner();
  return (p.array() >= origin_.array()).all() && (p.array() < hi.array()).all();
}

bool VoxelMap::IsOccupied(const Eigen::Vector3i& idx) const {
  if (idx.z() <= ground_layer_ || idx.z() >= ceiling_layer_) return true;
  if (!InMap(idx)) return false;
  return occupied_[Linear(idx)] != 0;
}

bool VoxelMap::IsInflated(const Eigen::Vector3i& idx) const {
  if (!InMap(idx)) return true;
  if (idx.z() <= ground_layer_ + inflation_voxels_ || idx.z() >= ceiling_layer_ - inflation_voxels_)
    return true;
  return inflate_count_[Linear(idx)] != 0;
}

void VoxelMap::LocalWindow(const Eigen::Vector3d& p_center, Eigen::Vector3i* min_idx,
                           Eigen::Vector3i* max_idx) const {
  const Eigen::Vector3i c = ToIndex(p_center);
  const Eigen::Vector3i half = (cfg_.local_update_range_m * inv_resolution_).array().ceil().cast<int>();
  *min_idx = (c - half).cwiseMax(Eigen::Vector3i::Zero());
  *max_idx = (c + half).cwiseMin(size_ - Eigen::Vector3i::Ones());
}

void VoxelMap::ExtractObservedOccupancy(const Eigen::Vector3i& min_idx, const Eigen::Vector3i& max_idx,
                                        std::vector<uint8_t>* occupied) const {
  if (!InMap(min_idx) || !InMap(max_idx) || (min_idx.array() > max_idx.array()).any()) {
    throw std::invalid_argument("VoxelMap::ExtractObservedOccupancy: box is empty or outside the map");
  }
  const Eigen::Vector3i n = max_idx - min_idx + Eigen::Vector3i::Ones();
  occupied->resize(static_cast<size_t>(n.x()) * n.y() * n.z());
  uint8_t* out = occupied->data();
  for (int z = min_idx.z(); z <= max_idx.z(); ++z) {
    for (int y = min_idx.y(); y <= max_idx.y(); ++y) {
      const uint8_t* row = occupied_.data() + Linear(Eigen::Vector3i(min_idx.x(), y, z));
      std::copy(row, row + n.x(), out);
      out += n.x();
    }
  }
}

int64_t VoxelMap::CountOccupied() const { return std::count(occupied_.begin(), occupied_.end(), uint8_t{1}); }

void VoxelMap::SetOccupiedFlag(int64_t lin, const Eigen::Vector3i& idx, bool occupied) {
  occupied_[lin] = occupied ? 1 : 0;
  const int r = inflation_voxels_;
  if ((idx.array() >= r).all() && (idx.array() < size_.array() - r).all()) {
    uint16_t* c = inflate_count_.data() + lin;
    const uint16_t step = occupied ? 1 : static_cast<uint16_t>(-1);  // uint16 wrap-around: -1
    for (const auto& [offset, length] : inflation_runs_) {
      uint16_t* run = c + offset;
      for (int k = 0; k < length; ++k) run[k] = static_cast<uint16_t>(run[k] + step);
    }
    return;
  }
  for (const auto& o : inflation_offsets_) {
    const Eigen::Vector3i j = idx + o;
    if (!InMap(j)) continue;
    uint16_t& c = inflate_count_[Linear(j)];
    c = occupied ? static_cast<uint16_t>(c + 1) : static_cast<uint16_t>(c - 1);
  }
}

int VoxelMap::SetOccupied(const std::vector<Eigen::Vector3d>& p_world) {
  int inside = 0;
  for (const auto& p : p_world) {
    if (!p.allFinite() || !InMap(p)) continue;
    ++inside;
    const Eigen::Vector3i idx = ToIndex(p);
    const int64_t lin = Linear(idx);
    log_odds_[lin] = l_max_;
    if (!occupied_[lin]) SetOccupiedFlag(lin, idx, true);
  }
  return inside;
}

MapUpdateStats VoxelMap::IntegrateDepth(const DepthFrame& frame) {
  const std::string why = ValidateDepthFrame(frame);
  if (!why.empty()) throw std::invalid_argument("VoxelMap::IntegrateDepth: " + why);
  MapUpdateStats stats;

  const auto& k = frame.intrinsics;
  const auto& dc = cfg_.depth;
  const Eigen::Matrix3d R = frame.q_world_camera.normalized().toRotationMatrix();
  const Eigen::Vector3d cam = frame.p_world_camera;
  const Eigen::Vector3d cam_vox = (cam - origin_) * inv_resolution_;  // camera in voxel units
  const Eigen::Vector3d lo = origin_.array() + 1e-6 * resolution_;
  const Eigen::Vector3d hi = max_corner().array() - 1e-6 * resolution_;

  // Every voxel a ray visits lies within max_ray_length of the camera: the per-frame marks live in a small
  // dense buffer over that box (cache friendly), and only the distinct voxels touched are then written to the
  // map (Fast-Planner's per-frame flags span the whole map).
  // The box is not clipped to the map, and has a voxel of margin: a walk never leaves it, even where rounding
  // makes it step one voxel beside the exact line; voxels outside the map are dropped when the marks are
  // applied.
  const int reach = static_cast<int>(std::ceil(dc.max_ray_length_m * inv_resolution_)) + 2;
  const Eigen::Vector3i cam_idx = cam_vox.array().floor().cast<int>();
  const Eigen::Vector3i box_lo = cam_idx.array() - reach;
  const Eigen::Vector3i box_n = Eigen::Vector3i::Constant(2 * reach + 1);
  const int64_t box_nxy = static_cast<int64_t>(box_n.x()) * box_n.y();
  // The box's size depends on the configuration only: its marks are allocated once and left all zero after
  // every frame (only the touched voxels are cleared), and the list of touched voxels has room for the whole
  // box, so the walk below neither allocates nor checks a capacity (issue 32: this loop is most of a frame).
  const size_t box_voxels = static_cast<size_t>(box_nxy) * box_n.z();
  if (local_mark_.size() != box_voxels) {
    local_mark_.assign(box_voxels, 0);
    touched_.resize(box_voxels + 1);  // + 1: the branch-free mark writes one past the last kept entry
  }
  uint8_t* const marks = local_mark_.data();
  int64_t* const touched = touched_.data();
  size_t n_touched = 0;
  auto mark = [marks, touched, &n_touched](int64_t local, uint8_t bits) {
    uint8_t& m = marks[local];
    touched[n_touched] = local;  // kept only if the voxel was not marked yet (no branch)
    n_touched += m == 0 ? 1 : 0;
    m |= bits;
  };

  for (int v = 0; v < k.height; v += dc.skip_pixel) {
    for (int u = 0; u < k.width; u += dc.skip_pixel) {
      const float d = frame.image.depth_m[static_cast<size_t>(v) * k.width + u];
      if (std::isnan(d) || d == -std::numeric_limits<float>::infinity()) continue;
      const Eigen::Vector3d dir_c((u - k.cx) / k.fx, (v - k.cy) / k.fy, 1.0);  // depth 1 m along the ray
      const double range_per_depth = dir_c.norm();
      bool hit = true;
      double depth = d;
      if (std::isinf(d) || d * range_per_depth > dc.max_ray_length_m) {
        hit = false;
        depth = dc.max_ray_length_m / range_per_depth;
      } else if (d * range_per_depth < dc.min_ray_length_m) {
        continue;
      }
      Eigen::Vector3d end = cam + R * (dir_c * depth);
      if (!InMap(end)) {
        // Liang-Barsky: keep the part of the segment camera -> end inside the map box.
        const Eigen::Vector3d seg = end - cam;
        double t0 = 0.0, t1 = 1.0;
        bool inside = true;
        for (int a = 0; a < 3 && inside; ++a) {
          if (std::abs(seg[a]) < 1e-12) {
            inside = cam[a] >= lo[a] && cam[a] <= hi[a];
            continue;
          }
          double ta = (lo[a] - cam[a]) / seg[a];
          double tb = (hi[a] - cam[a]) / seg[a];
          if (ta > tb) std::swap(ta, tb);
          t0 = std::max(t0, ta);
          t1 = std::min(t1, tb);
          inside = t0 <= t1;
        }
        if (!inside) continue;
        end = cam + seg * t1;
        hit = false;
        if (!InMap(end)) continue;
      }
      ++stats.rays;

      // Walk the voxels from the return back toward the camera (Amanatides & Woo), on the box's linear index.
      // Every ray is walked to the end: stopping at a voxel an earlier ray traversed (Fast-Planner's
      // shortcut) leaves voxels uncleared.
      const Eigen::Vector3d s = (end - origin_) * inv_resolution_;
      const Eigen::Vector3d dir = cam_vox - s;
      const Eigen::Vector3i idx = s.array().floor().cast<int>();
      if (((idx - cam_idx).array().abs() >= reach).any()) continue;  // only through rounding at the very edge
      const int64_t stride[3] = {1, box_n.x(), box_nxy};
      int64_t move[3];
      double t_max[3], t_delta[3];
      int steps = 0;
      for (int a = 0; a < 3; ++a) {
        steps += std::abs(cam_idx[a] - idx[a]);
        if (dir[a] > 0.0) {
          move[a] = stride[a];
          t_max[a] = (idx[a] + 1 - s[a]) / dir[a];
          t_delta[a] = 1.0 / dir[a];
        } else if (dir[a] < 0.0) {
          move[a] = -stride[a];
          t_max[a] = (idx[a] - s[a]) / dir[a];
          t_delta[a] = -1.0 / dir[a];
        } else {
          move[a] = 0;
          t_max[a] = std::numeric_limits<double>::infinity();
          t_delta[a] = std::numeric_limits<double>::infinity();
        }
      }
      const Eigen::Vector3i l = idx - box_lo;
      int64_t local = l.x() + box_n.x() * (l.y() + static_cast<int64_t>(box_n.y()) * l.z());
      mark(local, hit ? kHitBit : kMissBit);
      // The axis of each step is the one of the smallest t_max (ties: z over x and y, y over x), on scalars
      // rather than the arrays indexed by the axis: the same comparisons and sums (bit-identical walks),
      // without a store-to-load dependency through memory on every step.
      double tx = t_max[0], ty = t_max[1], tz = t_max[2];
      for (int i = 0; i < steps; ++i) {
        if (tx < ty) {
          if (tx < tz) {
            local += move[0];
            tx += t_delta[0];
          } else {
            local += move[2];
            tz += t_delta[2];
          }
        } else if (ty < tz) {
          local += move[1];
          ty += t_delta[1];
        } else {
          local += move[2];
          tz += t_delta[2];
        }
        mark(local, kMissBit);
      }
    }
  }

  for (size_t i = 0; i < n_touched; ++i) {
    const int64_t local = touched[i];
    const uint8_t bits = marks[local];
    marks[local] = 0;
    const Eigen::Vector3i idx = box_lo + Eigen::Vector3i(static_cast<int>(local % box_n.x()),
                                                         static_cast<int>((local % box_nxy) / box_n.x()),
                                                         static_cast<int>(local / box_nxy));
    if (!InMap(idx)) continue;
    const int64_t lin = Linear(idx);
    const bool is_hit = (bits & kHitBit) != 0;
    float& l = log_odds_[lin];
    const float old = l;
    l = std::clamp(l + (is_hit ? l_hit_ : l_miss_), l_min_, l_max_);
    if (l != old) ++stats.voxels_updated;
    const bool occ = l > l_occupied_;
    if (occ != (occupied_[lin] != 0)) {
      SetOccupiedFlag(lin, idx, occ);
      ++(occ ? stats.newly_occupied : stats.newly_free);
    }
  }
  return stats;
}

}  // namespace fast_planner
