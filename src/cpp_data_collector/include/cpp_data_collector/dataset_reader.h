// Readers for datasets written by DatasetWriter: one shard (memory-mapped), a dataset directory, verification
// (CRC per record, torn tails, manifest cross-check) and recovery of a dataset whose writer was killed.
#pragma once

#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "cpp_data_collector/manifest.h"
#include "cpp_data_collector/record_format.h"

namespace cpp_data_collector {

// One record decoded into owning storage.
struct DecodedRecord {
  RecordHead head{};
  std::vector<double> knots;
  std::vector<std::array<double, 3>> ctrl_pts_world;
  std::vector<double> yaw_pts;
  uint32_t width = 0;
  uint32_t height = 0;
  std::vector<uint16_t> depth_code;  // row-major codes (record_format.h)

  std::string plan_status_text() const;
  std::vector<float> DepthMetres() const;  // DecodeDepthCode per pixel
};

// A memory-mapped shard (final or *.partial). Records are counted from the file size; bytes after the last
// complete record are the torn tail (a writer killed mid-record), reported and never read.
class ShardReader {
 public:
  // Throws FormatError: missing file, not a shard, other version, inconsistent header.
  explicit ShardReader(const std::string& path);
  ~ShardReader();
  ShardReader(ShardReader&& other) noexcept;
  ShardReader& operator=(ShardReader&& other) noexcept;
  ShardReader(const ShardReader&) = delete;
  ShardReader& operator=(const ShardReader&) = delete;

  const std::string& path() const { return path_; }
  std::string file_name() const;
  bool partial() const { return partial_; }
  const ShardHeader& header() const { return header_; }
  const RecordLayout& layout() const { return layout_; }
  uint64_t num_records() const { return num_records_; }
  uint64_t torn_tail_bytes() const { return torn_tail_bytes_; }
  uint64_t file_size() const { return file_size_; }

  const uint8_t* RecordBytes(uint64_t index) const;
  // "" when record `index` has the record magic and a matching CRC, else the problem.
  std::string CheckRecord(uint64_t index) const;
  // Throws FormatError naming the shard and record index when the record fails CheckRecord.
  DecodedRecord Decode(uint64_t index) const;

 private:
  void Release();
  std::string path_;
  bool partial_ = false;
  ShardHeader header_;
  RecordLayout layout_;
  const uint8_t* map_ = nullptr;
  uint64_t file_size_ = 0;
  uint64_t num_records_ = 0;
  uint64_t torn_tail_bytes_ = 0;
};

struct ShardCheck {
  std::string file;
  uint32_t index = 0;
  bool partial = false;
  uint64_t records = 0;               // complete records in the file
  uint64_t torn_tail_bytes = 0;       // bytes after the last complete record
  std::vector<uint64_t> bad_records;  // indices failing CheckRecord
};

struct VerifyReport {
  std::string dir;
  bool has_manifest = false;
  DatasetStatus status = DatasetStatus::kIncomplete;
  std::vector<ShardCheck> shards;
  uint64_t valid_records = 0;
  std::vector<std::string> errors;  // corruption: CRC mismatches, truncated final shards, manifest mismatches
  std::vector<std::string>
      warnings;  // expected after a crash: incomplete dataset, torn tail of a partial shard
  bool clean() const { return errors.empty() && warnings.empty(); }
};

// A dataset directory: shards in index order plus the manifest (when present).
class DatasetReader {
 public:
  // Throws FormatError with a clear reason: missing path, not a directory, empty directory, a directory with
  // no manifest and no shards (foreign), shard index gaps or duplicates, shards that disagree on the layout.
  explicit DatasetReader(const std::string& dir);

  const std::string& dir() const { return dir_; }
  const std::vector<ShardReader>& shards() const { return shards_; }
  const std::optional<Manifest>& manifest() const { return manifest_; }
  uint64_t num_records() const;  // complete records over all shards (CRC not checked)

  // Reads every record and cross-checks the manifest.
  VerifyReport Verify() const;

 private:
  std::string dir_;
  std::vector<ShardReader> shards_;
  std::optional<Manifest> manifest_;
};

struct RecoverResult {
  std::vector<std::string> actions;  // what was done, one line each
  uint64_t records = 0;              // valid records in the recovered dataset
};

// Repairs a dataset whose writer died: cuts each *.partial shard after its last valid record (the torn tail
// and trailing records failing CRC), renames it to its final name (or removes it when empty), recounts
// episodes and rewrites the manifest with status "recovered". Interior CRC failures are left in place (and
// stay reported by Verify). Throws FormatError for a dataset that is complete or has no manifest.
RecoverResult RecoverDataset(const std::string& dir);

// Keeps the first `keep_records` records (in shard order) of a finalised (complete or recovered) dataset and
// removes the rest: the shard holding the cut is truncated after its last kept record (removed when nothing
// is left), later shards are removed, episodes and counts are recounted and the manifest is rewritten with
// status "recovered". Used to drop the records of an episode that did not finish before a collection run is
// resumed (quad_il.collection.resume). Throws FormatError for an incomplete dataset (recover it first), a
// *.partial shard, a record failing its CRC among those kept, or keep_records > the records present.
RecoverResult TruncateDataset(const std::string& dir, uint64_t keep_records);

}  // namespace cpp_data_collector
