#include "cpp_data_collector/dataset_reader.h"

#include <fcntl.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <map>
#include <unordered_map>

namespace cpp_data_collector {

namespace fs = std::filesystem;

std::string DecodedRecord::plan_status_text() const {
  return std::string(head.plan_status_text, strnlen(head.plan_status_text, kStatusTextBytes));
}

std::vector<float> DecodedRecord::DepthMetres() const {
  std::vector<float> out(depth_code.size());
  for (size_t i = 0; i < depth_code.size(); ++i) out[i] = DecodeDepthCode(depth_code[i]);
  return out;
}

namespace {

bool EndsWith(const std::string& s, const std::string& suffix) {
  return s.size() >= suffix.size() && s.compare(s.size() - suffix.size(), suffix.size(), suffix) == 0;
}

// "shard_000012.qdr" or "shard_000012.qdr.partial" -> 12 and whether partial; nullopt for other names.
std::optional<std::pair<uint32_t, bool>> ParseShardName(const std::string& name) {
  const std::string prefix = kShardPrefix;
  if (name.rfind(prefix, 0) != 0) return std::nullopt;
  std::string rest = name.substr(prefix.size());
  bool partial = false;
  if (EndsWith(rest, std::string(kShardSuffix) + kPartialSuffix)) {
    partial = true;
    rest.resize(rest.size() - std::strlen(kShardSuffix) - std::strlen(kPartialSuffix));
  } else if (EndsWith(rest, kShardSuffix)) {
    rest.resize(rest.size() - std::strlen(kShardSuffix));
  } else {
    return std::nullopt;
  }
  if (rest.size() != 6 || !std::all_of(rest.begin(), rest.end(), ::isdigit)) return std::nullopt;
  return std::make_pair(static_cast<uint32_t>(std::stoul(rest)), partial);
}

}  // namespace

ShardReader::ShardReader(const std::string& path) : path_(path) {
  partial_ = EndsWith(path, kPartialSuffix);
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) throw FormatError(path + ": cannot open shard: " + std::strerror(errno));
  struct stat st {};
  if (::fstat(fd, &st) != 0 || !S_ISREG(st.st_mode)) {
    ::close(fd);
    throw FormatError(path + ": not a regular file");
  }
  file_size_ = static_cast<uint64_t>(st.st_size);
  if (file_size_ == 0) {
    ::close(fd);
    throw FormatError(path + ": not a quad_il record shard (empty file)");
  }
  void* map = ::mmap(nullptr, file_size_, PROT_READ, MAP_SHARED, fd, 0);
  ::close(fd);
  if (map == MAP_FAILED) throw FormatError(path + ": cannot memory-map: " + std::strerror(errno));
  map_ = static_cast<const uint8_t*>(map);
  try {
    header_ = ParseShardHeader(map_, file_size_, path);
    layout_ = RecordLayout::Compute(header_.layout_params());
  } catch (...) {
    Release();
    throw;
  }
  num_records_ = (file_size_ - kHeaderSize) / layout_.record_size;
  torn_tail_bytes_ = (file_size_ - kHeaderSize) % layout_.record_size;
}

ShardReader::~ShardReader() { Release(); }

ShardReader::ShardReader(ShardReader&& o) noexcept
    : path_(std::move(o.path_)),
      partial_(o.partial_),
      header_(std::move(o.header_)),
      layout_(o.layout_),
      map_(o.map_),
      file_size_(o.file_size_),
      num_records_(o.num_records_),
      torn_tail_bytes_(o.torn_tail_bytes_) {
  o.map_ = nullptr;
}

ShardReader& ShardReader::operator=(ShardReader&& o) noexcept {
  if (this != &o) {
    Release();
    path_ = std::move(o.path_);
    partial_ = o.partial_;
    header_ = std::move(o.header_);
    layout_ = o.layout_;
    map_ = o.map_;
    file_size_ = o.file_size_;
    num_records_ = o.num_records_;
    torn_tail_bytes_ = o.torn_tail_bytes_;
    o.map_ = nullptr;
  }
  return *this;
}

void ShardReader::Release() {
  if (map_ != nullptr) ::munmap(const_cast<uint8_t*>(map_), file_size_);
  map_ = nullptr;
}

std::string ShardReader::file_name() const { return fs::path(path_).filename().string(); }

const uint8_t* ShardReader::RecordBytes(uint64_t index) const {
  if (index >= num_records_) {
    throw std::out_of_range(path_ + ": record " + std::to_string(index) + " out of range (" +
                            std::to_string(num_records_) + " records)");
  }
  return map_ + kHeaderSize + index * layout_.record_size;
}

std::string ShardReader::CheckRecord(uint64_t index) const {
  const uint8_t* rec = RecordBytes(index);
  uint32_t magic = 0;
  uint32_t stored = 0;
  std::memcpy(&magic, rec, sizeof(magic));
  std::memcpy(&stored, rec + layout_.crc_offset, sizeof(stored));
  const uint32_t computed = Crc32(rec, layout_.crc_offset);
  if (computed != stored) {
    return "CRC mismatch (stored " + std::to_string(stored) + ", computed " + std::to_string(computed) + ")";
  }
  if (magic != kRecordMagic) return "bad record magic";
  return {};
}

DecodedRecord ShardReader::Decode(uint64_t index) const {
  const std::string problem = CheckRecord(index);
  if (!problem.empty()) {
    throw FormatError(path_ + ": record " + std::to_string(index) + ": " + problem);
  }
  const uint8_t* rec = RecordBytes(index);
  DecodedRecord r;
  std::memcpy(&r.head, rec, sizeof(RecordHead));
  const RecordHead& h = r.head;
  if (h.num_knots > layout_.params.max_knots || h.num_ctrl_pts > layout_.params.max_ctrl_pts ||
      h.num_yaw_pts > layout_.params.max_yaw_pts) {
    throw FormatError(path_ + ": record " + std::to_string(index) + ": counts exceed the layout's maxima");
  }
  r.knots.resize(h.num_knots);
  std::memcpy(r.knots.data(), rec + layout_.knots_offset, h.num_knots * sizeof(double));
  r.ctrl_pts_world.resize(h.num_ctrl_pts);
  std::memcpy(r.ctrl_pts_world.data(), rec + layout_.ctrl_offset, h.num_ctrl_pts * 3 * sizeof(double));
  r.yaw_pts.resize(h.num_yaw_pts);
  std::memcpy(r.yaw_pts.data(), rec + layout_.yaw_offset, h.num_yaw_pts * sizeof(double));
  r.width = layout_.params.image_width;
  r.height = layout_.params.image_height;
  r.depth_code.resize(static_cast<size_t>(r.width) * r.height);
  std::memcpy(r.depth_code.data(), rec + layout_.depth_offset, r.depth_code.size() * sizeof(uint16_t));
  return r;
}

DatasetReader::DatasetReader(const std::string& dir) : dir_(dir) {
  std::error_code ec;
  if (!fs::exists(dir, ec)) throw FormatError(dir + ": no such dataset directory");
  if (!fs::is_directory(dir, ec)) {
    throw FormatError(dir +
                      ": not a directory (pass the dataset directory that holds manifest.yaml and shards)");
  }
  std::map<uint32_t, std::pair<std::string, bool>> found;
  size_t entries = 0;
  bool has_manifest = false;
  for (const auto& entry : fs::directory_iterator(dir)) {
    ++entries;
    const std::string name = entry.path().filename().string();
    if (name == kManifestName) has_manifest = true;
    const auto parsed = ParseShardName(name);
    if (!parsed) continue;
    if (found.count(parsed->first)) {
      throw FormatError(dir + ": shard index " + std::to_string(parsed->first) + " appears twice (" +
                        found[parsed->first].first + " and " + name + ")");
    }
    found[parsed->first] = {name, parsed->second};
  }
  if (entries == 0) throw FormatError(dir + ": empty directory, not a quad_il dataset");
  if (!has_manifest && found.empty()) {
    throw FormatError(dir + ": not a quad_il dataset (no manifest.yaml and no shard_*.qdr files)");
  }
  if (has_manifest) manifest_ = ReadManifest(dir + "/" + kManifestName);
  uint32_t expected = 0;
  for (const auto& kv : found) {
    if (kv.first != expected) {
      throw FormatError(dir + ": " + ShardFileName(expected) +
                        " is missing (next shard found: " + kv.second.first + ")");
    }
    ++expected;
    shards_.emplace_back(dir + "/" + kv.second.first);
    const ShardReader& s = shards_.back();
    if (s.header().shard_index != kv.first) {
      throw FormatError(s.path() + ": header says shard index " + std::to_string(s.header().shard_index));
    }
    if (s.header().layout_json != shards_.front().header().layout_json) {
      throw FormatError(s.path() + ": record layout differs from " + shards_.front().file_name());
    }
  }
}

uint64_t DatasetReader::num_records() const {
  uint64_t n = 0;
  for (const auto& s : shards_) n += s.num_records();
  return n;
}

VerifyReport DatasetReader::Verify() const {
  VerifyReport rep;
  rep.dir = dir_;
  rep.has_manifest = manifest_.has_value();
  if (manifest_) rep.status = manifest_->status;
  if (!manifest_)
    rep.warnings.push_back("no manifest.yaml: counts and configuration cannot be cross-checked");
  if (manifest_ && manifest_->status == DatasetStatus::kIncomplete) {
    rep.warnings.push_back(
        manifest_->writer_error.empty()
            ? "dataset is incomplete: the writer did not finalise it (killed or still running)"
            : "dataset is incomplete: the writer failed: " + manifest_->writer_error);
  }
  for (size_t i = 0; i < shards_.size(); ++i) {
    const ShardReader& s = shards_[i];
    ShardCheck c;
    c.file = s.file_name();
    c.index = s.header().shard_index;
    c.partial = s.partial();
    c.records = s.num_records();
    c.torn_tail_bytes = s.torn_tail_bytes();
    for (uint64_t r = 0; r < s.num_records(); ++r) {
      const std::string problem = s.CheckRecord(r);
      if (problem.empty()) {
        ++rep.valid_records;
      } else {
        c.bad_records.push_back(r);
        rep.errors.push_back(c.file + " record " + std::to_string(r) + ": " + problem);
      }
    }
    if (c.torn_tail_bytes > 0) {
      const std::string what = c.file + ": torn tail of " + std::to_string(c.torn_tail_bytes) +
                               " bytes after record " + std::to_string(c.records) + " (skipped)";
      (c.partial ? rep.warnings : rep.errors).push_back(c.partial ? what : what + " in a completed shard");
    }
    if (c.partial && i + 1 != shards_.size())
      rep.errors.push_back(c.file + ": partial shard is not the last one");
    if (c.partial && manifest_ && manifest_->status != DatasetStatus::kIncomplete) {
      rep.errors.push_back(c.file + ": partial shard in a " + std::string(ToString(manifest_->status)) +
                           " dataset");
    }
    rep.shards.push_back(c);
  }
  if (manifest_) {
    const Manifest& m = *manifest_;
    std::unordered_map<std::string, const ShardCheck*> by_file;
    for (const auto& c : rep.shards) by_file[c.file] = &c;
    for (const auto& e : m.shards) {
      auto it = by_file.find(e.file);
      if (it == by_file.end()) {
        rep.errors.push_back("manifest lists " + e.file + " but the file is missing");
      } else if (it->second->records != e.records) {
        rep.errors.push_back(e.file + ": holds " + std::to_string(it->second->records) +
                             " records, the manifest says " + std::to_string(e.records));
      }
    }
    if (m.status != DatasetStatus::kIncomplete) {
      if (m.shards.size() != shards_.size()) {
        rep.errors.push_back("manifest lists " + std::to_string(m.shards.size()) +
                             " shards, the directory has " + std::to_string(shards_.size()));
      }
      if (m.counts.written != num_records()) {
        rep.errors.push_back("manifest counts " + std::to_string(m.counts.written) +
                             " written records, shards hold " + std::to_string(num_records()));
      }
    }
    if (!shards_.empty() && (m.config.image_width != shards_.front().header().image_width ||
                             m.config.image_height != shards_.front().header().image_height)) {
      rep.errors.push_back("manifest image size differs from the shard headers");
    }
  }
  if (shards_.empty()) rep.warnings.push_back("dataset holds no records");
  return rep;
}

namespace {
void RecountAndWriteManifest(const std::string& dir, Manifest* manifest, RecoverResult* result);
}  // namespace

RecoverResult RecoverDataset(const std::string& dir) {
  RecoverResult result;
  Manifest manifest;
  std::vector<std::string> partial_names;
  {
    DatasetReader reader(dir);
    if (!reader.manifest())
      throw FormatError(dir + ": no manifest.yaml: cannot recover (not written by DatasetWriter?)");
    manifest = *reader.manifest();
    if (manifest.status == DatasetStatus::kComplete)
      throw FormatError(dir + ": dataset is complete, nothing to recover");
    for (const ShardReader& s : reader.shards()) {
      if (!s.partial()) continue;
      uint64_t keep = s.num_records();
      while (keep > 0 && !s.CheckRecord(keep - 1).empty()) --keep;
      const uint64_t new_size = kHeaderSize + keep * s.layout().record_size;
      if (new_size != s.file_size()) {
        result.actions.push_back(s.file_name() + ": cut " + std::to_string(s.file_size() - new_size) +
                                 " bytes after record " + std::to_string(keep) +
                                 " (torn tail / trailing bad records)");
      }
      if (::truncate(s.path().c_str(), static_cast<off_t>(new_size)) != 0) {
        throw FormatError(s.path() + ": cannot truncate: " + std::strerror(errno));
      }
      partial_names.push_back(s.file_name());
      if (keep == 0) result.actions.push_back(s.file_name() + ": holds no complete record, removed");
    }
  }
  for (const std::string& name : partial_names) {
    const std::string from = dir + "/" + name;
    const std::string to = from.substr(0, from.size() - std::strlen(kPartialSuffix));
    if (fs::file_size(from) == kHeaderSize) {
      fs::remove(from);
      continue;
    }
    fs::rename(from, to);
    result.actions.push_back(name + ": renamed to " + fs::path(to).filename().string());
  }
  RecountAndWriteManifest(dir, &manifest, &result);
  return result;
}

namespace {
// Rewrites the manifest from the shards on disk (shard list, episodes, written count) with status recovered.
void RecountAndWriteManifest(const std::string& dir, Manifest* manifest_out, RecoverResult* result_out) {
  Manifest& manifest = *manifest_out;
  RecoverResult& result = *result_out;
  // Recount shards and episodes from what is on disk now.
  DatasetReader reader(dir);
  manifest.shards.clear();
  manifest.episodes.clear();
  manifest.counts.written = 0;
  std::unordered_map<int64_t, size_t> episode_index;
  for (const ShardReader& s : reader.shards()) {
    ShardEntry e;
    e.file = s.file_name();
    e.index = s.header().shard_index;
    e.records = s.num_records();
    e.bytes = s.file_size();
    for (uint64_t r = 0; r < s.num_records(); ++r) {
      if (!s.CheckRecord(r).empty()) continue;
      RecordHead h;
      std::memcpy(&h, s.RecordBytes(r), sizeof(h));
      if (r == 0) e.first_seq = h.seq;
      e.last_seq = h.seq;
      auto it = episode_index.find(h.episode_id);
      if (it == episode_index.end()) {
        episode_index.emplace(h.episode_id, manifest.episodes.size());
        manifest.episodes.push_back(EpisodeEntry{h.episode_id, h.world_seed, 1});
      } else {
        manifest.episodes[it->second].records += 1;
      }
      ++result.records;
    }
    manifest.counts.written += s.num_records();
    manifest.shards.push_back(e);
  }
  manifest.status = DatasetStatus::kRecovered;
  manifest.finalized_utc = UtcNowIso8601();
  WriteManifest(dir, manifest, true);
  result.actions.push_back("manifest rewritten with status recovered: " + std::to_string(result.records) +
                           " valid records in " + std::to_string(manifest.shards.size()) + " shards");
}
}  // namespace

RecoverResult TruncateDataset(const std::string& dir, uint64_t keep_records) {
  RecoverResult result;
  Manifest manifest;
  std::vector<std::pair<std::string, uint64_t>> cuts;  // (path, new size); size 0: remove the file
  {
    DatasetReader reader(dir);
    if (!reader.manifest()) throw FormatError(dir + ": no manifest.yaml: cannot truncate");
    manifest = *reader.manifest();
    if (manifest.status == DatasetStatus::kIncomplete) {
      throw FormatError(dir + ": dataset is incomplete: recover it (read_dataset recover) before truncating");
    }
    if (keep_records > reader.num_records()) {
      throw FormatError(dir + ": cannot keep " + std::to_string(keep_records) +
                        " records, the dataset holds " + std::to_string(reader.num_records()));
    }
    uint64_t before = 0;
    for (const ShardReader& s : reader.shards()) {
      if (s.partial()) throw FormatError(s.path() + ": partial shard in a finalised dataset");
      const uint64_t keep_here = keep_records > before ? std::min(s.num_records(), keep_records - before) : 0;
      for (uint64_t r = 0; r < keep_here; ++r) {
        const std::string problem = s.CheckRecord(r);
        if (!problem.empty()) {
          throw FormatError(s.path() + ": record " + std::to_string(r) + ": " + problem + " (not truncated)");
        }
      }
      if (keep_here < s.num_records() || s.torn_tail_bytes() > 0) {
        cuts.emplace_back(s.path(), keep_here == 0 ? 0 : kHeaderSize + keep_here * s.layout().record_size);
        result.actions.push_back(
            s.file_name() + ": " +
            (keep_here == 0 ? std::string("removed (") + std::to_string(s.num_records()) + " records)"
                            : "cut after record " + std::to_string(keep_here) + " (" +
                                  std::to_string(s.num_records() - keep_here) + " records removed)"));
      }
      before += s.num_records();
    }
  }
  // Shards are cut from the last one back, so an interruption never leaves a gap in the shard sequence.
  for (auto it = cuts.rbegin(); it != cuts.rend(); ++it) {
    if (it->second == 0) {
      fs::remove(it->first);
    } else if (::truncate(it->first.c_str(), static_cast<off_t>(it->second)) != 0) {
      throw FormatError(it->first + ": cannot truncate: " + std::strerror(errno));
    }
  }
  // Seqs and drops after the last kept record no longer belong to the dataset.
  uint64_t next_seq = 0;
  {
    DatasetReader reader(dir);
    if (!reader.shards().empty() && reader.shards().back().num_records() > 0) {
      const ShardReader& last = reader.shards().back();
      RecordHead h;
      std::memcpy(&h, last.RecordBytes(last.num_records() - 1), sizeof(h));
      next_seq = h.seq + 1;
    }
  }
  std::vector<uint64_t> drops;
  for (uint64_t seq : manifest.dropped_seqs) {
    if (seq < next_seq) drops.push_back(seq);
  }
  manifest.counts.dropped -= manifest.dropped_seqs.size() - drops.size();
  manifest.dropped_seqs = drops;
  manifest.counts.submitted = next_seq;
  RecountAndWriteManifest(dir, &manifest, &result);
  return result;
}

}  // namespace cpp_data_collector
