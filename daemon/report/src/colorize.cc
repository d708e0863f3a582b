// Disparity colour mapping with a colour bar (preview.h).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <string>

#include <opencv2/imgproc.hpp>

#include "craftscan/daemon/preview.h"
#include "render_internal.h"

namespace craftscan::daemon {
namespace {

constexpr int kFont = cv::FONT_HERSHEY_SIMPLEX;

// Label font scale for a strip `width_px` wide: readable on a 640 px
// thumbnail, not oversized on a 5 MP map.
double LabelScale(int width_px) { return std::clamp(width_px / 1100.0, 0.35, 1.6); }

struct StripLayout {
  int pad = 0, bar = 0, text = 0, height = 0;
};

StripLayout Layout(int width_px) {
  StripLayout l;
  const double scale = LabelScale(width_px);
  int baseline = 0;
  const cv::Size t = cv::getTextSize("0123456789 px", kFont, scale, 1, &baseline);
  l.pad = std::max(3, static_cast<int>(std::lround(6 * scale)));
  l.bar = std::max(6, static_cast<int>(std::lround(14 * scale)));
  l.text = t.height + baseline;
  l.height = l.pad + l.bar + l.pad + l.text + l.pad;
  return l;
}

std::string PxLabel(double v) {
  char buf[48];
  std::snprintf(buf, sizeof buf, "%.1f px", v);
  return buf;
}

}  // namespace

int ColorBarHeight(int width_px) { return Layout(std::max(width_px, 1)).height; }

cv::Mat ColorizeDisparity(const cv::Mat& disparity_px, double min_d, double max_d,
                          std::string* error) {
  auto fail = [&](const std::string& m) {
    if (error) *error = "ColorizeDisparity: " + m;
    return cv::Mat();
  };
  if (disparity_px.empty()) return fail("empty disparity map");
  if (disparity_px.type() != CV_32FC1)
    return fail("disparity map must be CV_32FC1, got type " + std::to_string(disparity_px.type()));
  if (std::isinf(min_d) || std::isinf(max_d)) return fail("disparity range bound is infinite");
  if (std::isnan(min_d) || std::isnan(max_d)) {
    float lo = std::numeric_limits<float>::max(), hi = std::numeric_limits<float>::lowest();
    for (int y = 0; y < disparity_px.rows; ++y) {
      const float* row = disparity_px.ptr<float>(y);
      for (int x = 0; x < disparity_px.cols; ++x)
        if (std::isfinite(row[x])) lo = std::min(lo, row[x]), hi = std::max(hi, row[x]);
    }
    if (lo > hi) lo = 0, hi = 1;           // no valid pixel
    if (lo == hi) lo -= 0.5f, hi += 0.5f;  // one value: centre it on the map
    if (std::isnan(min_d)) min_d = lo;
    if (std::isnan(max_d)) max_d = hi;
  }
  if (!(min_d < max_d)) {
    return fail("disparity range must have min < max, got " + std::to_string(min_d) + " .. " +
                std::to_string(max_d));
  }

  try {
    const cv::Mat& lut = TurboLut();
    const StripLayout layout = Layout(disparity_px.cols);
    const cv::Vec3b strip_bg(255, 255, 255);
    cv::Mat out(disparity_px.rows + layout.height, disparity_px.cols, CV_8UC3, strip_bg);
    const double to_index = 255.0 / (max_d - min_d);
    for (int y = 0; y < disparity_px.rows; ++y) {
      const float* in = disparity_px.ptr<float>(y);
      cv::Vec3b* row = out.ptr<cv::Vec3b>(y);
      for (int x = 0; x < disparity_px.cols; ++x) {
        if (!std::isfinite(in[x])) {
          row[x] = cv::Vec3b(0, 0, 0);
          continue;
        }
        const double t = std::clamp((in[x] - min_d) * to_index, 0.0, 255.0);
        row[x] = lut.at<cv::Vec3b>(static_cast<int>(std::lround(t)));
      }
    }

    // Colour bar across the strip with the range at its ends.
    const int w = disparity_px.cols;
    const int margin = std::min(w / 4, layout.pad * 2);
    const int bar_top = disparity_px.rows + layout.pad;
    const int bar_w = std::max(1, w - 2 * margin);
    for (int x = 0; x < bar_w; ++x) {
      const int index = bar_w == 1 ? 255 : x * 255 / (bar_w - 1);
      const cv::Vec3b c = lut.at<cv::Vec3b>(index);
      for (int y = bar_top; y < bar_top + layout.bar; ++y) out.at<cv::Vec3b>(y, margin + x) = c;
    }
    const double scale = LabelScale(w);
    const int text_y = bar_top + layout.bar + layout.pad + layout.text - layout.text / 5;
    const cv::Scalar ink(40, 40, 40);
    const std::string lo_text = PxLabel(min_d), hi_text = PxLabel(max_d);
    int baseline = 0;
    const int hi_w = cv::getTextSize(hi_text, kFont, scale, 1, &baseline).width;
    cv::putText(out, lo_text, {margin, text_y}, kFont, scale, ink, 1, cv::LINE_AA);
    cv::putText(out, hi_text, {std::max(margin, w - margin - hi_w), text_y}, kFont, scale, ink, 1,
                cv::LINE_AA);
    const std::string mid = "disparity";
    const int mid_w = cv::getTextSize(mid, kFont, scale, 1, &baseline).width;
    const int lo_w = cv::getTextSize(lo_text, kFont, scale, 1, &baseline).width;
    if (mid_w + lo_w + hi_w + 4 * layout.pad < bar_w)
      cv::putText(out, mid, {(w - mid_w) / 2, text_y}, kFont, scale, cv::Scalar(110, 110, 110), 1,
                  cv::LINE_AA);
    return out;
  } catch (const cv::Exception& e) {
    return fail(std::string("OpenCV: ") + e.what());
  }
}

}  // namespace craftscan::daemon
