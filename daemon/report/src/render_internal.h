// Shared pieces of the preview renderers: the Turbo colour table, the
// supersampled camera, lighting and the frame buffer they draw into.
#pragma once

#include <cmath>
#include <limits>
#include <vector>

#include <opencv2/core.hpp>

#include "craftscan/daemon/preview.h"

namespace craftscan::daemon {

// OpenCV's Turbo colour map as a 256×1 CV_8UC3 BGR table (built once;
// immutable afterwards, so safe to read from any thread).
const cv::Mat& TurboLut();

// `camera` for an image `factor` times larger in each direction (pixel
// centres stay consistent: output pixel X covers factor·X … factor·X+factor−1).
PreviewCamera ScaleCamera(const PreviewCamera& camera, int factor);

// Directional light (unit, input frame) from PreviewOptions::light_in_camera.
cv::Vec3d LightInWorld(const PreviewCamera& camera, const PreviewOptions& options);

// Two-sided Lambert: ambient + (1 − ambient)·max(0, n·l) with n flipped to
// face `toward_camera`. A zero or non-finite normal gives full light.
inline float Lambert(cv::Vec3d n, const cv::Vec3d& light, const cv::Vec3d& toward_camera,
                     double ambient) {
  const double len = std::sqrt(n.dot(n));
  if (!(len > 0) || !std::isfinite(len)) return 1.0f;
  n *= 1.0 / len;
  if (n.dot(toward_camera) < 0) n = -n;
  return static_cast<float>(ambient + (1 - ambient) * std::max(0.0, n.dot(light)));
}

inline cv::Vec3b Scaled(const cv::Vec3b& bgr, float intensity) {
  return {cv::saturate_cast<uchar>(bgr[0] * intensity),
          cv::saturate_cast<uchar>(bgr[1] * intensity),
          cv::saturate_cast<uchar>(bgr[2] * intensity)};
}

// A colour + coverage image with a z-buffer ("nearness": larger is nearer,
// so orthographic −depth and perspective 1/depth, both affine in screen space).
struct FrameBuffer {
  int width = 0, height = 0;
  cv::Mat color;                // CV_8UC3
  cv::Mat coverage;             // CV_8UC1, 0 or 255
  std::vector<float> nearness;  // row-major, −inf = empty

  FrameBuffer(cv::Size size, const cv::Vec3b& background)
      : width(size.width),
        height(size.height),
        color(size, CV_8UC3, cv::Scalar(background[0], background[1], background[2])),
        coverage(size, CV_8UC1, cv::Scalar(0)),
        nearness(static_cast<std::size_t>(size.area()), -std::numeric_limits<float>::infinity()) {}

  // Writes the pixel if `near` is nearer than what is there.
  void Put(int x, int y, float near, const cv::Vec3b& bgr) {
    float& z = nearness[static_cast<std::size_t>(y) * width + x];
    if (near <= z) return;
    z = near;
    color.ptr<cv::Vec3b>(y)[x] = bgr;
    coverage.ptr<uchar>(y)[x] = 255;
  }
};

// Moves the supersampled frame buffer into `out` (area downsampling to the
// camera's size) and draws the scale bar when asked.
void FinishPreview(FrameBuffer& buffer, const PreviewCamera& camera, const PreviewOptions& options,
                   PreviewImage* out);

}  // namespace craftscan::daemon
