#include "quad_policy/abi.h"

#include <cstdio>

namespace quad_policy {

std::uint64_t LibraryLayoutStamp() { return kHeaderLayoutStamp; }

std::string LayoutMismatchMessage(std::uint64_t library_stamp, std::uint64_t header_stamp) {
  if (library_stamp == header_stamp) return "";
  char buf[400];
  std::snprintf(
      buf, sizeof(buf),
      "libquad_policy_core.so was built from other quad_policy headers than this program (layout stamp "
      "%016llx in the library, %016llx here); rebuild everything (cd build && make) and do not rebuild "
      "while nodes are being started",
      static_cast<unsigned long long>(library_stamp), static_cast<unsigned long long>(header_stamp));
  return buf;
}

}  // namespace quad_policy
