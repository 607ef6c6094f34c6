#include "fast_planner/plan_collector.h"

#include <cpp_data_collector/writer_config.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <stdexcept>

namespace fast_planner {

cpp_data_collector::OdometrySample ToOdometrySample(const quad_core::VehicleState& o) {
  cpp_data_collector::OdometrySample s;
  s.stamp_s = o.t_s;
  s.p_world_body = {o.p_world_body.x(), o.p_world_body.y(), o.p_world_body.z()};
  s.v_world = {o.v_world.x(), o.v_world.y(), o.v_world.z()};
  const Eigen::Quaterniond q = o.q_world_body.normalized();
  s.q_world_body = {q.x(), q.y(), q.z(), q.w()};
  s.w_body = {o.w_body.x(), o.w_body.y(), o.w_body.z()};
  return s;
}

void FillPlanRecord(const PlanRecord& plan, const RecordContext& ctx, cpp_data_collector::PlanRecord* out) {
  if (!plan.result || !plan.result->spline || !plan.depth || !plan.odometry) {
    throw std::invalid_argument(
        "FillPlanRecord: the plan needs a result with a trajectory, its depth frame and its odometry");
  }
  const PlanResult& res = *plan.result;
  const DepthFrame& d = *plan.depth;
  cpp_data_collector::PlanRecord& r = *out;
  r.episode_id = ctx.episode_id;
  r.world_seed = ctx.world_seed;
  r.sim_time_s = plan.request.start_time_s;
  r.depth = d.image.view();
  r.depth_stamp_s = d.stamp_s;
  r.odom = ToOdometrySample(*plan.odometry);
  r.goal_world = {plan.goal.x(), plan.goal.y(), plan.goal.z()};
  const quad_core::NonUniformBspline& sp = *res.spline;
  cpp_data_collector::BsplineData& b = r.bspline;
  b.order = sp.order();
  b.traj_id = res.traj_id;
  b.start_time_s = res.start_time_s;
  b.knots.assign(sp.knots().begin(), sp.knots().end());
  const Eigen::MatrixXd& cp = sp.ctrl_pts();
  b.ctrl_pts_world.resize(static_cast<size_t>(cp.rows()));
  for (Eigen::Index i = 0; i < cp.rows(); ++i) {
    b.ctrl_pts_world[static_cast<size_t>(i)] = {cp(i, 0), cp(i, 1), cp(i, 2)};
  }
  b.yaw_pts.clear();
  b.yaw_dt_s = 0.0;
  r.status.code = static_cast<int32_t>(res.search_status);
  r.status.text = res.reason;
  r.timings = {ctx.map_update_ms, res.timings.frontend_ms, res.timings.optimization_ms, res.timings.total_ms};
}

PlanCollector::PlanCollector(const std::string& config_path, const std::string& output_dir,
                             const std::string& commit,
                             std::vector<std::pair<std::string, std::string>> run_info,
                             cpp_data_collector::OpenMode mode, WarningSink warn)
    : config_(cpp_data_collector::LoadWriterConfigFile(config_path)),
      run_info_(std::move(run_info)),
      mode_(mode),
      warn_(std::move(warn)) {
  config_.output_dir = output_dir;
  if (!commit.empty()) config_.software_commit = commit;
  config_.Validate();
  namespace fs = std::filesystem;
  if (mode_ == cpp_data_collector::OpenMode::kCreate && fs::exists(fs::path(output_dir) / "manifest.yaml")) {
    throw std::runtime_error("collector output directory " + output_dir +
                             " already holds a dataset (manifest.yaml); choose another output_dir");
  }
  record_.bspline.knots.reserve(config_.max_ctrl_pts + 8);
  record_.bspline.ctrl_pts_world.reserve(config_.max_ctrl_pts);
  record_us_.reserve(1 << 16);
}

std::string PlanCollector::Start(const quad_core::CameraIntrinsics& k) {
  if (writer_) return "";
  config_.image_width = static_cast<uint32_t>(k.width);
  config_.image_height = static_cast<uint32_t>(k.height);
  config_.camera_fx_px = k.fx;
  config_.camera_fy_px = k.fy;
  config_.camera_cx_px = k.cx;
  config_.camera_cy_px = k.cy;
  writer_ =
      std::make_unique<cpp_data_collector::DatasetWriter>(config_, cpp_data_collector::WriterHooks{}, mode_);
  for (const auto& [key, value] : run_info_) writer_->SetRunInfo(key, value);
  char buf[1024];
  std::snprintf(buf, sizeof(buf), "recording every plan to %s (%ux%u, queue %u, policy %s, commit %s)",
                config_.output_dir.c_str(), config_.image_width, config_.image_height, config_.queue_capacity,
                cpp_data_collector::ToString(config_.full_queue_policy), config_.software_commit.c_str());
  return buf;
}

void PlanCollector::OnPlan(const PlanRecord& plan) {
  if (!plan.result || !plan.result->spline) return;
  if (!writer_ || !plan.depth || !plan.odometry) {
    ++not_recorded_;
    char buf[160];
    std::snprintf(buf, sizeof(buf), "plan not recorded (%s); %lu so far",
                  !writer_ ? "collector not started: no camera_info yet"
                           : (!plan.depth ? "no depth frame" : "no odometry"),
                  static_cast<unsigned long>(not_recorded_));
    if (warn_) warn_(CollectorWarning::kNotRecorded, buf);
    return;
  }
  if (context_.episode_id < 0) {
    if (held_.size() >= kMaxHeldPlans) {
      ++not_recorded_;
      if (warn_) {
        warn_(CollectorWarning::kNotRecorded,
              "plan not recorded (no episode yet: nothing on sim/status, and " +
                  std::to_string(kMaxHeldPlans) + " plans are already held); " +
                  std::to_string(not_recorded_) + " so far");
      }
      return;
    }
    HeldPlan h;
    FillPlanRecord(plan, context_, &h.record);
    h.depth = plan.depth;  // keeps the pixels h.record.depth points into
    held_.push_back(std::move(h));
    if (warn_) {
      warn_(CollectorWarning::kHeld,
            "plan held until the episode is known (sim/status); " + std::to_string(held_.size()) + " held");
    }
    return;
  }
  const auto t0 = std::chrono::steady_clock::now();
  FillPlanRecord(plan, context_, &record_);
  Write(record_, t0);
}

void PlanCollector::SetEpisode(int64_t episode_id, uint64_t world_seed) {
  context_.episode_id = episode_id;
  context_.world_seed = world_seed;
  if (episode_id < 0 || held_.empty()) return;
  for (HeldPlan& h : held_) {
    h.record.episode_id = episode_id;
    h.record.world_seed = world_seed;
    Write(h.record, std::chrono::steady_clock::now());
  }
  held_.clear();
}

void PlanCollector::Write(const cpp_data_collector::PlanRecord& record) {
  if (!writer_) throw std::logic_error("PlanCollector::Write: the collector is not started (Start first)");
  Write(record, std::chrono::steady_clock::now());
}

void PlanCollector::Write(const cpp_data_collector::PlanRecord& record,
                          std::chrono::steady_clock::time_point t0) {
  const cpp_data_collector::RecordResult rr = writer_->Record(record);
  const double us = std::chrono::duration<double, std::micro>(std::chrono::steady_clock::now() - t0).count();
  if (record_us_.size() < record_us_.capacity()) record_us_.push_back(us);
  if (!rr.ok() && warn_) {
    const cpp_data_collector::WriterStats s = writer_->stats();
    warn_(CollectorWarning::kRecordFailed,
          std::string("record ") + cpp_data_collector::ToString(rr.status) + (rr.reason.empty() ? "" : ": ") +
              rr.reason + " (written " + std::to_string(s.written) + ", dropped " +
              std::to_string(s.dropped) + ", rejected " + std::to_string(s.rejected) + ")");
  }
}

std::string PlanCollector::writer_error() const {
  if (!writer_) return "";
  const cpp_data_collector::WriterStats s = writer_->stats();
  return s.failed ? (s.last_error.empty() ? std::string("failed") : s.last_error) : "";
}

std::string PlanCollector::StatsLine() const {
  if (!writer_) return "collector not started (no camera_info received)";
  const cpp_data_collector::WriterStats s = writer_->stats();
  char buf[1024];
  std::snprintf(buf, sizeof(buf),
                "collector %s: submitted %lu, written %lu, dropped %lu, rejected %lu, lost %lu, not recorded "
                "%lu, shards %lu, %.1f MB, queue high water %u, blocked calls %lu%s%s; Record() %s",
                config_.output_dir.c_str(), static_cast<unsigned long>(s.submitted),
                static_cast<unsigned long>(s.written), static_cast<unsigned long>(s.dropped),
                static_cast<unsigned long>(s.rejected), static_cast<unsigned long>(s.lost),
                static_cast<unsigned long>(not_recorded_), static_cast<unsigned long>(s.shards_completed),
                static_cast<double>(s.bytes_written) / 1e6, s.queue_high_water,
                static_cast<unsigned long>(s.blocked_calls), s.failed ? ", writer error: " : "",
                s.last_error.c_str(), RecordCostText().c_str());
  return buf;
}

PlanCollector::Finalized PlanCollector::Finalize() {
  // Plans still held never learnt their episode: a record without one would not be keyed, so none is written.
  std::string unkeyed;
  if (!held_.empty()) {
    not_recorded_ += held_.size();
    unkeyed = std::to_string(held_.size()) +
              " plan(s) not recorded: the episode was never known (nothing on sim/status); ";
    held_.clear();
  }
  if (!writer_) return {true, unkeyed + StatsLine()};
  const cpp_data_collector::FinalizeResult f = writer_->Finalize();
  if (f.ok) return {true, unkeyed + "dataset finalised: " + StatsLine()};
  return {false, unkeyed + "dataset finalised with an error (" + f.error + "): " + StatsLine()};
}

std::string PlanCollector::RecordCostText() const {
  if (record_us_.empty()) return "not called";
  std::vector<double> v = record_us_;
  std::sort(v.begin(), v.end());
  const auto q = [&](double f) { return v[std::min(v.size() - 1, static_cast<size_t>(f * v.size()))]; };
  char buf[128];
  std::snprintf(buf, sizeof(buf), "median %.1f us, p99 %.1f us over %zu plans", q(0.5), q(0.99), v.size());
  return buf;
}

}  // namespace fast_planner
