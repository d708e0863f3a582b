// Helpers shared by the convert_*.cc files (not installed).
#pragma once

#include <string>
#include <string_view>

#include <opencv2/core/mat.hpp>

#include "craftscan/dds/messages.h"

namespace craftscan::dds::internal {

// Sets *error (may be null) to `message`; returns false.
inline bool Fail(std::string* error, std::string message) {
  if (error) *error = std::move(message);
  return false;
}

// The pixels of `image` with rows packed: borrowed from a continuous Mat,
// else from a clone kept alive by `storage`.
const uint8_t* PackedPixels(const cv::Mat& image, MessageStorage* storage);

// Fills `image` (possibly a member of a bigger message) from `mat`; the
// strings and any copy are kept by `storage`. `what` names the image in errors.
bool FillImage(const cv::Mat& mat, int64_t stamp_ns, std::string_view frame_id,
               std::string_view what, ros::Image* image, MessageStorage* storage,
               std::string* error);

}  // namespace craftscan::dds::internal
