// config_check: loads one YAML file with the strict C++ loader of its kind, as the nodes do, and reports the
// loader's error if it does not load (tests/python/test_shipped_configs.py loads every shipped file this
// way).
//
//   config_check KIND FILE
//
// KIND: sim (quad_sim::LoadSimConfig, which also loads its vehicle_file), vehicle
// (quad_core::LoadVehicleParams), world (quad_sim::LoadWorld), tracker (kr_tracker::LoadTrackerConfig),
// planner (fast_planner::LoadPlannerConfig), collector (cpp_data_collector::LoadWriterConfigFile). Prints
// "ok: KIND FILE" on stdout. Exit status: 0 loaded, 1 the loader refused it (its message on stderr), 2 usage.
#include <cpp_data_collector/writer_config.h>
#include <kr_tracker/config.h>
#include <quad_core/vehicle_params.h>
#include <quad_sim/sim_config.h>
#include <quad_sim/world.h>

#include <functional>
#include <iostream>
#include <map>
#include <stdexcept>
#include <string>

#include "fast_planner/planner_config.h"

int main(int argc, char** argv) {
  const std::map<std::string, std::function<void(const std::string&)>> loaders = {
      {"sim", [](const std::string& f) { quad_sim::LoadSimConfig(f); }},
      {"vehicle", [](const std::string& f) { quad_core::LoadVehicleParams(f); }},
      {"world", [](const std::string& f) { quad_sim::LoadWorld(f); }},
      {"tracker", [](const std::string& f) { kr_tracker::LoadTrackerConfig(f); }},
      {"planner", [](const std::string& f) { fast_planner::LoadPlannerConfig(f); }},
      {"collector", [](const std::string& f) { cpp_data_collector::LoadWriterConfigFile(f); }},
  };
  if (argc == 2 && (std::string(argv[1]) == "--help" || std::string(argv[1]) == "-h")) {
    std::cout
        << "usage: config_check KIND FILE   (KIND: sim, vehicle, world, tracker, planner, collector)\n"
           "  loads FILE with the strict loader of KIND; exit 0 loaded, 1 refused (reason on stderr), 2 "
           "usage\n";
    return 0;
  }
  const auto it = argc == 3 ? loaders.find(argv[1]) : loaders.end();
  if (it == loaders.end()) {
    std::cerr
        << "config_check: " << (argc == 3 ? "unknown kind '" + std::string(argv[1]) + "'" : "bad arguments")
        << "\nusage: config_check KIND FILE   (KIND: sim, vehicle, world, tracker, planner, collector)\n";
    return 2;
  }
  try {
    it->second(argv[2]);
  } catch (const std::exception& e) {
    std::cerr << "config_check: " << argv[1] << " " << argv[2] << ": " << e.what() << "\n";
    return 1;
  }
  std::cout << "ok: " << argv[1] << " " << argv[2] << "\n";
  return 0;
}
