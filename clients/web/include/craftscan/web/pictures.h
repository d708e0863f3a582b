// The pictures the console sends its pages over the WebSocket (API.md):
// JPEG data URLs of the cameras' captures and a false-colour picture of each
// view's disparity map, small enough to go to every browser as it arrives.
//
//   DisparityPicture p = RenderDisparity(update.disparity);  // Turbo, ≤ 320 px wide
//   std::string url = JpegDataUrl(p.bgr);                    // "data:image/jpeg;base64,..."
//   nlohmann::json message = DisparityMessage(update);       // {"type": "disparity", ...}
//
// Pure functions of their input; thread-safe; never throw.
#pragma once

#include <cstdint>
#include <limits>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core/mat.hpp>

#include "craftscan/client/station_client.h"

namespace craftscan::web {

// The widest picture sent to the pages (captures and disparity maps), px.
inline constexpr int kThumbnailWidth = 320;

// RFC 4648 base64 (with '=' padding).
std::string Base64(const std::vector<unsigned char>& data);

// "data:image/jpeg;base64,..." of `image` (CV_8UC1 or CV_8UC3) scaled
// (area) to at most `max_width` px wide, JPEG quality 80; "" for an empty
// image or one OpenCV cannot encode.
std::string JpegDataUrl(const cv::Mat& image, int max_width = kThumbnailWidth);

// A disparity map as a picture: valid pixels in OpenCV's Turbo colour map
// scaled over the valid values' range (scale_min = the map's first colour,
// dark blue: far; scale_max = its last, dark red: near), invalid pixels
// (NaN, ±inf) black, which Turbo never gives.
struct DisparityPicture {
  cv::Mat bgr;                // CV_8UC3; empty for an empty map or a type other than CV_32FC1
  double valid_fraction = 0;  // finite pixels of the full map / all of them, 0..1
  std::int64_t valid_pixels = 0;
  // The colour scale: the smallest and largest finite value, NaN when no
  // pixel is valid (the picture is then all black). One value only: the
  // scale is that value ± 0.5 px.
  double scale_min = std::numeric_limits<double>::quiet_NaN();
  double scale_max = std::numeric_limits<double>::quiet_NaN();
};

// The picture of `disparity_px` (CV_32FC1, px), shrunk (nearest neighbour,
// so holes stay black) to at most `max_width` px wide with its aspect kept;
// the valid fraction and scale are of the full map.
DisparityPicture RenderDisparity(const cv::Mat& disparity_px, int max_width = kThumbnailWidth);

// The WebSocket message of a view's disparity map (API.md):
// {"type": "disparity", "session", "view_index", "width", "height" (of the
// full map), "min_disparity", "max_disparity" (the searched range, px),
// "scale_min", "scale_max" (the picture's colour scale, px; null without
// valid pixels), "valid_fraction", "image": JPEG data URL ("" if the map
// could not be drawn)}.
nlohmann::json DisparityMessage(const client::DisparityUpdate& update);

}  // namespace craftscan::web
