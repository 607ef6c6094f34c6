// The simulated world: the ground plane z = 0 plus oriented boxes, generated from a seed and a config or
// loaded from a world YAML file.
#pragma once

#include "quad_sim/geometry.h"

#include <Eigen/Core>

#include <cstdint>
#include <string>
#include <vector>

namespace quad_core {
class StrictYaml;
}

namespace quad_sim {

struct World {
  std::vector<OrientedBox> boxes;
  Eigen::Vector3d bounds_min_m =
      Eigen::Vector3d(-20.0, -20.0, 0.0);  // the flying area (used by the voxel map)
  Eigen::Vector3d bounds_max_m = Eigen::Vector3d(20.0, 20.0, 5.0);
  uint64_t seed = 0;  // the generator seed (0 for hand-built worlds); recorded for reproducibility

  // Throws std::invalid_argument naming the box and field for NaN/Inf, non-positive sizes, a zero quaternion
  // or inverted bounds.
  void Validate() const;
};

bool operator==(const World& a, const World& b);  // exact (bitwise) equality of every number
inline bool operator!=(const World& a, const World& b) { return !(a == b); }

// A sphere the generator keeps free of boxes (around the start and the goal).
struct ClearZone {
  Eigen::Vector3d center_world_m = Eigen::Vector3d::Zero();
  double radius_m = 0.0;
};

struct WorldGenConfig {
  Eigen::Vector3d bounds_min_m = Eigen::Vector3d(-20.0, -20.0, 0.0);
  Eigen::Vector3d bounds_max_m = Eigen::Vector3d(20.0, 20.0, 5.0);
  int num_boxes = 200;                   // used when density_boxes_per_100m2 is 0
  double density_boxes_per_100m2 = 0.0;  // > 0: number of boxes = density * area / 100 (rounded)
  Eigen::Vector3d size_min_m = Eigen::Vector3d(0.3, 0.3, 0.5);
  Eigen::Vector3d size_max_m = Eigen::Vector3d(1.5, 1.5, 5.0);
  double center_z_min_m = 0.0;  // range of the box centres' heights
  double center_z_max_m = 3.0;
  double max_roll_deg = 30.0;  // roll, pitch uniform in [-max, max]; yaw uniform in [-180, 180)
  double max_pitch_deg = 30.0;
  std::vector<ClearZone> clear_zones;  // no box may come closer than radius to a zone's centre
  double clear_radius_m = 2.0;         // radius of the zones added with AddClearZone (start, goal)
  double min_gap_m = 0.5;              // exact minimum distance between any two boxes
  int max_attempts_per_box = 200;      // rejection sampling; fewer boxes than asked is an error

  int TargetBoxCount() const;
  void AddClearZone(const Eigen::Vector3d& center_world_m) {
    clear_zones.push_back({center_world_m, clear_radius_m});
  }
  void Validate() const;  // throws std::invalid_argument naming the field
};

// Deterministic in (config, seed) on every platform: the generator draws from a 64-bit Mersenne twister
// through its own uniform mapping (std:: distributions are implementation-defined). Throws std::runtime_error
// if the boxes do not fit (too dense for the gap and clear zones).
World GenerateWorld(const WorldGenConfig& config, uint64_t seed);

// Reads the generator keys (all at the top level of `y`).
WorldGenConfig ReadWorldGenConfig(quad_core::StrictYaml* y);

// World YAML file: `format: quad_sim_world`, `version: 1`, seed, bounds and one entry per box
// (center_m, q_xyzw, size_m), numbers written with 17 significant digits so that a round trip is exact.
void SaveWorld(const World& world, const std::string& path);
World LoadWorld(const std::string& path);
std::string WorldToYaml(const World& world);
World WorldFromYaml(const std::string& text, const std::string& source = "<string>");

}  // namespace quad_sim
