// DatasetWriter: the collector the expert planner embeds. Record() copies one plan into a preallocated queue
// slot on the caller's thread (no allocation, no encoding, no I/O); a background thread encodes the depth
// image, computes the CRC and appends the record to the current shard. Format: docs/data_format.md.
//
//   cpp_data_collector::DatasetWriter writer(config);        // throws on bad config or unusable directory
//   auto r = writer.Record(plan_record);                      // after each plan; r.status says
//   queued/dropped/...
//   ...
//   writer.Finalize();                                        // flush, rename the last shard, final manifest
//
// Shutdown: call Finalize() on the normal shutdown path (e.g. after ros::spin() returns on SIGINT); the
// destructor calls it too. Never call it from inside a signal handler (it takes locks and does I/O). A
// process killed without Finalize (SIGKILL, crash) still leaves every completed record readable; see the
// reader.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <string>

#include "cpp_data_collector/plan_record.h"
#include "cpp_data_collector/record_format.h"
#include "cpp_data_collector/writer_config.h"

namespace cpp_data_collector {

enum class RecordStatus {
  kQueued,            // copied into a slot; the writer thread will write it
  kDroppedQueueFull,  // drop policy and no free slot: counted in stats().dropped, its seq is a gap
  kRejectedInvalid,   // bad input (NaN, wrong image size, too many control points...): counted, not written
  kWriterClosed,      // Finalize() was already called
  kWriterFailed,      // the writer thread hit an I/O error; nothing more is written (see stats().last_error)
};
const char* ToString(RecordStatus status);

struct RecordResult {
  RecordStatus status = RecordStatus::kQueued;
  uint64_t seq = 0;    // valid for kQueued and kDroppedQueueFull
  std::string reason;  // empty for kQueued; why otherwise
  bool ok() const { return status == RecordStatus::kQueued; }
};

struct WriterStats {
  uint64_t submitted = 0;  // calls that passed validation and got a seq
  uint64_t written = 0;    // records appended to shard files
  uint64_t dropped = 0;    // drop policy, queue full
  uint64_t rejected = 0;   // invalid input
  uint64_t lost = 0;       // accepted but never written because the writer thread failed
  uint64_t shards_completed = 0;
  uint64_t bytes_written = 0;
  uint32_t queue_high_water = 0;  // most slots ever in use at once
  uint64_t blocked_calls = 0;     // block policy: calls that had to wait for a free slot
  bool failed = false;
  std::string last_error;
};

struct FinalizeResult {
  bool ok = true;
  std::string error;  // the writer thread's I/O error, if any
  WriterStats stats;
};

// Test seam: called on the writer thread before each record is written (e.g. to stall it deterministically).
struct WriterHooks {
  std::function<void(uint64_t seq)> before_write;
};

// kCreate: output_dir must not hold a dataset yet. kAppend: continue the finalised (complete or recovered)
// dataset in output_dir, or start one if it has none; used by a resumed collection run (docs/collect.md,
// "Resuming"). Appending continues the shard indices, seqs, counts and episode list (appended_runs in the
// manifest's run_info counts the appends). Episode ids are kept as given: a resumed run flies keyed episodes
// (quad_core/episode_key.h, issue 32), whose ids are index + 1 in every launch, so the appended episodes have
// the ids a straight run would have given them. A record whose episode id names an episode the dataset held
// before the append is rejected (kRejectedInvalid, with the reason), so (world_seed, episode_id) still names
// one flight.
enum class OpenMode { kCreate, kAppend };

class DatasetWriter {
 public:
  // Validates the config, creates output_dir (kCreate: it must not already hold a dataset: manifest.yaml or
  // shard_*; kAppend: see OpenMode), preallocates queue_capacity slots, writes the initial manifest (status
  // incomplete) and starts the writer thread. Throws std::invalid_argument (config) or std::runtime_error
  // (file system, or a dataset that cannot be appended to) with the reason.
  explicit DatasetWriter(const WriterConfig& config, WriterHooks hooks = {},
                         OpenMode mode = OpenMode::kCreate);
  ~DatasetWriter();
  DatasetWriter(const DatasetWriter&) = delete;
  DatasetWriter& operator=(const DatasetWriter&) = delete;

  // Thread-safe. Validates, assigns the next seq and copies the record into a free slot. With the block
  // policy it waits for a slot; with the drop policy it returns kDroppedQueueFull at once. Allocation-free
  // for valid input (a rejection builds its reason string).
  RecordResult Record(const PlanRecord& record);

  // Adds a key/value pair to the manifest's run_info (e.g. "sampling_seed"); written with the next manifest.
  void SetRunInfo(const std::string& key, const std::string& value);

  // Drains the queue, completes the last shard (fsync, rename *.partial), writes the final manifest and stops
  // the thread. Idempotent; safe to call from any thread except a signal handler.
  FinalizeResult Finalize();

  WriterStats stats() const;
  const WriterConfig& config() const;
  const RecordLayout& layout() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// Why a record is invalid for this writer, or "" when it is valid. Exposed for the planner's own checks.
std::string ValidatePlanRecord(const PlanRecord& record, const WriterConfig& config);

}  // namespace cpp_data_collector
