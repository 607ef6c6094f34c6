#include "quad_engine/dataset_sink.h"

#include <stdexcept>

namespace quad_engine {

DatasetSink::DatasetSink(const std::string& collector_config, const std::string& output_dir,
                         const std::string& commit, std::vector<std::pair<std::string, std::string>> run_info,
                         bool append)
    : collector_(collector_config, output_dir, commit, std::move(run_info),
                 append ? cpp_data_collector::OpenMode::kAppend : cpp_data_collector::OpenMode::kCreate,
                 [this](fast_planner::CollectorWarning, const std::string& text) {
                   ++warnings_;
                   last_warning_ = text;
                 }) {}

void DatasetSink::Write(const EpisodeRun& run) {
  if (run.records.empty()) return;
  collector_.Start(run.intrinsics);
  for (const OwnedRecord& r : run.records) {
    OwnedRecord copy;  // views rebound to this run's storage (a run may have been moved or decoded)
    copy.record = r.record;
    copy.frame = r.frame;
    copy.status_text = r.status_text;
    copy.Rebind();
    collector_.Write(copy.record);
  }
  // A record the writer refused is a warning with its reason; a failed writer loses everything after it.
  const std::string error = collector_.writer_error();
  if (!error.empty()) throw std::runtime_error("dataset writer failed: " + error);
}

fast_planner::PlanCollector::Finalized DatasetSink::Finalize() { return collector_.Finalize(); }

}  // namespace quad_engine
