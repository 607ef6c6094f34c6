// Helpers shared by the cpp_data_collector gtests.
#pragma once

#include <stdlib.h>

#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include "cpp_data_collector/dataset_writer.h"
#include "cpp_data_collector/synthetic.h"

namespace cdc_test {

// A fresh directory under $TMPDIR (or /tmp), removed with everything in it at the end of the scope.
class TempDir {
 public:
  TempDir() {
    const char* base = std::getenv("TMPDIR");
    std::string templ = std::string(base ? base : "/tmp") + "/cdc_test_XXXXXX";
    std::vector<char> buf(templ.begin(), templ.end());
    buf.push_back('\0');
    path_ = mkdtemp(buf.data());
  }
  ~TempDir() {
    std::error_code ec;
    std::filesystem::remove_all(path_, ec);
  }
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;
  const std::string& path() const { return path_; }
  std::string operator/(const std::string& name) const { return path_ + "/" + name; }

 private:
  std::string path_;
};

inline cpp_data_collector::WriterConfig SmallConfig(const std::string& dir, uint32_t w = 32,
                                                    uint32_t h = 24) {
  cpp_data_collector::WriterConfig c;
  c.output_dir = dir;
  c.image_width = w;
  c.image_height = h;
  c.max_ctrl_pts = 40;
  c.max_yaw_pts = 40;
  c.queue_capacity = 8;
  c.fsync = false;
  c.software_commit = "test-commit";
  return c;
}

inline cpp_data_collector::SyntheticConfig SmallSynthetic(uint64_t seed, uint32_t w = 32, uint32_t h = 24) {
  cpp_data_collector::SyntheticConfig s;
  s.seed = seed;
  s.width = w;
  s.height = h;
  s.records_per_episode = 7;
  s.boxes_per_world = 12;
  return s;
}

inline std::vector<uint8_t> ReadBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::vector<uint8_t>(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

inline void WriteBytes(const std::string& path, const std::vector<uint8_t>& bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(reinterpret_cast<const char*>(bytes.data()), static_cast<std::streamsize>(bytes.size()));
}

}  // namespace cdc_test
