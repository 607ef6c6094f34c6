// A guard against a policy node linked with a libquad_policy_core.so built from other headers (a rebuild of
// the library while nodes were being started gave 40 minutes of silently mis-linked nodes,
// docs/inference.md). kHeaderLayoutStamp is computed from the size and alignment of every type of the
// library's public headers, as the code including this header sees them; LibraryLayoutStamp() returns the
// same number as the library was compiled. A program calls CheckLibraryLayout() first: different stamps mean
// different layouts.
#pragma once

#include <cstddef>
#include <cstdint>
#include <stdexcept>
#include <string>

#include "quad_policy/config.h"
#include "quad_policy/fixture.h"
#include "quad_policy/npy.h"
#include "quad_policy/policy_decider.h"
#include "quad_policy/policy_meta.h"
#include "quad_policy/preprocessing.h"
#include "quad_policy/safety.h"
#include "quad_policy/torch_policy.h"
#include "quad_policy/trajectory.h"

namespace quad_policy {

// FNV-1a (64 bit) over (sizeof, alignof) of each type, in this order.
template <typename... Types>
constexpr std::uint64_t LayoutStampOf() {
  std::uint64_t h = 14695981039346656037ull;
  const std::size_t values[] = {sizeof(Types)..., alignof(Types)...};
  for (std::size_t v : values) {
    for (int byte = 0; byte < 8; ++byte) {
      h ^= (static_cast<std::uint64_t>(v) >> (8 * byte)) & 0xffu;
      h *= 1099511628211ull;
    }
  }
  return h;
}

// Internal linkage (a namespace-scope constexpr variable): each translation unit keeps its own value.
constexpr std::uint64_t kHeaderLayoutStamp =
    LayoutStampOf<PolicyNodeConfig, RecordedFrame, DecisionFixture, NpyArray, RefusalConfig, DecisionInputs,
                  DecisionTimings, Decision, PolicyDecider, PolicyMeta, DepthImageView, DepthImage,
                  VehicleState, OutputDecoder, SafetyConfig, CameraModel, SafetyResult, DepthCollision,
                  VerdictCounts, TorchPolicy, UniformBspline>();

// The stamp as the library was compiled (defined in the library).
std::uint64_t LibraryLayoutStamp();

// "" when the stamps agree, else what is wrong and how to fix it (defined in the library; takes plain numbers
// so that it works across mismatched layouts).
std::string LayoutMismatchMessage(std::uint64_t library_stamp, std::uint64_t header_stamp);

// Throws std::runtime_error with LayoutMismatchMessage when this program's headers and the library disagree.
inline void CheckLibraryLayout() {
  const std::string message = LayoutMismatchMessage(LibraryLayoutStamp(), kHeaderLayoutStamp);
  if (!message.empty()) throw std::runtime_error(message);
}

}  // namespace quad_policy
