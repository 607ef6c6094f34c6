// An EpisodeRun as bytes and back (records included, bit for bit), so that a flown episode can travel between
// processes (the Ray backend's actors return them to the driver, which writes them in key order).
#pragma once

#include <string>

#include "quad_engine/episode.h"

namespace quad_engine {

std::string EncodeRun(const EpisodeRun& run);
// Throws std::invalid_argument naming the problem for bytes that are not an encoded run of this version.
EpisodeRun DecodeRun(const std::string& bytes);

}  // namespace quad_engine
