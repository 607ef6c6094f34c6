#include "cpp_data_collector/synthetic.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <stdexcept>

namespace cpp_data_collector {

namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kSpeedMps = 2.0;
constexpr double kAltitudeM = 1.5;
constexpr double kKnotDtS = 0.25;  // 0.5 m control-point spacing at 2 m/s, as Fast-Planner's defaults
constexpr double kCameraRateHz = 30.0;
constexpr double kOdomRateHz = 200.0;

// SplitMix64 (Steele, Lea, Flood 2014): a tiny, portable generator, so synthetic data is identical on every
// platform (std::uniform_real_distribution is implementation-defined).
class SplitMix64 {
 public:
  explicit SplitMix64(uint64_t seed) : state_(seed) {}
  uint64_t Next() {
    uint64_t z = (state_ += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
  }
  double Uniform(double lo, double hi) {
    return lo + (hi - lo) * static_cast<double>(Next() >> 11) * 0x1.0p-53;
  }

 private:
  uint64_t state_;
};

uint64_t Mix(uint64_t a, uint64_t b) { return SplitMix64(a * 0x9E3779B97F4A7C15ull ^ b).Next(); }

struct Box {
  double cx, cy, cz;  // centre, world
  double hx, hy, hz;  // half extents
  double cos_yaw, sin_yaw;
  double radius;  // bounding sphere
};

struct World {
  uint64_t seed;
  double goal_y;
  double wiggle_amp_m;
  double wiggle_omega;
  double wiggle_phase;
  std::vector<Box> boxes;
};

World MakeWorld(uint64_t world_seed, uint32_t num_boxes) {
  SplitMix64 rng(world_seed);
  World w;
  w.seed = world_seed;
  w.goal_y = rng.Uniform(-4.0, 4.0);
  w.wiggle_amp_m = rng.Uniform(0.5, 2.0);
  w.wiggle_omega = rng.Uniform(0.2, 0.6);
  w.wiggle_phase = rng.Uniform(0.0, 2.0 * kPi);
  for (uint32_t i = 0; i < num_boxes; ++i) {
    Box b;
    b.cx = rng.Uniform(4.0, 60.0);
    // Keep a 2.5 m corridor around the nominal path free, like a planner's clear path.
    const double side = rng.Uniform(0.0, 1.0) < 0.5 ? -1.0 : 1.0;
    b.hx = rng.Uniform(0.25, 1.5);
    b.hy = rng.Uniform(0.25, 1.5);
    b.hz = rng.Uniform(0.5, 2.5);
    b.cy = side * rng.Uniform(2.5 + std::max(b.hx, b.hy) + 2.0, 14.0);
    b.cz = b.hz;
    const double yaw = rng.Uniform(-kPi, kPi);
    b.cos_yaw = std::cos(yaw);
    b.sin_yaw = std::sin(yaw);
    b.radius = std::sqrt(b.hx * b.hx + b.hy * b.hy + b.hz * b.hz);
    w.boxes.push_back(b);
  }
  return w;
}

struct State {
  std::array<double, 3> p, v, a;
};

// The vehicle's path: forward at kSpeedMps along +x with a lateral sinusoid; t in seconds since episode
// start.
State PathAt(const World& w, double t) {
  const double s = w.wiggle_omega * t + w.wiggle_phase;
  State st;
  st.p = {kSpeedMps * t, w.wiggle_amp_m * (std::sin(s) - std::sin(w.wiggle_phase)),
          kAltitudeM + 0.2 * std::sin(0.5 * t)};
  st.v = {kSpeedMps, w.wiggle_amp_m * w.wiggle_omega * std::cos(s), 0.1 * std::cos(0.5 * t)};
  st.a = {0.0, -w.wiggle_amp_m * w.wiggle_omega * w.wiggle_omega * std::sin(s), -0.05 * std::sin(0.5 * t)};
  return st;
}

// Rotation world<-body from yaw (heading of the velocity) and the roll/pitch a multirotor needs for `a`.
void Attitude(const State& st, std::array<double, 4>* q_xyzw, std::array<std::array<double, 3>, 3>* r) {
  const double yaw = std::atan2(st.v[1], st.v[0]);
  const double g = 9.81;
  const double cy = std::cos(yaw), sy = std::sin(yaw);
  // Acceleration in the yaw frame -> small pitch (forward accel) and roll (lateral accel).
  const double a_fwd = cy * st.a[0] + sy * st.a[1];
  const double a_left = -sy * st.a[0] + cy * st.a[1];
  const double pitch = std::atan2(a_fwd, g);
  const double roll = std::atan2(-a_left, g);
  const double cr = std::cos(roll / 2), sr = std::sin(roll / 2);
  const double cp = std::cos(pitch / 2), sp = std::sin(pitch / 2);
  const double ch = std::cos(yaw / 2), sh = std::sin(yaw / 2);
  const double qw = ch * cp * cr + sh * sp * sr;
  const double qx = ch * cp * sr - sh * sp * cr;
  const double qy = ch * sp * cr + sh * cp * sr;
  const double qz = sh * cp * cr - ch * sp * sr;
  *q_xyzw = {qx, qy, qz, qw};
  auto& R = *r;
  R[0] = {1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)};
  R[1] = {2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)};
  R[2] = {2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)};
}

// Ray (origin o, direction d, not normalised) against a yaw-rotated box: the entry parameter or +inf.
double RayBox(const Box& b, const std::array<double, 3>& o, const std::array<double, 3>& d) {
  const double ox = o[0] - b.cx, oy = o[1] - b.cy, oz = o[2] - b.cz;
  const double lo[3] = {b.cos_yaw * ox + b.sin_yaw * oy, -b.sin_yaw * ox + b.cos_yaw * oy, oz};
  const double ld[3] = {b.cos_yaw * d[0] + b.sin_yaw * d[1], -b.sin_yaw * d[0] + b.cos_yaw * d[1], d[2]};
  const double h[3] = {b.hx, b.hy, b.hz};
  double t_near = -std::numeric_limits<double>::infinity();
  double t_far = std::numeric_limits<double>::infinity();
  for (int k = 0; k < 3; ++k) {
    if (std::abs(ld[k]) < 1e-12) {
      if (std::abs(lo[k]) > h[k]) return std::numeric_limits<double>::infinity();
      continue;
    }
    double t1 = (-h[k] - lo[k]) / ld[k];
    double t2 = (h[k] - lo[k]) / ld[k];
    if (t1 > t2) std::swap(t1, t2);
    t_near = std::max(t_near, t1);
    t_far = std::min(t_far, t2);
    if (t_near > t_far) return std::numeric_limits<double>::infinity();
  }
  if (t_far < 0.0) return std::numeric_limits<double>::infinity();
  return t_near > 0.0 ? t_near : 0.0;
}

}  // namespace

SyntheticGenerator::SyntheticGenerator(const SyntheticConfig& config) : config_(config) {
  if (config.width == 0 || config.height == 0)
    throw std::invalid_argument("synthetic: image size must be positive");
  if (config.records_per_episode == 0)
    throw std::invalid_argument("synthetic: records_per_episode must be >= 1");
  if (!(config.record_period_s > 0.0)) throw std::invalid_argument("synthetic: record_period_s must be > 0");
  if (!(config.min_range_m > 0.0) || !(config.max_range_m > config.min_range_m)) {
    throw std::invalid_argument("synthetic: need 0 < min_range_m < max_range_m");
  }
  const double scale = static_cast<double>(config.width) / 640.0;
  fx_ = 387.2 * scale;
  fy_ = 387.2 * scale;
  cx_ = config.width / 2.0;
  cy_ = config.height / 2.0;
}

void SyntheticGenerator::Generate(uint64_t index, SyntheticRecord* out, DepthMode depth_mode) const {
  const SyntheticConfig& c = config_;
  const uint64_t episode = index / c.records_per_episode;
  const uint64_t step = index % c.records_per_episode;
  const uint64_t world_seed = Mix(c.seed, episode);
  const World world = MakeWorld(world_seed, c.boxes_per_world);
  SplitMix64 rng(Mix(Mix(c.seed, 0xA11CEull), index));

  // Sim time runs on across episodes (a 5 s reset gap between them), as in one collection run.
  const double episode_start_s =
      static_cast<double>(episode) * (c.records_per_episode * c.record_period_s + 5.0);
  const double t_plan = 1.0 + static_cast<double>(step) * c.record_period_s + rng.Uniform(0.0, 0.02);
  const double depth_t = std::floor(t_plan * kCameraRateHz) / kCameraRateHz;
  const double odom_t = std::floor(depth_t * kOdomRateHz) / kOdomRateHz;
  const double latency_s = rng.Uniform(0.003, 0.03);

  PlanRecord& r = out->record;
  r.episode_id = static_cast<int64_t>(episode);
  r.world_seed = world_seed;
  r.sim_time_s = episode_start_s + depth_t + latency_s;
  r.goal_world = {60.0, world.goal_y, kAltitudeM};

  const State st = PathAt(world, odom_t);
  std::array<std::array<double, 3>, 3> R{};
  r.odom.stamp_s = episode_start_s + odom_t;
  r.odom.p_world_body = st.p;
  r.odom.v_world = st.v;
  Attitude(st, &r.odom.q_world_body, &R);
  r.odom.w_body = {rng.Uniform(-0.05, 0.05), rng.Uniform(-0.05, 0.05), world.wiggle_omega * 0.3};

  // Depth image: camera at the body origin looking along body x; optical frame x right (= -body y),
  // y down (= -body z), z forward. Pixel values are the z coordinate of the hit in the optical frame.
  const uint32_t W = c.width, H = c.height;
  out->depth_m.resize(static_cast<size_t>(W) * H);
  std::vector<const Box*> visible;
  const uint32_t render_rows = depth_mode == DepthMode::kRender ? H : 0;
  for (const Box& b : world.boxes) {
    const double dx = b.cx - st.p[0], dy = b.cy - st.p[1], dz = b.cz - st.p[2];
    const double forward = R[0][0] * dx + R[1][0] * dy + R[2][0] * dz;
    if (forward + b.radius > 0.0 && std::sqrt(dx * dx + dy * dy + dz * dz) - b.radius < c.max_range_m * 1.8) {
      visible.push_back(&b);
    }
  }
  const uint64_t pixel_seed = Mix(c.seed ^ 0x5EEDull, index);
  for (uint32_t v = 0; v < render_rows; ++v) {
    for (uint32_t u = 0; u < W; ++u) {
      const double xc = (u + 0.5 - cx_) / fx_;
      const double yc = (v + 0.5 - cy_) / fy_;
      // optical (xc, yc, 1) -> body (1, -xc, -yc) -> world
      const double bx = 1.0, by = -xc, bz = -yc;
      const std::array<double, 3> d = {R[0][0] * bx + R[0][1] * by + R[0][2] * bz,
                                       R[1][0] * bx + R[1][1] * by + R[1][2] * bz,
                                       R[2][0] * bx + R[2][1] * by + R[2][2] * bz};
      double t = std::numeric_limits<double>::infinity();
      if (d[2] < 0.0) t = -st.p[2] / d[2];  // ground plane z = 0
      for (const Box* b : visible) t = std::min(t, RayBox(*b, st.p, d));
      float depth;
      if (!(t <= c.max_range_m)) {
        depth = std::numeric_limits<float>::infinity();
      } else if (t < c.min_range_m) {
        depth = -std::numeric_limits<float>::infinity();
      } else {
        depth = static_cast<float>(t);  // the ray has unit optical z, so t is the depth
      }
      const uint64_t h = Mix(pixel_seed, static_cast<uint64_t>(v) * W + u);
      if (static_cast<double>(h >> 11) * 0x1.0p-53 < c.invalid_pixel_fraction) {
        depth = std::numeric_limits<float>::quiet_NaN();
      }
      out->depth_m[static_cast<size_t>(v) * W + u] = depth;
    }
  }
  r.depth.data = out->depth_m.data();
  r.depth.width = W;
  r.depth.height = H;
  r.depth.row_stride = static_cast<size_t>(W);
  r.depth_stamp_s = episode_start_s + depth_t;

  // B-spline: Fast-Planner's uniform cubic parametrisation, knots (i - 3) * dt so knots[3] = 0 is flown at
  // start_time; control points near the path ahead, bent by a smooth lateral bump (an avoided obstacle).
  BsplineData& b = r.bspline;
  const int n = 8 + static_cast<int>(rng.Next() % 25);
  b.order = 3;
  b.traj_id = static_cast<int64_t>(step) + 1;
  b.start_time_s = r.sim_time_s;
  b.knots.resize(static_cast<size_t>(n + 4));
  for (int i = 0; i < n + 4; ++i) b.knots[i] = (i - 3) * kKnotDtS;
  b.ctrl_pts_world.resize(static_cast<size_t>(n));
  const double bump_m = rng.Uniform(-0.8, 0.8);
  const double bump_centre = rng.Uniform(0.3, 0.7) * n;
  const double t_start_rel = r.sim_time_s - episode_start_s;
  for (int i = 0; i < n; ++i) {
    const State at = PathAt(world, t_start_rel + (i - 1) * kKnotDtS);
    const double w = std::exp(-0.5 * std::pow((i - bump_centre) / 2.0, 2));
    b.ctrl_pts_world[i] = {at.p[0], at.p[1] + bump_m * w, at.p[2] + 0.3 * bump_m * w};
  }
  b.yaw_dt_s = kKnotDtS;
  b.yaw_pts.resize(static_cast<size_t>(n));
  for (int i = 0; i < n; ++i) {
    const State at = PathAt(world, t_start_rel + (i - 1) * kKnotDtS);
    b.yaw_pts[i] = std::atan2(at.v[1], at.v[0]);
  }

  const bool horizon = rng.Uniform(0.0, 1.0) < 0.1;
  r.status.code = horizon ? 1 : 0;
  out->status_text = horizon ? "reached horizon" : "success";
  r.status.text = out->status_text;
  r.timings.map_update_ms = rng.Uniform(0.8, 3.0);
  r.timings.frontend_ms = rng.Uniform(0.1, 1.2);
  r.timings.optimization_ms = rng.Uniform(0.5, 3.5);
  r.timings.total_ms = r.timings.frontend_ms + r.timings.optimization_ms + rng.Uniform(0.05, 0.3);
}

}  // namespace cpp_data_collector
