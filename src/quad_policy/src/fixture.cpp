#include "quad_policy/fixture.h"

#include <filesystem>
#include <stdexcept>

#include "quad_policy/npy.h"

namespace quad_policy {

namespace {

NpyArray Load(const std::string& dir, const char* name, const std::vector<std::size_t>& shape_prefix,
              std::size_t ndim) {
  const std::string path = dir + "/" + name;
  NpyArray a = ReadNpy(path);
  if (a.shape.size() != ndim) {
    throw std::invalid_argument(path + ": expected " + std::to_string(ndim) + " dimensions, got " +
                                std::to_string(a.shape.size()));
  }
  for (std::size_t i = 0; i < shape_prefix.size(); ++i) {
    if (a.shape[i] != shape_prefix[i]) {
      throw std::invalid_argument(path + ": dimension " + std::to_string(i) + " is " +
                                  std::to_string(a.shape[i]) + ", expected " +
                                  std::to_string(shape_prefix[i]));
    }
  }
  return a;
}

}  // namespace

CameraModel DecisionFixture::Camera(std::size_t i) const {
  const RecordedFrame& f = frames.at(i);
  CameraModel c;
  c.intrinsics.width = f.depth.width;
  c.intrinsics.height = f.depth.height;
  c.intrinsics.fx = fx;
  c.intrinsics.fy = fy;
  c.intrinsics.cx = cx;
  c.intrinsics.cy = cy;
  Eigen::Isometry3d T_world_body = Eigen::Isometry3d::Identity();
  T_world_body.linear() = f.state.q_world_body.normalized().toRotationMatrix();
  T_world_body.translation() = f.state.p_world_body;
  c.T_world_camera = T_world_body * T_body_camera;
  return c;
}

DecisionFixture ReadDecisionFixture(const std::string& dir) {
  const NpyArray depth = ReadNpy(dir + "/depth_m.npy");
  if (depth.shape.size() != 3) throw std::invalid_argument(dir + "/depth_m.npy: expected (N, H, W)");
  const std::size_t n = depth.shape[0], h = depth.shape[1], w = depth.shape[2];
  const std::vector<double> stamp = Load(dir, "stamp_s.npy", {n}, 1).as_double();
  const std::vector<double> p = Load(dir, "p_world_body.npy", {n, 3}, 2).as_double();
  const std::vector<double> v = Load(dir, "v_world.npy", {n, 3}, 2).as_double();
  const std::vector<double> q = Load(dir, "q_world_body.npy", {n, 4}, 2).as_double();
  const std::vector<double> g = Load(dir, "goal_world.npy", {n, 3}, 2).as_double();
  const std::vector<double> k = Load(dir, "camera_k.npy", {4}, 1).as_double();
  const std::vector<double> T = Load(dir, "T_body_camera.npy", {4, 4}, 2).as_double();
  const std::vector<float> d = depth.as_float();
  DecisionFixture fx;
  fx.fx = k[0];
  fx.fy = k[1];
  fx.cx = k[2];
  fx.cy = k[3];
  Eigen::Matrix4d m;
  for (int r = 0; r < 4; ++r) {
    for (int c = 0; c < 4; ++c) m(r, c) = T[4 * r + c];
  }
  fx.T_body_camera.matrix() = m;
  fx.frames.resize(n);
  for (std::size_t i = 0; i < n; ++i) {
    RecordedFrame& f = fx.frames[i];
    f.stamp_s = stamp[i];
    f.depth.width = static_cast<int>(w);
    f.depth.height = static_cast<int>(h);
    f.depth.depth_m.assign(d.begin() + i * h * w, d.begin() + (i + 1) * h * w);
    f.state.p_world_body = Eigen::Vector3d(p[3 * i], p[3 * i + 1], p[3 * i + 2]);
    f.state.v_world = Eigen::Vector3d(v[3 * i], v[3 * i + 1], v[3 * i + 2]);
    f.state.q_world_body = Eigen::Quaterniond(q[4 * i + 3], q[4 * i], q[4 * i + 1], q[4 * i + 2]);  // xyzw
    f.goal_world = Eigen::Vector3d(g[3 * i], g[3 * i + 1], g[3 * i + 2]);
  }
  return fx;
}

void WriteDecisionFixture(const std::string& dir, const DecisionFixture& fixture) {
  std::filesystem::create_directories(dir);
  const std::size_t n = fixture.frames.size();
  if (n == 0) throw std::invalid_argument("a fixture needs at least one frame");
  const int h = fixture.frames[0].depth.height, w = fixture.frames[0].depth.width;
  std::vector<float> depth;
  std::vector<double> stamp, p, v, q, g;
  for (const RecordedFrame& f : fixture.frames) {
    if (f.depth.height != h || f.depth.width != w ||
        f.depth.depth_m.size() != static_cast<std::size_t>(h) * static_cast<std::size_t>(w)) {
      throw std::invalid_argument("fixture frames must all have the same image size");
    }
    depth.insert(depth.end(), f.depth.depth_m.begin(), f.depth.depth_m.end());
    stamp.push_back(f.stamp_s);
    for (int j = 0; j < 3; ++j) {
      p.push_back(f.state.p_world_body[j]);
      v.push_back(f.state.v_world[j]);
      g.push_back(f.goal_world[j]);
    }
    const Eigen::Quaterniond& qq = f.state.q_world_body;
    q.insert(q.end(), {qq.x(), qq.y(), qq.z(), qq.w()});
  }
  const std::size_t hs = static_cast<std::size_t>(h), ws = static_cast<std::size_t>(w);
  WriteNpy(dir + "/depth_m.npy", NpyArray::FromFloat(depth, {n, hs, ws}));
  WriteNpy(dir + "/stamp_s.npy", NpyArray::FromDouble(stamp, {n}));
  WriteNpy(dir + "/p_world_body.npy", NpyArray::FromDouble(p, {n, 3}));
  WriteNpy(dir + "/v_world.npy", NpyArray::FromDouble(v, {n, 3}));
  WriteNpy(dir + "/q_world_body.npy", NpyArray::FromDouble(q, {n, 4}));
  WriteNpy(dir + "/goal_world.npy", NpyArray::FromDouble(g, {n, 3}));
  WriteNpy(dir + "/camera_k.npy",
           NpyArray::FromDouble({fixture.fx, fixture.fy, fixture.cx, fixture.cy}, {4}));
  std::vector<double> T(16);
  for (int r = 0; r < 4; ++r) {
    for (int c = 0; c < 4; ++c) T[4 * r + c] = fixture.T_body_camera.matrix()(r, c);
  }
  WriteNpy(dir + "/T_body_camera.npy", NpyArray::FromDouble(T, {4, 4}));
}

}  // namespace quad_policy
