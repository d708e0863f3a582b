// The pictures the console sends its pages (pictures.h).
#include "craftscan/web/pictures.h"

#include <algorithm>
#include <cmath>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

namespace craftscan::web {

std::string Base64(const std::vector<unsigned char>& data) {
  static const char* table = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  out.reserve((data.size() + 2) / 3 * 4);
  std::size_t i = 0;
  for (; i + 2 < data.size(); i += 3) {
    const unsigned v = (data[i] << 16) | (data[i + 1] << 8) | data[i + 2];
    out += table[(v >> 18) & 63];
    out += table[(v >> 12) & 63];
    out += table[(v >> 6) & 63];
    out += table[v & 63];
  }
  if (i + 1 == data.size()) {
    const unsigned v = data[i] << 16;
    out += table[(v >> 18) & 63];
    out += table[(v >> 12) & 63];
    out += "==";
  } else if (i + 2 == data.size()) {
    const unsigned v = (data[i] << 16) | (data[i + 1] << 8);
    out += table[(v >> 18) & 63];
    out += table[(v >> 12) & 63];
    out += table[(v >> 6) & 63];
    out += '=';
  }
  return out;
}

std::string JpegDataUrl(const cv::Mat& image, int max_width) {
  if (image.empty()) return "";
  try {
    cv::Mat small = image;
    if (max_width > 0 && image.cols > max_width) {
      const double s = static_cast<double>(max_width) / image.cols;
      cv::resize(image, small, cv::Size(), s, s, cv::INTER_AREA);
    }
    std::vector<unsigned char> jpeg;
    if (!cv::imencode(".jpg", small, jpeg, {cv::IMWRITE_JPEG_QUALITY, 80})) return "";
    return "data:image/jpeg;base64," + Base64(jpeg);
  } catch (const cv::Exception&) {
    return "";  // a type JPEG cannot hold
  }
}

DisparityPicture RenderDisparity(const cv::Mat& disparity_px, int max_width) {
  DisparityPicture out;
  if (disparity_px.empty() || disparity_px.type() != CV_32FC1) return out;
  float lo = 0, hi = 0;
  for (int y = 0; y < disparity_px.rows; ++y) {
    const float* row = disparity_px.ptr<float>(y);
    for (int x = 0; x < disparity_px.cols; ++x) {
      if (!std::isfinite(row[x])) continue;
      lo = out.valid_pixels == 0 ? row[x] : std::min(lo, row[x]);
      hi = out.valid_pixels == 0 ? row[x] : std::max(hi, row[x]);
      ++out.valid_pixels;
    }
  }
  out.valid_fraction = static_cast<double>(out.valid_pixels) / disparity_px.total();

  cv::Mat small = disparity_px;
  if (max_width > 0 && disparity_px.cols > max_width) {
    const int height = std::max(1, static_cast<int>(std::lround(double(disparity_px.rows) *
                                                                max_width / disparity_px.cols)));
    cv::resize(disparity_px, small, {max_width, height}, 0, 0, cv::INTER_NEAREST);
  }
  // Finite pixels (every comparison with NaN is false; ±inf is out of range).
  const float kBig = std::numeric_limits<float>::max();
  const cv::Mat valid = (small >= -kBig) & (small <= kBig);
  if (out.valid_pixels == 0) {
    out.bgr = cv::Mat(small.size(), CV_8UC3, cv::Scalar::all(0));
    return out;
  }
  out.scale_min = lo;
  out.scale_max = hi;
  if (!(hi > lo)) out.scale_min -= 0.5, out.scale_max += 0.5;
  // Invalid pixels at the scale's bottom before the 8-bit conversion (NaN
  // has no defined conversion), black after the colour map.
  cv::Mat finite = small.clone();
  finite.setTo(out.scale_min, ~valid);
  cv::Mat index;
  const double scale = 255.0 / (out.scale_max - out.scale_min);
  finite.convertTo(index, CV_8U, scale, -out.scale_min * scale);
  cv::applyColorMap(index, out.bgr, cv::COLORMAP_TURBO);
  out.bgr.setTo(cv::Scalar::all(0), ~valid);
  return out;
}

nlohmann::json DisparityMessage(const client::DisparityUpdate& update) {
  const DisparityPicture picture = RenderDisparity(update.disparity);
  auto number_or_null = [](double v) { return std::isfinite(v) ? nlohmann::json(v) : nullptr; };
  return {{"type", "disparity"},
          {"session", update.session},
          {"view_index", update.view_index},
          {"width", update.disparity.cols},
          {"height", update.disparity.rows},
          {"min_disparity", update.min_disparity},
          {"max_disparity", update.max_disparity},
          {"scale_min", number_or_null(picture.scale_min)},
          {"scale_max", number_or_null(picture.scale_max)},
          {"valid_fraction", picture.valid_fraction},
          {"image", JpegDataUrl(picture.bgr)}};
}

}  // namespace craftscan::web
