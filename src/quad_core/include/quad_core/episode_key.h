// Keyed episodes (issue 32): an episode of a run is named by (world seed, episode index), and everything that
// depends on when and as what it is flown is a function of that key, never of the episodes flown before it in
// the same process. The simulator node (ResetEpisode with keyed = true) and the rollout engine both use these
// rules, so the same key gives the same stamps, the same episode id and therefore, with deterministic cores,
// the same flight and records, whichever backend, worker or position in a run flies it.
//
//   sim time of the episode's first step = kEpisodeTimeBaseNs + (index + 1) * kEpisodeSpacingNs
//   episode id                           = index + 1 (an unkeyed episode gets an id >= kUnkeyedEpisodeIdBase)
//
// The spacing bounds an episode's length in sim time (take-off, flight and the end's frame included): a reset
// into an episode whose start is not after the current sim time is refused with the reason.
#pragma once

#include <cstdint>
#include <stdexcept>
#include <string>

namespace quad_core {

constexpr uint64_t kEpisodeTimeBaseNs = 1000000000ULL;    // 1 s: the simulator's first stamp
constexpr uint64_t kEpisodeSpacingNs = 1000000000000ULL;  // 1000 s of sim time per keyed episode
constexpr uint32_t kMaxEpisodeIndex = 4000000;            // ros::Time's uint32 seconds hold 4.29e9 s
constexpr uint32_t kUnkeyedEpisodeIdBase = 0x80000000u;   // ids of unkeyed episodes (the node's initial one)

inline void CheckEpisodeIndex(int64_t index) {
  if (index < 0 || index > static_cast<int64_t>(kMaxEpisodeIndex)) {
    throw std::invalid_argument("episode index " + std::to_string(index) + " outside [0, " +
                                std::to_string(kMaxEpisodeIndex) + "]");
  }
}

// Sim time (ns) of the keyed episode's first step. Throws std::invalid_argument for an index out of range.
inline uint64_t EpisodeStartNs(int64_t index) {
  CheckEpisodeIndex(index);
  return kEpisodeTimeBaseNs + (static_cast<uint64_t>(index) + 1) * kEpisodeSpacingNs;
}

// The keyed episode's id (EpisodeStatus.episode_id, the records' episode_id).
inline uint32_t EpisodeIdOf(int64_t index) {
  CheckEpisodeIndex(index);
  return static_cast<uint32_t>(index) + 1;
}

// A sim time in ns as the seconds every ROS consumer reads from a stamp (ros::Time::toSec: whole seconds plus
// 1e-9 times the nanoseconds), so that an in-process consumer computes with bit-identical times.
inline double StampSeconds(uint64_t ns) {
  const uint64_t sec = ns / 1000000000ULL;
  const uint64_t nsec = ns % 1000000000ULL;
  return static_cast<double>(sec) + 1e-9 * static_cast<double>(nsec);
}

}  // namespace quad_core
