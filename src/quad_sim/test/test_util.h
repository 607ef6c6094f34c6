// Helpers shared by the quad_sim gtests.
#pragma once

#include "quad_core/vehicle_params.h"
#include "quad_sim/sim_config.h"

#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <string>

namespace quad_sim_test {

inline std::string RepoPath(const std::string& rel) { return std::string(QUAD_IL_ROOT) + "/" + rel; }

inline quad_core::VehicleParams DefaultVehicle() {
  return quad_core::LoadVehicleParams(RepoPath("config/vehicle.yaml"));
}

inline quad_sim::SimConfig DefaultSimConfig() { return quad_sim::LoadSimConfig(RepoPath("config/sim.yaml")); }

// A temporary file removed when the object goes out of scope.
class TempFile {
 public:
  explicit TempFile(const std::string& suffix) {
    char name[] = "/tmp/quad_sim_test_XXXXXX";
    const int fd = mkstemp(name);
    if (fd >= 0) close(fd);
    std::remove(name);
    path_ = std::string(name) + suffix;
  }
  ~TempFile() { std::remove(path_.c_str()); }
  void Write(const std::string& text) const { std::ofstream(path_) << text; }
  const std::string& path() const { return path_; }

 private:
  std::string path_;
};

inline std::string ReadFile(const std::string& path) {
  std::ifstream f(path);
  return std::string((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
}

}  // namespace quad_sim_test
