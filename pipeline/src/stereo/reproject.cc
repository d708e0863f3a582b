#include "craftscan/pipeline/stereo/reproject.h"

#include <cmath>
#include <limits>
#include <stdexcept>

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "craftscan/pipeline/common/status.h"
#include "craftscan/pipeline/stereo/adcensus.h"

namespace craftscan {

bool ReprojectOptions::IsValid(std::string* why) const {
  if (std::isnan(min_depth_mm) || std::isnan(max_depth_mm))
    return Fail(why, "depth limits are NaN");
  if (min_depth_mm > max_depth_mm) return Fail(why, "min_depth_mm > max_depth_mm");
  if (!(min_texture_std >= 0)) return Fail(why, "min_texture_std must be >= 0");
  if (texture_window < 3 || texture_window % 2 == 0)
    return Fail(why, "texture_window must be odd and >= 3");
  return true;
}

cv::Mat TextureMask(const cv::Mat& color, int window, double min_std) {
  if (color.empty() || (color.type() != CV_8UC1 && color.type() != CV_8UC3)) {
    throw std::invalid_argument("TextureMask: color must be a non-empty CV_8UC1 or CV_8UC3");
  }
  if (window < 3 || window % 2 == 0) {
    throw std::invalid_argument("TextureMask: window must be odd and >= 3");
  }
  cv::Mat grey, g, mean, mean2;
  if (color.type() == CV_8UC3)
    cv::cvtColor(color, grey, cv::COLOR_BGR2GRAY);
  else
    grey = color;
  grey.convertTo(g, CV_32F);
  cv::boxFilter(g, mean, CV_32F, cv::Size(window, window));
  cv::boxFilter(g.mul(g), mean2, CV_32F, cv::Size(window, window));
  return (mean2 - mean.mul(mean)) >= min_std * min_std;
}

namespace {

using ReprojectStatus = ReprojectResult::Status;

ReprojectResult InvalidInput(std::string message) {
  return Failed<ReprojectResult>(ReprojectStatus::kInvalidInput, "ReprojectToPoints: " + message);
}

// On validated inputs; OpenCV may still throw (out of memory).
std::vector<ColoredPoint> ReprojectValid(const cv::Mat& disparity, const cv::Matx44d& q,
                                         const cv::Mat& color, const ReprojectOptions& options) {
  const cv::Mat texture_ok =  // CV_8U, non-zero where the texture passes
      options.min_texture_std > 0
          ? TextureMask(color, options.texture_window, options.min_texture_std)
          : cv::Mat();

  std::vector<ColoredPoint> points;
  points.reserve(static_cast<std::size_t>(disparity.total()));
  for (int y = 0; y < disparity.rows; ++y) {
    const float* d_row = disparity.ptr<float>(y);
    for (int x = 0; x < disparity.cols; ++x) {
      const float d = d_row[x];
      if (!IsValidDisparity(d) || !std::isfinite(d)) continue;
      if (!texture_ok.empty() && texture_ok.at<std::uint8_t>(y, x) == 0 &&
          (options.texture_exempt.empty() || options.texture_exempt.at<std::uint8_t>(y, x) == 0))
        continue;
      const cv::Vec4d h = q * cv::Vec4d(x, y, d, 1.0);
      // W ≈ 0 is a point at infinity (zero disparity with equal principal
      // points); "≈" relative to the terms that make up W.
      const double w_scale =
          std::abs(q(3, 0) * x) + std::abs(q(3, 1) * y) + std::abs(q(3, 2) * d) + std::abs(q(3, 3));
      if (std::abs(h[3]) <= 1e-12 * w_scale || h[3] == 0) continue;
      const double px = h[0] / h[3], py = h[1] / h[3], pz = h[2] / h[3];
      if (!std::isfinite(px) || !std::isfinite(py) || !std::isfinite(pz)) continue;
      if (pz < options.min_depth_mm || pz > options.max_depth_mm) continue;

      ColoredPoint p;
      p.x = static_cast<float>(px);
      p.y = static_cast<float>(py);
      p.z = static_cast<float>(pz);
      if (color.empty()) {
        p.r = p.g = p.b = 255;
      } else if (color.type() == CV_8UC1) {
        p.r = p.g = p.b = color.at<std::uint8_t>(y, x);
      } else {
        const cv::Vec3b& bgr = color.at<cv::Vec3b>(y, x);
        p.b = bgr[0];
        p.g = bgr[1];
        p.r = bgr[2];
      }
      points.push_back(p);
    }
  }
  return points;
}

}  // namespace

ReprojectResult ReprojectToPoints(const cv::Mat& disparity, const cv::Mat& Q, const cv::Mat& color,
                                  const ReprojectOptions& options) {
  std::string why;
  if (!options.IsValid(&why)) return InvalidInput(why);
  if (disparity.empty() || disparity.type() != CV_32FC1) {
    return InvalidInput("disparity must be a non-empty CV_32FC1");
  }
  if (Q.rows != 4 || Q.cols != 4 || (Q.type() != CV_64FC1 && Q.type() != CV_32FC1)) {
    return InvalidInput("Q must be 4x4 CV_64F");
  }
  if (!color.empty() &&
      (color.size() != disparity.size() || (color.type() != CV_8UC1 && color.type() != CV_8UC3))) {
    return InvalidInput("color must be empty or CV_8UC1/CV_8UC3 of the disparity's size");
  }
  if (!options.texture_exempt.empty() && (options.texture_exempt.size() != disparity.size() ||
                                          options.texture_exempt.type() != CV_8UC1)) {
    return InvalidInput("texture_exempt must be empty or CV_8UC1 of the disparity's size");
  }
  if (options.min_texture_std > 0 && color.empty()) {
    return InvalidInput("the texture filter needs the colour image");
  }
  try {
    cv::Matx44d q;
    Q.convertTo(cv::Mat(q, false), CV_64F);
    for (int i = 0; i < 16; ++i) {
      if (!std::isfinite(q.val[i])) return InvalidInput("Q not finite");
    }
    ReprojectResult result;
    result.points = ReprojectValid(disparity, q, color, options);
    result.status = ReprojectStatus::kOk;
    return result;
  } catch (const std::exception& e) {  // cv::Exception, std::bad_alloc
    return Failed<ReprojectResult>(ReprojectStatus::kFailed,
                                   std::string("ReprojectToPoints: ") + e.what());
  }
}

}  // namespace craftscan
