// manifest.yaml of a dataset directory: config, seeds, counts, drops, shards, software commit.
// Written atomically (temporary file + rename) at start, after every completed shard and when finalised, so a
// killed writer leaves a manifest describing everything up to its last completed shard.
#pragma once

#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "cpp_data_collector/writer_config.h"

namespace cpp_data_collector {

// kIncomplete: being written, or the writer died (shards may include a *.partial one). kComplete: finalised.
// kRecovered: an incomplete dataset repaired by `read_dataset recover` (torn tails cut, partial shards
// renamed).
enum class DatasetStatus { kIncomplete, kComplete, kRecovered };
const char* ToString(DatasetStatus status);

struct ShardEntry {
  std::string file;  // final name, e.g. shard_000003.qdr
  uint32_t index = 0;
  uint64_t records = 0;
  uint64_t bytes = 0;
  uint64_t first_seq = 0;
  uint64_t last_seq = 0;
};

struct EpisodeEntry {
  int64_t episode_id = 0;
  uint64_t world_seed = 0;
  uint64_t records = 0;
};

struct RecordCounts {
  uint64_t submitted = 0;  // Record() calls that passed validation (each got a seq)
  uint64_t written = 0;    // records in completed shards plus the current shard
  uint64_t dropped = 0;    // queue full under the drop policy
  uint64_t rejected = 0;   // invalid input (no seq)
  uint64_t lost = 0;       // accepted but not written because the writer thread failed (I/O error)
};

// At most this many dropped seqs are listed (the count is always exact).
inline constexpr size_t kMaxListedDrops = 1000;

struct Manifest {
  uint32_t format_version = 0;
  DatasetStatus status = DatasetStatus::kIncomplete;
  std::string created_utc;
  std::string finalized_utc;  // empty unless complete or recovered
  std::string software_commit;
  WriterConfig config;
  uint32_t record_size_bytes = 0;
  std::vector<std::pair<std::string, std::string>> run_info;  // caller-provided, e.g. sampling seeds
  RecordCounts counts;
  std::vector<uint64_t> dropped_seqs;  // first kMaxListedDrops
  std::vector<EpisodeEntry> episodes;  // in order of first appearance
  std::vector<ShardEntry> shards;      // completed shards in index order
  std::string writer_error;            // empty unless the writer thread failed
};

// Writes <dir>/manifest.yaml atomically; throws std::runtime_error on I/O failure.
void WriteManifest(const std::string& dir, const Manifest& manifest, bool fsync);
// Reads a manifest; throws FormatError naming the file and the bad key.
Manifest ReadManifest(const std::string& path);

// Current UTC time as ISO 8601 ("2024-05-01T12:00:00Z").
std::string UtcNowIso8601();

}  // namespace cpp_data_collector
