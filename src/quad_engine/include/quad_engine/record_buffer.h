// The per-episode buffer of the expert's successful plans: the embedded collector's records kept in memory,
// to be written in key order through the collector's writer (DatasetSink).
#pragma once

#include <fast_planner/plan_collector.h>

#include <functional>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "quad_engine/episode.h"

namespace quad_engine {

class RecordBuffer : public fast_planner::PlanObserver {
 public:
  void Start(int64_t episode_id, uint64_t world_seed) {
    context_ = fast_planner::RecordContext{};
    context_.episode_id = episode_id;
    context_.world_seed = world_seed;
    records_.clear();
  }
  void SetMapUpdateMs(double ms) { context_.map_update_ms = ms; }
  // Frames given to the expert without pixels (the privileged expert does not look at them): a plan made at
  // such a frame gets the frame rendered then, at the same sim state (plans are made at the frame's step).
  void SetPlaceholder(std::shared_ptr<const fast_planner::DepthFrame> placeholder,
                      std::function<quad_core::DepthImage()> render) {
    placeholder_ = std::move(placeholder);
    rendered_.reset();
    render_ = std::move(render);
  }
  void OnPlan(const fast_planner::PlanRecord& plan) override {
    if (!plan.result || !plan.result->spline || !plan.depth || !plan.odometry) return;
    OwnedRecord r;
    fast_planner::FillPlanRecord(plan, context_, &r.record);
    r.frame = plan.depth;
    if (placeholder_ && plan.depth == placeholder_) {
      if (!rendered_) {
        auto f = std::make_shared<fast_planner::DepthFrame>(*placeholder_);
        f->image = render_();
        rendered_ = f;
      }
      r.frame = rendered_;
    }
    r.status_text = std::string(r.record.status.text);
    r.Rebind();
    records_.push_back(std::move(r));
    records_.back().Rebind();
  }
  std::vector<OwnedRecord> Take() { return std::move(records_); }
  // Drops the records after the first n (labels of a frame that is not kept).
  void Truncate(size_t n) {
    if (records_.size() > n) records_.resize(n);
  }
  size_t size() const { return records_.size(); }

 private:
  fast_planner::RecordContext context_;
  std::vector<OwnedRecord> records_;
  std::shared_ptr<const fast_planner::DepthFrame> placeholder_, rendered_;
  std::function<quad_core::DepthImage()> render_;
};

}  // namespace quad_engine
