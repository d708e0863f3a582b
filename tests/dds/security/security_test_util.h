// Shared by the DDS Security test and its peer process: a hash that shows a
// capture arrived intact without sending it back.
#pragma once

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <string>

#include "craftscan/dds/messages.h"

namespace craftscan::dds::testing {

// FNV-1a 64 over the left then the right image bytes of `capture`, as 16
// hex digits.
inline std::string CaptureHash(const msg::StereoCapture& capture) {
  uint64_t hash = 1469598103934665603ull;
  for (const auto* data : {&capture.left_data, &capture.right_data}) {
    for (uint32_t i = 0; i < data->_length; ++i) {
      hash = (hash ^ data->_buffer[i]) * 1099511628211ull;
    }
  }
  char hex[17];
  std::snprintf(hex, sizeof hex, "%016llx", static_cast<unsigned long long>(hash));
  return hex;
}

}  // namespace craftscan::dds::testing
