#include "craftscan/daemon/live_preview.h"

#include <algorithm>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

namespace craftscan::daemon {

LivePreviewImage MakeLivePreviewImage(const cv::Mat& image, int width) {
  LivePreviewImage out;
  cv::Mat grey;
  if (image.channels() == 3) {
    cv::cvtColor(image, grey, cv::COLOR_BGR2GRAY);
  } else {
    grey = image;
  }
  // Focus per cell on the full-resolution image: scaling would smooth away
  // exactly what it measures.
  cv::Mat laplacian;
  cv::Laplacian(grey, laplacian, CV_32F);
  out.focus.reserve(kPreviewGridCols * kPreviewGridRows);
  for (int r = 0; r < kPreviewGridRows; ++r) {
    for (int c = 0; c < kPreviewGridCols; ++c) {
      const cv::Rect cell(
          c * grey.cols / kPreviewGridCols, r * grey.rows / kPreviewGridRows,
          (c + 1) * grey.cols / kPreviewGridCols - c * grey.cols / kPreviewGridCols,
          (r + 1) * grey.rows / kPreviewGridRows - r * grey.rows / kPreviewGridRows);
      cv::Scalar mean, stddev;
      cv::meanStdDev(laplacian(cell), mean, stddev);
      out.focus.push_back(static_cast<float>(stddev[0] * stddev[0]));
    }
  }
  out.histogram.assign(kPreviewHistogramBins, 0);
  std::size_t clipped = 0, black = 0;
  const int channels = image.channels();
  for (int y = 0; y < image.rows; ++y) {
    const std::uint8_t* p = image.ptr<std::uint8_t>(y);
    const std::uint8_t* g = grey.ptr<std::uint8_t>(y);
    for (int x = 0; x < image.cols; ++x, p += channels) {
      ++out.histogram[g[x] >> 2];
      bool any_full = false, all_zero = true;
      for (int k = 0; k < channels; ++k) {
        any_full |= p[k] == 255;
        all_zero &= p[k] == 0;
      }
      clipped += any_full;
      black += all_zero;
    }
  }
  const double total = static_cast<double>(image.total());
  out.clipped_pct = static_cast<float>(100.0 * static_cast<double>(clipped) / total);
  out.black_pct = static_cast<float>(100.0 * static_cast<double>(black) / total);
  cv::Mat small = image;
  if (width > 0 && width < image.cols) {
    const double s = static_cast<double>(width) / image.cols;
    cv::resize(image, small, cv::Size(width, std::max(1, static_cast<int>(image.rows * s + 0.5))),
               0, 0, cv::INTER_AREA);
  }
  cv::imencode(".jpg", small, out.jpeg, {cv::IMWRITE_JPEG_QUALITY, 80});
  return out;
}

PreviewFrame MakePreviewFrame(const cv::Mat& left, const cv::Mat& right, int width) {
  PreviewFrame f;
  f.full_size = left.size();
  f.left = MakeLivePreviewImage(left, width);
  f.right = MakeLivePreviewImage(right, width);
  const int w = width > 0 && width < left.cols ? width : left.cols;
  f.size = cv::Size(
      w, std::max(1, static_cast<int>(left.rows * (static_cast<double>(w) / left.cols) + 0.5)));
  f.grid_cols = kPreviewGridCols;
  f.grid_rows = kPreviewGridRows;
  return f;
}

}  // namespace craftscan::daemon
