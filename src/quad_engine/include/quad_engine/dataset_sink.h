// The dataset an engine run writes: the expert's embedded collector (fast_planner::PlanCollector, the same
// writer, config and manifest as collect.launch) fed with the records of flown episodes, one episode after
// the other in the order the caller gives (key order), so that the dataset does not depend on how many
// workers flew the episodes or in which order they finished.
#pragma once

#include <fast_planner/plan_collector.h>

#include <cstdint>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "quad_engine/episode.h"

namespace quad_engine {

class DatasetSink {
 public:
  // collector_config: config/collector.yaml; append: continue the dataset in output_dir (a resumed run), else
  // output_dir must not hold one. Throws with the reason.
  DatasetSink(const std::string& collector_config, const std::string& output_dir, const std::string& commit,
              std::vector<std::pair<std::string, std::string>> run_info, bool append);

  // Writes the run's records in their order (starts the writer with the run's camera at the first run with
  // records). Throws std::runtime_error if the writer has failed (its error), so no record is lost silently.
  void Write(const EpisodeRun& run);

  fast_planner::PlanCollector::Finalized Finalize();
  std::string StatsLine() const { return collector_.StatsLine(); }
  uint64_t warnings() const { return warnings_; }
  const std::string& last_warning() const { return last_warning_; }

 private:
  fast_planner::PlanCollector collector_;
  uint64_t warnings_ = 0;
  std::string last_warning_;
};

}  // namespace quad_engine
