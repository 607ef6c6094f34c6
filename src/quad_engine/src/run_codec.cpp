#include "quad_engine/run_codec.h"

#include <cstring>
#include <stdexcept>
#include <type_traits>

namespace quad_engine {
namespace {

constexpr uint32_t kMagic = 0x51454e31;  // "QEN1"

class Out {
 public:
  template <typename T>
  void Pod(const T& v) {
    static_assert(std::is_trivially_copyable_v<T>);
    const char* p = reinterpret_cast<const char*>(&v);
    s_.append(p, sizeof(T));
  }
  void Str(const std::string& v) {
    Pod<uint64_t>(v.size());
    s_.append(v);
  }
  template <typename T>
  void Vec(const std::vector<T>& v) {
    Pod<uint64_t>(v.size());
    if (!v.empty()) s_.append(reinterpret_cast<const char*>(v.data()), v.size() * sizeof(T));
  }
  std::string Take() { return std::move(s_); }

 private:
  std::string s_;
};

class In {
 public:
  explicit In(const std::string& s) : s_(s) {}
  template <typename T>
  T Pod() {
    T v;
    Need(sizeof(T));
    std::memcpy(&v, s_.data() + at_, sizeof(T));
    at_ += sizeof(T);
    return v;
  }
  std::string Str() {
    const uint64_t n = Pod<uint64_t>();
    Need(n);
    std::string v = s_.substr(at_, n);
    at_ += n;
    return v;
  }
  template <typename T>
  std::vector<T> Vec() {
    const uint64_t n = Pod<uint64_t>();
    if (n > (s_.size() - at_) / sizeof(T)) Fail("a vector longer than the bytes left");
    std::vector<T> v(n);
    if (n) std::memcpy(v.data(), s_.data() + at_, n * sizeof(T));
    at_ += n * sizeof(T);
    return v;
  }
  bool done() const { return at_ == s_.size(); }

 private:
  void Need(uint64_t n) {
    if (n > s_.size() - at_) Fail("cut short");
  }
  [[noreturn]] static void Fail(const std::string& why) {
    throw std::invalid_argument("DecodeRun: not an encoded episode run: " + why);
  }
  const std::string& s_;
  size_t at_ = 0;
};

void PutRecord(const OwnedRecord& o, Out* out) {
  const cpp_data_collector::PlanRecord& r = o.record;
  out->Pod(r.episode_id);
  out->Pod(r.world_seed);
  out->Pod(r.sim_time_s);
  out->Pod(r.depth_stamp_s);
  out->Pod(r.depth.width);
  out->Pod(r.depth.height);
  std::vector<float> px(static_cast<size_t>(r.depth.width) * r.depth.height);
  for (int row = 0; row < r.depth.height; ++row) {
    std::memcpy(px.data() + static_cast<size_t>(row) * r.depth.width, r.depth.data + row * r.depth.row_stride,
                sizeof(float) * r.depth.width);
  }
  out->Vec(px);
  out->Pod(r.odom);
  out->Pod(r.goal_world);
  out->Pod(r.bspline.order);
  out->Pod(r.bspline.traj_id);
  out->Pod(r.bspline.start_time_s);
  out->Vec(r.bspline.knots);
  out->Vec(r.bspline.ctrl_pts_world);
  out->Vec(r.bspline.yaw_pts);
  out->Pod(r.bspline.yaw_dt_s);
  out->Pod(r.status.code);
  out->Str(o.status_text);
  out->Pod(r.timings);
}

OwnedRecord GetRecord(In* in) {
  OwnedRecord o;
  cpp_data_collector::PlanRecord& r = o.record;
  r.episode_id = in->Pod<int64_t>();
  r.world_seed = in->Pod<uint64_t>();
  r.sim_time_s = in->Pod<double>();
  r.depth_stamp_s = in->Pod<double>();
  auto frame = std::make_shared<fast_planner::DepthFrame>();
  frame->stamp_s = r.depth_stamp_s;
  frame->image.width = in->Pod<int>();
  frame->image.height = in->Pod<int>();
  frame->image.depth_m = in->Vec<float>();
  if (frame->image.depth_m.size() != static_cast<size_t>(frame->image.width) * frame->image.height) {
    throw std::invalid_argument("DecodeRun: a record's depth image size does not match its pixels");
  }
  o.frame = frame;
  r.odom = in->Pod<cpp_data_collector::OdometrySample>();
  r.goal_world = in->Pod<std::array<double, 3>>();
  r.bspline.order = in->Pod<int32_t>();
  r.bspline.traj_id = in->Pod<int64_t>();
  r.bspline.start_time_s = in->Pod<double>();
  r.bspline.knots = in->Vec<double>();
  r.bspline.ctrl_pts_world = in->Vec<std::array<double, 3>>();
  r.bspline.yaw_pts = in->Vec<double>();
  r.bspline.yaw_dt_s = in->Pod<double>();
  r.status.code = in->Pod<int32_t>();
  o.status_text = in->Str();
  r.timings = in->Pod<cpp_data_collector::PlanTimings>();
  o.Rebind();
  return o;
}

}  // namespace

std::string EncodeRun(const EpisodeRun& run) {
  Out out;
  out.Pod(kMagic);
  out.Pod(run.spec.index);
  out.Pod(run.spec.seed);
  for (int i = 0; i < 3; ++i) out.Pod(run.spec.start_world[i]);
  out.Pod(run.spec.start_yaw_rad);
  for (int i = 0; i < 3; ++i) out.Pod(run.spec.goal_world[i]);
  out.Str(run.outcome);
  out.Str(run.reason);
  out.Pod(run.sim_duration_s);
  out.Pod(run.samples);
  out.Pod(run.intrinsics);
  out.Pod(run.steps);
  out.Pod(run.frames);
  out.Pod(run.plans);
  out.Pod(run.plan_failures);
  out.Pod(run.sim_s);
  out.Pod(run.wall_s);
  out.Pod<uint64_t>(run.records.size());
  for (const OwnedRecord& r : run.records) PutRecord(r, &out);
  return out.Take();
}

EpisodeRun DecodeRun(const std::string& bytes) {
  In in(bytes);
  if (in.Pod<uint32_t>() != kMagic)
    throw std::invalid_argument("DecodeRun: not an encoded episode run (magic)");
  EpisodeRun run;
  run.spec.index = in.Pod<int64_t>();
  run.spec.seed = in.Pod<uint64_t>();
  for (int i = 0; i < 3; ++i) run.spec.start_world[i] = in.Pod<double>();
  run.spec.start_yaw_rad = in.Pod<double>();
  for (int i = 0; i < 3; ++i) run.spec.goal_world[i] = in.Pod<double>();
  run.outcome = in.Str();
  run.reason = in.Str();
  run.sim_duration_s = in.Pod<double>();
  run.samples = in.Pod<uint64_t>();
  run.intrinsics = in.Pod<quad_core::CameraIntrinsics>();
  run.steps = in.Pod<uint64_t>();
  run.frames = in.Pod<uint64_t>();
  run.plans = in.Pod<uint64_t>();
  run.plan_failures = in.Pod<uint64_t>();
  run.sim_s = in.Pod<double>();
  run.wall_s = in.Pod<double>();
  const uint64_t n = in.Pod<uint64_t>();
  run.records.reserve(n);
  for (uint64_t i = 0; i < n; ++i) run.records.push_back(GetRecord(&in));
  for (OwnedRecord& r : run.records) r.Rebind();
  if (!in.done()) throw std::invalid_argument("DecodeRun: trailing bytes after the last record");
  return run;
}

}  // namespace quad_engine
