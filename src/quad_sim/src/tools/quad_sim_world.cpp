// quad_sim_world: command-line access to the world generator, the world file format and the voxel map export.
//
//   quad_sim_world generate --config config/sim.yaml --seed 7 --out world.yaml
//                           [--start x,y,z --goal x,y,z]   (clear zones; default: the config's start and
//                           goal)
//   quad_sim_world voxelize --config config/sim.yaml (--world world.yaml | --seed 7) --out map.bt
//   quad_sim_world check --world world.yaml
// Prints one human-readable summary line on stdout; errors go to stderr with exit code 1 (bad input) or 2
// (usage).
#include "quad_sim/sim_config.h"
#include "quad_sim/voxel_map.h"
#include "quad_sim/world.h"

#include <cstdio>
#include <iostream>
#include <map>
#include <sstream>
#include <stdexcept>
#include <string>

namespace {

struct UsageError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

const char* kUsage =
    "usage: quad_sim_world generate --config SIM_YAML --seed N --out WORLD_YAML [--start X,Y,Z --goal "
    "X,Y,Z]\n"
    "       quad_sim_world voxelize --config SIM_YAML (--world WORLD_YAML | --seed N) --out MAP_BT\n"
    "       quad_sim_world check --world WORLD_YAML\n";

std::map<std::string, std::string> ParseFlags(int argc, char** argv) {
  std::map<std::string, std::string> flags;
  for (int i = 2; i < argc; i += 2) {
    const std::string key = argv[i];
    if (key.rfind("--", 0) != 0 || i + 1 >= argc) throw UsageError("bad argument '" + key + "'");
    flags[key.substr(2)] = argv[i + 1];
  }
  return flags;
}

std::string Need(const std::map<std::string, std::string>& flags, const std::string& key) {
  auto it = flags.find(key);
  if (it == flags.end()) throw UsageError("missing --" + key);
  return it->second;
}

Eigen::Vector3d ParseVector(const std::string& text) {
  std::stringstream s(text);
  Eigen::Vector3d v;
  char c1 = 0, c2 = 0;
  if (!(s >> v.x() >> c1 >> v.y() >> c2 >> v.z()) || c1 != ',' || c2 != ',' || !v.allFinite()) {
    throw UsageError("'" + text + "' is not a finite x,y,z");
  }
  return v;
}

uint64_t ParseSeed(const std::string& text) {
  size_t used = 0;
  const unsigned long long v = std::stoull(text, &used);
  if (used != text.size()) throw UsageError("'" + text + "' is not a seed");
  return v;
}

quad_sim::WorldGenConfig GenConfig(const quad_sim::SimConfig& cfg,
                                   const std::map<std::string, std::string>& flags) {
  quad_sim::WorldGenConfig gen = cfg.world_gen;
  if (flags.count("start") || flags.count("goal")) {
    gen.clear_zones.resize(gen.clear_zones.size() - 2);  // replace the config's start and goal zones
    gen.AddClearZone(flags.count("start") ? ParseVector(flags.at("start")) : cfg.start_m);
    gen.AddClearZone(flags.count("goal") ? ParseVector(flags.at("goal")) : cfg.goal_m);
  }
  return gen;
}

int Run(int argc, char** argv) {
  if (argc < 2) throw UsageError("missing command");
  const std::string cmd = argv[1];
  const auto flags = ParseFlags(argc, argv);
  if (cmd == "generate") {
    const quad_sim::SimConfig cfg = quad_sim::LoadSimConfig(Need(flags, "config"));
    const quad_sim::World w = quad_sim::GenerateWorld(GenConfig(cfg, flags), ParseSeed(Need(flags, "seed")));
    quad_sim::SaveWorld(w, Need(flags, "out"));
    std::cout << "generated " << w.boxes.size() << " boxes (seed " << w.seed << ") -> " << flags.at("out")
              << "\n";
  } else if (cmd == "voxelize") {
    const quad_sim::SimConfig cfg = quad_sim::LoadSimConfig(Need(flags, "config"));
    const quad_sim::World w =
        flags.count("world") ? quad_sim::LoadWorld(flags.at("world"))
                             : quad_sim::GenerateWorld(GenConfig(cfg, flags), ParseSeed(Need(flags, "seed")));
    const quad_sim::VoxelMap m = quad_sim::VoxelMap::FromWorld(w, cfg.voxel_map);
    m.WriteOctomap(Need(flags, "out"));
    std::cout << "voxelized " << w.boxes.size() << " boxes: " << m.NumOccupied() << " occupied voxels at "
              << m.resolution_m() << " m -> " << flags.at("out") << "\n";
  } else if (cmd == "check") {
    const quad_sim::World w = quad_sim::LoadWorld(Need(flags, "world"));
    std::cout << "ok: " << w.boxes.size() << " boxes, seed " << w.seed << "\n";
  } else {
    throw UsageError("unknown command '" + cmd + "'");
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  try {
    return Run(argc, argv);
  } catch (const UsageError& e) {
    std::cerr << "quad_sim_world: " << e.what() << "\n" << kUsage;
    return 2;
  } catch (const std::exception& e) {
    std::cerr << "quad_sim_world: " << e.what() << "\n";
    return 1;
  }
}
