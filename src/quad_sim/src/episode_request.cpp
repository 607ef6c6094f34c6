#include "quad_sim/episode_request.h"

#include "quad_sim/math_utils.h"

#include <stdexcept>

namespace quad_sim {

EpisodeSetup ResolveEpisode(const SimConfig& config, const EpisodeRequest& request) {
  EpisodeSetup e;
  e.start_world_m = config.start_m;
  e.start_yaw_rad = config.start_yaw_rad;
  e.goal_world_m = config.goal_m;
  if (!request.q_start_wxyz.isZero(0.0)) {
    const Eigen::Vector4d& w = request.q_start_wxyz;
    const Eigen::Quaterniond q(w[0], w[1], w[2], w[3]);
    if (!q.coeffs().allFinite()) throw std::invalid_argument("start orientation is not finite");
    e.start_world_m = request.start_world_m;
    e.start_yaw_rad = YawOf(q.normalized());
    e.goal_world_m = request.goal_world_m;
  }
  if (!request.world_file.empty()) {
    e.world = LoadWorld(request.world_file);
  } else if (!config.world_file.empty() && request.seed == 0) {
    e.world = LoadWorld(config.world_file);
  } else {
    WorldGenConfig gen = config.world_gen;
    gen.clear_zones.resize(gen.clear_zones.size() - 2);  // drop the configured start/goal zones ...
    gen.AddClearZone(e.start_world_m);                   // ... and keep this episode's start and goal clear
    gen.AddClearZone(e.goal_world_m);
    e.world = GenerateWorld(gen, request.seed != 0 ? request.seed : config.world_seed);
  }
  return e;
}

}  // namespace quad_sim
