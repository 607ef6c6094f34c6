#include "quad_sim/depth_camera.h"

#include "quad_sim/math_utils.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>
#include <thread>

namespace quad_sim {

quad_core::CameraIntrinsics DepthCameraConfig::FastPlannerFov(int width, int height) {
  quad_core::CameraIntrinsics k;
  k.width = width;
  k.height = height;
  // Fast-Planner's simulated depth camera: 640 x 480, fx = fy = 387.2. Same field of view at any resolution.
  k.fx = 387.2 * width / 640.0;
  k.fy = 387.2 * height / 480.0;
  // Pixel (u, v) integer coordinates are pixel centres, so the symmetric principal point is (w - 1) / 2.
  k.cx = 0.5 * (width - 1);
  k.cy = 0.5 * (height - 1);
  return k;
}

void DepthCameraConfig::Validate() const {
  auto fail = [](const std::string& what) { throw std::invalid_argument("DepthCameraConfig: " + what); };
  const quad_core::CameraIntrinsics& k = intrinsics;
  if (k.width < 1 || k.height < 1) fail("width and height must be >= 1");
  if (!(k.fx > 0.0) || !(k.fy > 0.0) || !std::isfinite(k.fx) || !std::isfinite(k.fy))
    fail("fx, fy must be > 0");
  if (!std::isfinite(k.cx) || !std::isfinite(k.cy)) fail("cx, cy must be finite");
  if (!(rate_hz > 0.0)) fail("rate_hz must be > 0");
  if (!(min_depth_m >= 0.0) || !(max_depth_m > min_depth_m) || !std::isfinite(max_depth_m)) {
    fail("need 0 <= min_depth_m < max_depth_m < Inf");
  }
  if (!p_body_camera_m.allFinite() || !q_body_camera.coeffs().allFinite()) fail("mount must be finite");
  if (!(noise_std_at_1m_m >= 0.0)) fail("noise_std_at_1m_m must be >= 0");
  if (num_threads < 1) fail("num_threads must be >= 1");
}

Eigen::Quaterniond OpticalMountRotation(double roll_rad, double pitch_rad, double yaw_rad) {
  // base_link (FLU) -> optical (x right, y down, z forward) when looking along body +x.
  Eigen::Matrix3d R_flu_optical;
  R_flu_optical << 0, 0, 1, -1, 0, 0, 0, -1, 0;
  return (QuatFromRpy(roll_rad, pitch_rad, yaw_rad) * Eigen::Quaterniond(R_flu_optical)).normalized();
}

DepthRenderer::DepthRenderer(const DepthCameraConfig& config) : config_(config) { config_.Validate(); }

namespace {

constexpr int kTile = 8;

// One candidate box prepared for rasterisation: the camera ray of pixel (u, v) in the box's frame is
// o_box + t * (M.col(0) * xn(u) + M.col(1) * yn(v) + M.col(2)), t being the depth along the optical axis.
struct BoxRaster {
  double zmin;         // smallest optical depth of the box's corners: no pixel of it can be nearer
  int u0, u1, v0, v1;  // inclusive screen rectangle that may show the box
  double o[3];
  double m[3][3];  // m[i][j] = M(i, j)
  double h[3];
};

// Exact slab test of the pixel ray against the box; returns the entry depth or +Inf.
inline double RayBoxDepth(const BoxRaster& b, const double d[3]) {
  double t_enter = -std::numeric_limits<double>::infinity();
  double t_exit = std::numeric_limits<double>::infinity();
  for (int i = 0; i < 3; ++i) {
    if (d[i] == 0.0) {
      if (std::abs(b.o[i]) > b.h[i]) return std::numeric_limits<double>::infinity();
      continue;
    }
    const double inv = 1.0 / d[i];
    double t0 = (-b.h[i] - b.o[i]) * inv;
    double t1 = (b.h[i] - b.o[i]) * inv;
    if (t0 > t1) std::swap(t0, t1);
    if (t0 > t_enter) t_enter = t0;
    if (t1 < t_exit) t_exit = t1;
  }
  if (t_enter > t_exit || t_exit < 0.0) return std::numeric_limits<double>::infinity();
  return std::max(t_enter, 0.0);  // 0 when the camera is inside the box
}

}  // namespace

quad_core::DepthImage DepthRenderer::Render(const WorldIndex& index, const Eigen::Vector3d& p_world_camera,
                                            const Eigen::Quaterniond& q_world_camera) const {
  // Exact ray casting organised as rasterisation: the boxes that the btDbvt frustum query returns are sorted
  // near to far, each is projected to a screen rectangle, and every pixel of that rectangle gets the exact
  // analytic ray/box test unless its 8x8 tile is already nearer than the whole box (occlusion culling). The
  // result equals casting every pixel's ray against every box; it is 3-5x faster than per-pixel tree
  // traversal.
  const quad_core::CameraIntrinsics& k = config_.intrinsics;
  const int W = k.width;
  const int H = k.height;
  const Eigen::Matrix3d R = q_world_camera.normalized().toRotationMatrix();
  const Eigen::Vector3d& o = p_world_camera;
  const double max_d = config_.max_depth_m;
  const double inf = std::numeric_limits<double>::infinity();
  std::vector<double> xn(W), yn(H);
  for (int u = 0; u < W; ++u) xn[u] = (u - k.cx) / k.fx;
  for (int v = 0; v < H; ++v) yn[v] = (v - k.cy) / k.fy;

  // Frustum (pixel footprints included) bounded by the far plane, in world coordinates.
  const double x_lo = (-0.5 - k.cx) / k.fx, x_hi = (W - 0.5 - k.cx) / k.fx;
  const double y_lo = (-0.5 - k.cy) / k.fy, y_hi = (H - 0.5 - k.cy) / k.fy;
  std::vector<Eigen::Vector4d> planes;
  for (const Eigen::Vector3d& n_cam :
       {Eigen::Vector3d(1, 0, -x_lo), Eigen::Vector3d(-1, 0, x_hi), Eigen::Vector3d(0, 1, -y_lo),
        Eigen::Vector3d(0, -1, y_hi), Eigen::Vector3d(0, 0, 1)}) {
    const Eigen::Vector3d n = R * n_cam.normalized();
    planes.emplace_back(n.x(), n.y(), n.z(), -n.dot(o));
  }
  const Eigen::Vector3d axis = R.col(2);
  planes.emplace_back(-axis.x(), -axis.y(), -axis.z(), axis.dot(o) + max_d);
  const std::vector<int> candidates = index.QueryConvex(planes);

  std::vector<BoxRaster> rasters;
  rasters.reserve(candidates.size());
  for (int id : candidates) {
    const OrientedBox& box = index.boxes()[id];
    double zmin = inf, zmax = -inf, umin = inf, umax = -inf, vmin = inf, vmax = -inf;
    bool straddles = false;
    for (const Eigen::Vector3d& c : box.Corners()) {
      const Eigen::Vector3d pc = R.transpose() * (c - o);
      zmin = std::min(zmin, pc.z());
      zmax = std::max(zmax, pc.z());
      if (pc.z() <= 1e-9) {
        straddles = true;
        continue;
      }
      umin = std::min(umin, k.fx * pc.x() / pc.z() + k.cx);
      umax = std::max(umax, k.fx * pc.x() / pc.z() + k.cx);
      vmin = std::min(vmin, k.fy * pc.y() / pc.z() + k.cy);
      vmax = std::max(vmax, k.fy * pc.y() / pc.z() + k.cy);
    }
    if (zmax <= 0.0 || zmin > max_d) continue;
    BoxRaster b;
    b.zmin = std::max(zmin, 0.0);
    if (straddles) {
      // Part of the box is behind the camera plane: its projection is unbounded, test the whole image.
      b.u0 = 0, b.u1 = W - 1, b.v0 = 0, b.v1 = H - 1;
    } else {
      b.u0 = std::max(0, static_cast<int>(std::floor(umin)) - 1);
      b.u1 = std::min(W - 1, static_cast<int>(std::ceil(umax)) + 1);
      b.v0 = std::max(0, static_cast<int>(std::floor(vmin)) - 1);
      b.v1 = std::min(H - 1, static_cast<int>(std::ceil(vmax)) + 1);
      if (b.u0 > b.u1 || b.v0 > b.v1) continue;
    }
    const Eigen::Matrix3d Rt_box = box.q_world_box.toRotationMatrix().transpose();
    const Eigen::Vector3d ob = Rt_box * (o - box.center_world_m);
    const Eigen::Matrix3d M = Rt_box * R;
    const Eigen::Vector3d h = box.HalfExtents();
    for (int i = 0; i < 3; ++i) {
      b.o[i] = ob(i);
      b.h[i] = h(i);
      for (int j = 0; j < 3; ++j) b.m[i][j] = M(i, j);
    }
    rasters.push_back(b);
  }
  // Near to far (ties by box index: the order never changes a pixel's minimum, but keeps the work
  // reproducible).
  std::stable_sort(rasters.begin(), rasters.end(),
                   [](const BoxRaster& a, const BoxRaster& b) { return a.zmin < b.zmin; });

  std::vector<double> depth(static_cast<size_t>(W) * H, inf);
  const int tiles_x = (W + kTile - 1) / kTile;
  const int tiles_y = (H + kTile - 1) / kTile;
  // Rows of tiles are independent: threads take interleaved tile rows, so the output is the same for any
  // count.
  auto render_tile_rows = [&](int first_tile_row, int stride) {
    std::vector<double> tile_max(tiles_x);
    for (int ty = first_tile_row; ty < tiles_y; ty += stride) {
      const int v_begin = ty * kTile;
      const int v_end = std::min(H, v_begin + kTile);
      // The ground plane z = 0 (seen from above) first: it occludes boxes below the horizon.
      for (int v = v_begin; v < v_end; ++v) {
        const double base_z = R(2, 2) + yn[v] * R(2, 1);
        for (int u = 0; u < W; ++u) {
          const double dz = base_z + xn[u] * R(2, 0);
          if (dz < 0.0 && o.z() >= 0.0) depth[static_cast<size_t>(v) * W + u] = -o.z() / dz;
        }
      }
      for (int tx = 0; tx < tiles_x; ++tx) {
        double m = 0.0;
        for (int v = v_begin; v < v_end; ++v) {
          for (int u = tx * kTile; u < std::min(W, (tx + 1) * kTile); ++u) {
            m = std::max(m, std::min(depth[static_cast<size_t>(v) * W + u], max_d));
          }
        }
        tile_max[tx] = m;
      }
      for (const BoxRaster& b : rasters) {
        if (b.v1 < v_begin || b.v0 >= v_end) continue;
        const int va = std::max(b.v0, v_begin);
        const int vb = std::min(b.v1, v_end - 1);
        for (int tx = b.u0 / kTile; tx <= b.u1 / kTile; ++tx) {
          if (b.zmin >= tile_max[tx]) continue;  // everything in this tile is already nearer than the box
          const int ua = std::max(b.u0, tx * kTile);
          const int ub = std::min(b.u1, (tx + 1) * kTile - 1);
          for (int v = va; v <= vb; ++v) {
            const double r0 = b.m[0][2] + yn[v] * b.m[0][1];
            const double r1 = b.m[1][2] + yn[v] * b.m[1][1];
            const double r2 = b.m[2][2] + yn[v] * b.m[2][1];
            double* row = &depth[static_cast<size_t>(v) * W];
            for (int u = ua; u <= ub; ++u) {
              const double d[3] = {r0 + xn[u] * b.m[0][0], r1 + xn[u] * b.m[1][0], r2 + xn[u] * b.m[2][0]};
              const double t = RayBoxDepth(b, d);
              if (t < row[u]) row[u] = t;
            }
          }
          double m = 0.0;
          for (int v = v_begin; v < v_end; ++v) {
            for (int u = tx * kTile; u < std::min(W, (tx + 1) * kTile); ++u) {
              m = std::max(m, std::min(depth[static_cast<size_t>(v) * W + u], max_d));
            }
          }
          tile_max[tx] = m;
        }
      }
    }
  };
  const int threads = std::min(config_.num_threads, tiles_y);
  if (threads <= 1) {
    render_tile_rows(0, 1);
  } else {
    std::vector<std::thread> pool;
    for (int i = 1; i < threads; ++i) pool.emplace_back(render_tile_rows, i, threads);
    render_tile_rows(0, threads);
    for (std::thread& t : pool) t.join();
  }

  quad_core::DepthImage img;
  img.width = W;
  img.height = H;
  img.depth_m.resize(depth.size());
  const float pos_inf = std::numeric_limits<float>::infinity();
  for (size_t i = 0; i < depth.size(); ++i) {
    const double t = depth[i];
    if (!(t <= max_d)) {
      img.depth_m[i] = pos_inf;  // no return within range (REP 118)
    } else if (t < config_.min_depth_m) {
      img.depth_m[i] = -pos_inf;  // too close to measure (REP 118)
    } else {
      img.depth_m[i] = static_cast<float>(t);
    }
  }
  return img;
}

void DepthRenderer::AddNoise(quad_core::DepthImage* image, std::mt19937_64* rng) const {
  if (config_.noise_std_at_1m_m <= 0.0) return;
  std::normal_distribution<double> unit(0.0, 1.0);
  for (float& z : image->depth_m) {
    if (!std::isfinite(z)) continue;
    const double sigma = config_.noise_std_at_1m_m * static_cast<double>(z) * z;
    const double noisy = z + sigma * unit(*rng);
    z = static_cast<float>(std::max(noisy, config_.min_depth_m));
  }
}

}  // namespace quad_sim
