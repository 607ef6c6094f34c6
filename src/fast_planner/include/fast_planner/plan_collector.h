// The expert's embedded data collector (issue 6, docs/cpp_data_collector.md), ROS-free: a PlanObserver that
// turns each successful plan, with exactly the depth frame and odometry it used, into a
// cpp_data_collector::PlanRecord and hands it to a DatasetWriter (which copies it and writes it on its own
// thread). The planner node owns one and forwards the episode (sim/status), the map update time and the
// camera intrinsics (the writer starts at the first camera_info: they go into every shard header).
#pragma once

#include <cpp_data_collector/dataset_writer.h>
#include <cpp_data_collector/plan_record.h>
#include <quad_core/camera.h>
#include <quad_core/vehicle_state.h>

#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "fast_planner/planner_manager.h"

namespace fast_planner {

// What a record holds besides the plan itself.
struct RecordContext {
  int64_t episode_id = -1;
  uint64_t world_seed = 0;
  double map_update_ms = 0.0;  // the map update of the frame the plan was made after
};

// The odometry as the record stores it: quaternion normalised, in (x, y, z, w) order.
cpp_data_collector::OdometrySample ToOdometrySample(const quad_core::VehicleState& odom);

// The record of one successful plan (plan.result with a spline, plan.depth and plan.odometry set; throws
// std::invalid_argument otherwise). `out->depth` points into plan.depth's pixels. `out->bspline`'s vectors
// are reused (assigned, not reallocated once large enough), so a caller that keeps `out` between plans
// allocates nothing after the first ones. No yaw points: the tracker faces the direction of travel. The
// status is the front end's outcome (reached goal / horizon / safe stop); every recorded plan succeeded.
void FillPlanRecord(const PlanRecord& plan, const RecordContext& ctx, cpp_data_collector::PlanRecord* out);

enum class CollectorWarning {
  kNotRecorded,   // a successful plan that could not be recorded (no camera_info yet, no depth, no odometry)
  kRecordFailed,  // the writer refused or dropped the record
  kHeld,          // a plan made before the episode was known, held until it is (SetEpisode)
};

class PlanCollector : public PlanObserver {
 public:
  // Gets every warning's text (the node logs it, throttled per kind).
  using WarningSink = std::function<void(CollectorWarning, const std::string&)>;

  // `config_path`: a writer YAML (config/collector.yaml); `output_dir` replaces its output_dir and a
  // non-empty `commit` its software_commit. kCreate refuses a directory that already holds a dataset now (the
  // writer would too, but only at the first camera_info). Throws with the reason.
  PlanCollector(const std::string& config_path, const std::string& output_dir, const std::string& commit,
                std::vector<std::pair<std::string, std::string>> run_info, cpp_data_collector::OpenMode mode,
                WarningSink warn);

  bool started() const { return writer_ != nullptr; }
  // Creates the writer with these intrinsics (the image size and camera of every shard); returns the line
  // to log. Later calls do nothing and return "". Throws if the writer cannot start.
  std::string Start(const quad_core::CameraIntrinsics& k);

  // The episode of the plans from now on. A plan made before the first episode is known (the node's depth
  // frame or goal can arrive before sim/status: they come on other connections) is held, and written with
  // this episode when it is set; at most kMaxHeldPlans are held, later ones are counted as not recorded.
  void SetEpisode(int64_t episode_id, uint64_t world_seed);
  static constexpr size_t kMaxHeldPlans = 32;
  size_t held() const { return held_.size(); }
  void SetMapUpdateMs(double ms) { context_.map_update_ms = ms; }

  void OnPlan(const PlanRecord& plan) override;

  // Writes a record already filled (FillPlanRecord), e.g. one the rollout engine buffered during an episode;
  // the same checks and warnings as OnPlan's. The collector must be started.
  void Write(const cpp_data_collector::PlanRecord& record);

  // One line of writer statistics (also the not-recorded count and Record()'s cost).
  std::string StatsLine() const;

  struct Finalized {
    bool ok = true;    // false on a writer error
    std::string text;  // what to print: "dataset finalised: <stats>" or the error
  };
  // Completes the dataset (drains the queue, final manifest).
  Finalized Finalize();

  uint64_t not_recorded() const { return not_recorded_; }
  // The writer's I/O error ("" while it works or before it started).
  std::string writer_error() const;
  const cpp_data_collector::WriterConfig& config() const { return config_; }

 private:
  std::string RecordCostText() const;
  void Write(const cpp_data_collector::PlanRecord& record, std::chrono::steady_clock::time_point t0);

  cpp_data_collector::WriterConfig config_;
  std::vector<std::pair<std::string, std::string>> run_info_;
  cpp_data_collector::OpenMode mode_;
  WarningSink warn_;
  std::unique_ptr<cpp_data_collector::DatasetWriter> writer_;
  cpp_data_collector::PlanRecord record_;  // reused: its B-spline vectors keep their capacity
  RecordContext context_;
  // Plans made before the first episode was known: the record (its depth pointing into `depth`'s pixels).
  struct HeldPlan {
    cpp_data_collector::PlanRecord record;
    std::shared_ptr<const DepthFrame> depth;
  };
  std::vector<HeldPlan> held_;
  uint64_t not_recorded_ = 0;
  std::vector<double> record_us_;
};

}  // namespace fast_planner
