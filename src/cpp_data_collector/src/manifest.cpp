#include "cpp_data_collector/manifest.h"

#include <fcntl.h>
#include <unistd.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cerrno>
#include <charconv>
#include <cstdio>
#include <cstring>
#include <ctime>
#include <fstream>
#include <stdexcept>

#include "cpp_data_collector/record_format.h"

namespace cpp_data_collector {

const char* ToString(DatasetStatus status) {
  switch (status) {
    case DatasetStatus::kIncomplete:
      return "incomplete";
    case DatasetStatus::kComplete:
      return "complete";
    case DatasetStatus::kRecovered:
      return "recovered";
  }
  return "unknown";
}

std::string UtcNowIso8601() {
  const std::time_t now = std::time(nullptr);
  std::tm tm{};
  gmtime_r(&now, &tm);
  char buf[32];
  std::strftime(buf, sizeof(buf), "%Y-%m-%dT%H:%M:%SZ", &tm);
  return buf;
}

namespace {

// Shortest decimal that reads back as the same double (std::to_chars), so the manifest shows 0.1, not
// 0.10000000000000001, and still round-trips exactly.
std::string Shortest(double v) {
  char buf[64];
  const auto res = std::to_chars(buf, buf + sizeof(buf), v);
  return std::string(buf, res.ptr);
}

void FsyncPath(const std::string& path, int flags) {
  const int fd = ::open(path.c_str(), flags);
  if (fd < 0) return;
  ::fsync(fd);
  ::close(fd);
}

std::string Emit(const Manifest& m) {
  YAML::Emitter e;
  e << YAML::BeginMap;
  e << YAML::Comment("quad_il cpp_data_collector dataset manifest; format: docs/data_format.md");
  e << YAML::Key << "format" << YAML::Value << "quad_il.cpp_data_collector";
  e << YAML::Key << "format_version" << YAML::Value << m.format_version;
  e << YAML::Key << "status" << YAML::Value << ToString(m.status);
  e << YAML::Key << "created_utc" << YAML::Value << m.created_utc;
  e << YAML::Key << "finalized_utc" << YAML::Value << m.finalized_utc;
  e << YAML::Key << "software_commit" << YAML::Value << YAML::DoubleQuoted << m.software_commit;
  e << YAML::Key << "record_size_bytes" << YAML::Value << m.record_size_bytes;
  const WriterConfig& c = m.config;
  e << YAML::Key << "config" << YAML::Value << YAML::BeginMap;
  e << YAML::Key << "output_dir" << YAML::Value << c.output_dir;
  e << YAML::Key << "shard_size_mb" << YAML::Value << Shortest(c.shard_size_mb);
  e << YAML::Key << "queue_capacity" << YAML::Value << c.queue_capacity;
  e << YAML::Key << "full_queue_policy" << YAML::Value << ToString(c.full_queue_policy);
  e << YAML::Key << "image_width" << YAML::Value << c.image_width;
  e << YAML::Key << "image_height" << YAML::Value << c.image_height;
  e << YAML::Key << "max_ctrl_pts" << YAML::Value << c.max_ctrl_pts;
  e << YAML::Key << "max_yaw_pts" << YAML::Value << c.max_yaw_pts;
  e << YAML::Key << "fsync" << YAML::Value << c.fsync;
  e << YAML::Key << "software_commit" << YAML::Value << YAML::DoubleQuoted << c.software_commit;
  e << YAML::Key << "camera" << YAML::Value << YAML::BeginMap;
  e << YAML::Key << "fx_px" << YAML::Value << Shortest(c.camera_fx_px);
  e << YAML::Key << "fy_px" << YAML::Value << Shortest(c.camera_fy_px);
  e << YAML::Key << "cx_px" << YAML::Value << Shortest(c.camera_cx_px);
  e << YAML::Key << "cy_px" << YAML::Value << Shortest(c.camera_cy_px);
  e << YAML::EndMap << YAML::EndMap;
  e << YAML::Key << "run_info" << YAML::Value << YAML::BeginMap;
  for (const auto& kv : m.run_info)
    e << YAML::Key << kv.first << YAML::Value << YAML::DoubleQuoted << kv.second;
  e << YAML::EndMap;
  e << YAML::Key << "counts" << YAML::Value << YAML::BeginMap;
  e << YAML::Key << "submitted" << YAML::Value << m.counts.submitted;
  e << YAML::Key << "written" << YAML::Value << m.counts.written;
  e << YAML::Key << "dropped" << YAML::Value << m.counts.dropped;
  e << YAML::Key << "rejected" << YAML::Value << m.counts.rejected;
  e << YAML::Key << "lost" << YAML::Value << m.counts.lost;
  e << YAML::EndMap;
  e << YAML::Key << "dropped_seqs" << YAML::Value << YAML::Flow << m.dropped_seqs;
  std::vector<uint64_t> seeds;
  for (const auto& ep : m.episodes) {
    if (std::find(seeds.begin(), seeds.end(), ep.world_seed) == seeds.end()) seeds.push_back(ep.world_seed);
  }
  e << YAML::Key << "world_seeds" << YAML::Value << YAML::Flow << seeds;
  e << YAML::Key << "episodes" << YAML::Value << YAML::BeginSeq;
  for (const auto& ep : m.episodes) {
    e << YAML::Flow << YAML::BeginMap;
    e << YAML::Key << "episode_id" << YAML::Value << ep.episode_id;
    e << YAML::Key << "world_seed" << YAML::Value << ep.world_seed;
    e << YAML::Key << "records" << YAML::Value << ep.records;
    e << YAML::EndMap;
  }
  e << YAML::EndSeq;
  e << YAML::Key << "shards" << YAML::Value << YAML::BeginSeq;
  for (const auto& s : m.shards) {
    e << YAML::Flow << YAML::BeginMap;
    e << YAML::Key << "file" << YAML::Value << s.file;
    e << YAML::Key << "index" << YAML::Value << s.index;
    e << YAML::Key << "records" << YAML::Value << s.records;
    e << YAML::Key << "bytes" << YAML::Value << s.bytes;
    e << YAML::Key << "first_seq" << YAML::Value << s.first_seq;
    e << YAML::Key << "last_seq" << YAML::Value << s.last_seq;
    e << YAML::EndMap;
  }
  e << YAML::EndSeq;
  e << YAML::Key << "writer_error" << YAML::Value << YAML::DoubleQuoted << m.writer_error;
  e << YAML::EndMap;
  if (!e.good()) throw std::runtime_error("manifest: YAML emitter error: " + e.GetLastError());
  return std::string(e.c_str()) + "\n";
}

template <typename T>
T Need(const YAML::Node& node, const std::string& key, const std::string& path) {
  const YAML::Node v = node[key];
  if (!v) throw FormatError(path + ": missing key '" + key + "'");
  try {
    return v.as<T>();
  } catch (const YAML::Exception&) {
    throw FormatError(path + ": key '" + key + "' has a value of the wrong type");
  }
}

}  // namespace

void WriteManifest(const std::string& dir, const Manifest& manifest, bool fsync) {
  const std::string text = Emit(manifest);
  const std::string final_path = dir + "/" + kManifestName;
  const std::string tmp_path = final_path + ".tmp";
  const int fd = ::open(tmp_path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) throw std::runtime_error("manifest: cannot create " + tmp_path + ": " + std::strerror(errno));
  size_t done = 0;
  while (done < text.size()) {
    const ssize_t n = ::write(fd, text.data() + done, text.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) {
      // Disk full (ENOSPC, EFBIG) or an I/O error: the previous manifest stays in place; the torn temporary
      // file is removed so that nothing half-written is left beside it.
      const std::string err = std::strerror(errno);
      ::close(fd);
      ::unlink(tmp_path.c_str());
      throw std::runtime_error("manifest: cannot write " + tmp_path + ": " + err);
    }
    done += static_cast<size_t>(n);
  }
  if (fsync && ::fsync(fd) != 0) {
    const std::string err = std::strerror(errno);
    ::close(fd);
    ::unlink(tmp_path.c_str());
    throw std::runtime_error("manifest: cannot fsync " + tmp_path + ": " + err);
  }
  ::close(fd);
  if (::rename(tmp_path.c_str(), final_path.c_str()) != 0) {
    const std::string err = std::strerror(errno);
    ::unlink(tmp_path.c_str());
    throw std::runtime_error("manifest: cannot rename " + tmp_path + ": " + err);
  }
  if (fsync) FsyncPath(dir, O_RDONLY | O_DIRECTORY);
}

Manifest ReadManifest(const std::string& path) {
  YAML::Node root;
  try {
    root = YAML::LoadFile(path);
  } catch (const YAML::BadFile&) {
    throw FormatError(path + ": cannot open manifest");
  } catch (const YAML::Exception& e) {
    throw FormatError(path + ": manifest is not valid YAML: " + e.what());
  }
  if (!root.IsMap() || !root["format"] || root["format"].as<std::string>() != "quad_il.cpp_data_collector") {
    throw FormatError(path + ": not a quad_il cpp_data_collector manifest (missing 'format' key)");
  }
  Manifest m;
  m.format_version = Need<uint32_t>(root, "format_version", path);
  if (m.format_version != kFormatVersion) {
    throw FormatError(path + ": manifest format version " + std::to_string(m.format_version) +
                      " is not supported (this reader reads version " + std::to_string(kFormatVersion) + ")");
  }
  const std::string status = Need<std::string>(root, "status", path);
  if (status == "incomplete") {
    m.status = DatasetStatus::kIncomplete;
  } else if (status == "complete") {
    m.status = DatasetStatus::kComplete;
  } else if (status == "recovered") {
    m.status = DatasetStatus::kRecovered;
  } else {
    throw FormatError(path + ": unknown status '" + status + "'");
  }
  m.created_utc = Need<std::string>(root, "created_utc", path);
  m.finalized_utc = Need<std::string>(root, "finalized_utc", path);
  m.software_commit = Need<std::string>(root, "software_commit", path);
  m.record_size_bytes = Need<uint32_t>(root, "record_size_bytes", path);
  const YAML::Node c = root["config"];
  if (!c || !c.IsMap()) throw FormatError(path + ": missing key 'config'");
  m.config.output_dir = Need<std::string>(c, "output_dir", path);
  m.config.shard_size_mb = Need<double>(c, "shard_size_mb", path);
  m.config.queue_capacity = Need<uint32_t>(c, "queue_capacity", path);
  try {
    m.config.full_queue_policy = ParseFullQueuePolicy(Need<std::string>(c, "full_queue_policy", path));
  } catch (const std::invalid_argument& e) {
    throw FormatError(path + ": " + e.what());
  }
  m.config.image_width = Need<uint32_t>(c, "image_width", path);
  m.config.image_height = Need<uint32_t>(c, "image_height", path);
  m.config.max_ctrl_pts = Need<uint32_t>(c, "max_ctrl_pts", path);
  m.config.max_yaw_pts = Need<uint32_t>(c, "max_yaw_pts", path);
  m.config.fsync = Need<bool>(c, "fsync", path);
  m.config.software_commit = Need<std::string>(c, "software_commit", path);
  if (const YAML::Node cam = c["camera"]) {
    m.config.camera_fx_px = Need<double>(cam, "fx_px", path);
    m.config.camera_fy_px = Need<double>(cam, "fy_px", path);
    m.config.camera_cx_px = Need<double>(cam, "cx_px", path);
    m.config.camera_cy_px = Need<double>(cam, "cy_px", path);
  }
  if (const YAML::Node ri = root["run_info"]) {
    for (const auto& kv : ri)
      m.run_info.emplace_back(kv.first.as<std::string>(), kv.second.as<std::string>());
  }
  const YAML::Node counts = root["counts"];
  if (!counts || !counts.IsMap()) throw FormatError(path + ": missing key 'counts'");
  m.counts.submitted = Need<uint64_t>(counts, "submitted", path);
  m.counts.written = Need<uint64_t>(counts, "written", path);
  m.counts.dropped = Need<uint64_t>(counts, "dropped", path);
  m.counts.rejected = Need<uint64_t>(counts, "rejected", path);
  m.counts.lost = Need<uint64_t>(counts, "lost", path);
  m.dropped_seqs = Need<std::vector<uint64_t>>(root, "dropped_seqs", path);
  for (const auto& ep : root["episodes"]) {
    EpisodeEntry e;
    e.episode_id = Need<int64_t>(ep, "episode_id", path);
    e.world_seed = Need<uint64_t>(ep, "world_seed", path);
    e.records = Need<uint64_t>(ep, "records", path);
    m.episodes.push_back(e);
  }
  for (const auto& sh : root["shards"]) {
    ShardEntry s;
    s.file = Need<std::string>(sh, "file", path);
    s.index = Need<uint32_t>(sh, "index", path);
    s.records = Need<uint64_t>(sh, "records", path);
    s.bytes = Need<uint64_t>(sh, "bytes", path);
    s.first_seq = Need<uint64_t>(sh, "first_seq", path);
    s.last_seq = Need<uint64_t>(sh, "last_seq", path);
    m.shards.push_back(s);
  }
  m.writer_error = Need<std::string>(root, "writer_error", path);
  return m;
}

}  // namespace cpp_data_collector
