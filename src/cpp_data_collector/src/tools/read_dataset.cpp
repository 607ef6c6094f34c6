// read_dataset: verify, dump and recover datasets written by DatasetWriter (format: docs/data_format.md).
#include <cmath>
#include <cstdio>
#include <cstring>
#include <iostream>
#include <stdexcept>
#include <string>

#include "cpp_data_collector/dataset_reader.h"

namespace cdc = cpp_data_collector;

namespace {

constexpr char kUsage[] =
    "usage: read_dataset verify DIR\n"
    "       read_dataset dump DIR [--format text|jsonl] [--depth none|crc|full] [--first N] [--count N]\n"
    "       read_dataset recover DIR\n"
    "       read_dataset truncate DIR --keep N\n"
    "verify   checks every record's CRC, torn tails and the manifest; prints a report.\n"
    "         exit 0 clean, 3 only warnings (incomplete dataset, torn tail of a partial shard), 1 errors\n"
    "dump     prints records (jsonl: one JSON object per line, doubles with 17 significant digits, NaN and\n"
    "         Infinity as Python's json reads them, strings byte-wise with \\u00XX for bytes >= 0x80)\n"
    "recover  repairs a dataset whose writer died: cuts torn tails, renames *.partial shards, rewrites the\n"
    "         manifest with status recovered\n"
    "truncate keeps the first N records of a finalised dataset and removes the rest (the records of an\n"
    "         episode that did not finish, before a collection run is resumed); manifest status recovered\n"
    "exit 2: bad arguments, or DIR is not a readable dataset.\n";

std::string Num(double v) {
  if (std::isnan(v)) return "NaN";
  if (std::isinf(v)) return v > 0 ? "Infinity" : "-Infinity";
  char buf[40];
  std::snprintf(buf, sizeof(buf), "%.17g", v);
  return buf;
}

std::string JsonString(const std::string& s) {
  std::string out = "\"";
  for (unsigned char c : s) {
    if (c == '"' || c == '\\') {
      out += '\\';
      out += static_cast<char>(c);
    } else if (c < 0x20 || c >= 0x80) {
      char buf[8];
      std::snprintf(buf, sizeof(buf), "\\u%04x", c);
      out += buf;
    } else {
      out += static_cast<char>(c);
    }
  }
  return out + "\"";
}

template <typename T>
std::string Array(const T* v, size_t n) {
  std::string out = "[";
  for (size_t i = 0; i < n; ++i) out += (i ? "," : "") + Num(static_cast<double>(v[i]));
  return out + "]";
}

int Verify(const std::string& dir) {
  const cdc::DatasetReader reader(dir);
  const cdc::VerifyReport rep = reader.Verify();
  std::printf("dataset %s: status %s, %zu shards, %llu valid records\n", dir.c_str(),
              rep.has_manifest ? cdc::ToString(rep.status) : "(no manifest)", rep.shards.size(),
              static_cast<unsigned long long>(rep.valid_records));
  for (const auto& c : rep.shards) {
    std::printf("  %s: %llu records, %zu bad, torn tail %llu bytes%s\n", c.file.c_str(),
                static_cast<unsigned long long>(c.records), c.bad_records.size(),
                static_cast<unsigned long long>(c.torn_tail_bytes), c.partial ? " (partial)" : "");
  }
  for (const auto& w : rep.warnings) std::printf("WARNING %s\n", w.c_str());
  for (const auto& e : rep.errors) std::printf("ERROR %s\n", e.c_str());
  if (!rep.errors.empty()) return 1;
  return rep.warnings.empty() ? 0 : 3;
}

int Dump(const std::string& dir, const std::string& format, const std::string& depth, uint64_t first,
         uint64_t count) {
  const cdc::DatasetReader reader(dir);
  uint64_t global = 0;
  int status = 0;
  for (const cdc::ShardReader& s : reader.shards()) {
    for (uint64_t i = 0; i < s.num_records(); ++i, ++global) {
      if (global < first || global - first >= count) continue;
      cdc::DecodedRecord r;
      try {
        r = s.Decode(i);
      } catch (const cdc::FormatError& e) {
        std::fprintf(stderr, "read_dataset: %s\n", e.what());
        status = 1;
        continue;
      }
      const cdc::RecordHead& h = r.head;
      const uint32_t depth_crc = cdc::Crc32(r.depth_code.data(), r.depth_code.size() * sizeof(uint16_t));
      if (format == "text") {
        std::printf(
            "%s[%llu] seq %llu episode %lld seed %llu t %.6f depth@%.6f odom@%.6f p (%.3f %.3f %.3f) "
            "spline order %d n %u status %d '%s' total %.3f ms depth_crc %u\n",
            s.file_name().c_str(), static_cast<unsigned long long>(i), static_cast<unsigned long long>(h.seq),
            static_cast<long long>(h.episode_id), static_cast<unsigned long long>(h.world_seed), h.sim_time_s,
            h.depth_stamp_s, h.odom_stamp_s, h.p_world_body[0], h.p_world_body[1], h.p_world_body[2],
            h.bspline_order, h.num_ctrl_pts, h.plan_status_code, r.plan_status_text().c_str(), h.t_total_ms,
            depth_crc);
        continue;
      }
      std::string line = "{";
      line += "\"shard\":" + JsonString(s.file_name()) + ",\"index\":" + std::to_string(i);
      line += ",\"seq\":" + std::to_string(h.seq) + ",\"episode_id\":" + std::to_string(h.episode_id);
      line += ",\"world_seed\":" + std::to_string(h.world_seed);
      line += ",\"sim_time_s\":" + Num(h.sim_time_s) + ",\"depth_stamp_s\":" + Num(h.depth_stamp_s);
      line += ",\"odom_stamp_s\":" + Num(h.odom_stamp_s);
      line += ",\"p_world_body\":" + Array(h.p_world_body, 3) + ",\"v_world\":" + Array(h.v_world, 3);
      line += ",\"q_world_body\":" + Array(h.q_world_body, 4) + ",\"w_body\":" + Array(h.w_body, 3);
      line += ",\"goal_world\":" + Array(h.goal_world, 3);
      line += ",\"bspline_start_time_s\":" + Num(h.bspline_start_time_s);
      line += ",\"bspline_yaw_dt_s\":" + Num(h.bspline_yaw_dt_s);
      line += ",\"bspline_traj_id\":" + std::to_string(h.bspline_traj_id);
      line += ",\"bspline_order\":" + std::to_string(h.bspline_order);
      line += ",\"knots\":" + Array(r.knots.data(), r.knots.size());
      line += ",\"ctrl_pts_world\":[";
      for (size_t k = 0; k < r.ctrl_pts_world.size(); ++k) {
        line += (k ? "," : "") + Array(r.ctrl_pts_world[k].data(), 3);
      }
      line += "],\"yaw_pts\":" + Array(r.yaw_pts.data(), r.yaw_pts.size());
      line += ",\"plan_status_code\":" + std::to_string(h.plan_status_code);
      line += ",\"plan_status_text\":" + JsonString(r.plan_status_text());
      line += ",\"t_map_update_ms\":" + Num(h.t_map_update_ms) + ",\"t_frontend_ms\":" + Num(h.t_frontend_ms);
      line += ",\"t_optimization_ms\":" + Num(h.t_optimization_ms) + ",\"t_total_ms\":" + Num(h.t_total_ms);
      line += ",\"depth_width\":" + std::to_string(r.width) + ",\"depth_height\":" + std::to_string(r.height);
      if (depth != "none") line += ",\"depth_crc32\":" + std::to_string(depth_crc);
      if (depth == "full") line += ",\"depth_code\":" + Array(r.depth_code.data(), r.depth_code.size());
      line += "}\n";
      std::fwrite(line.data(), 1, line.size(), stdout);
    }
  }
  return status;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 3) {
    std::cerr << kUsage;
    return 2;
  }
  const std::string command = argv[1];
  const std::string dir = argv[2];
  std::string format = "text";
  std::string depth = "crc";
  uint64_t first = 0;
  uint64_t count = UINT64_MAX;
  uint64_t keep = UINT64_MAX;
  for (int i = 3; i < argc; ++i) {
    const std::string flag = argv[i];
    if (i + 1 >= argc) {
      std::cerr << "read_dataset: " << flag << " needs a value\n" << kUsage;
      return 2;
    }
    const std::string v = argv[++i];
    try {
      if (flag == "--format" && (v == "text" || v == "jsonl")) {
        format = v;
      } else if (flag == "--depth" && (v == "none" || v == "crc" || v == "full")) {
        depth = v;
      } else if (flag == "--first") {
        first = std::stoull(v);
      } else if (flag == "--count") {
        count = std::stoull(v);
      } else if (flag == "--keep" && command == "truncate") {
        keep = std::stoull(v);
      } else {
        throw std::invalid_argument("bad option");
      }
    } catch (const std::exception&) {
      std::cerr << "read_dataset: bad option " << flag << " " << v << "\n" << kUsage;
      return 2;
    }
  }
  try {
    if (command == "verify") return Verify(dir);
    if (command == "dump") return Dump(dir, format, depth, first, count);
    if (command == "recover") {
      const cdc::RecoverResult r = cdc::RecoverDataset(dir);
      for (const auto& a : r.actions) std::printf("%s\n", a.c_str());
      return 0;
    }
    if (command == "truncate") {
      if (keep == UINT64_MAX) {
        std::cerr << "read_dataset: truncate needs --keep N\n" << kUsage;
        return 2;
      }
      const cdc::RecoverResult r = cdc::TruncateDataset(dir, keep);
      for (const auto& a : r.actions) std::printf("%s\n", a.c_str());
      return 0;
    }
  } catch (const cdc::FormatError& e) {
    std::cerr << "read_dataset: " << e.what() << "\n";
    return 2;
  } catch (const std::exception& e) {
    std::cerr << "read_dataset: " << e.what() << "\n";
    return 1;
  }
  std::cerr << "read_dataset: unknown command '" << command << "'\n" << kUsage;
  return 2;
}
