// Keyed episodes (quad_core/episode_key.h, issue 32): the sim time and id of an episode are functions of its
// index alone, far enough apart that one episode's stamps never reach the next one's.
#include "quad_core/episode_key.h"

#include <gtest/gtest.h>

#include <cstdint>
#include <limits>
#include <stdexcept>
#include <string>

namespace {

using quad_core::EpisodeIdOf;
using quad_core::EpisodeStartNs;
using quad_core::StampSeconds;

TEST(EpisodeKey, StartsAreOneSecondPlusIndexPlusOneTimesTheSpacing) {
  EXPECT_EQ(EpisodeStartNs(0), 1001000000000ULL);
  EXPECT_EQ(EpisodeStartNs(1), 2001000000000ULL);
  EXPECT_EQ(EpisodeStartNs(1) - EpisodeStartNs(0), quad_core::kEpisodeSpacingNs);
  // Every keyed start is after the simulator's first stamp (its initial, unkeyed episode).
  EXPECT_GT(EpisodeStartNs(0), quad_core::kEpisodeTimeBaseNs);
}

TEST(EpisodeKey, IdsAreIndexPlusOneAndNeverAnUnkeyedId) {
  EXPECT_EQ(EpisodeIdOf(0), 1u);
  EXPECT_EQ(EpisodeIdOf(41), 42u);
  EXPECT_LT(EpisodeIdOf(quad_core::kMaxEpisodeIndex), quad_core::kUnkeyedEpisodeIdBase);
}

TEST(EpisodeKey, TheLastIndexStillFitsARosTimesUint32Seconds) {
  const uint64_t last_s = EpisodeStartNs(quad_core::kMaxEpisodeIndex) / 1000000000ULL;
  // The episode's own spacing must fit too: its last stamp is below the next start.
  EXPECT_LT(last_s + quad_core::kEpisodeSpacingNs / 1000000000ULL,
            static_cast<uint64_t>(std::numeric_limits<uint32_t>::max()));
}

TEST(EpisodeKey, AnIndexOutOfRangeIsRefusedNamingIt) {
  for (int64_t bad : {int64_t{-1}, static_cast<int64_t>(quad_core::kMaxEpisodeIndex) + 1}) {
    try {
      EpisodeStartNs(bad);
      FAIL() << bad;
    } catch (const std::invalid_argument& e) {
      EXPECT_EQ(std::string(e.what()), "episode index " + std::to_string(bad) + " outside [0, 4000000]");
    }
    EXPECT_THROW(EpisodeIdOf(bad), std::invalid_argument);
  }
}

TEST(EpisodeKey, StampSecondsIsRosTimesToSec) {
  // ros::Time::toSec: whole seconds plus 1e-9 times the nanoseconds, in double.
  const uint64_t ns = EpisodeStartNs(1) + 123456789ULL;
  EXPECT_EQ(StampSeconds(ns), 2001.0 + 1e-9 * 123456789.0);
  EXPECT_EQ(StampSeconds(3000000000ULL), 3.0);
}

}  // namespace
