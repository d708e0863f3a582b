#include "craftscan/pipeline/stereo/preprocess.h"
#include "craftscan/pipeline/common/status.h"

#include <algorithm>
#include <exception>
#include <opencv2/imgproc.hpp>
#include <string>

namespace craftscan {

bool PreprocessOptions::IsValid(std::string* why) const {
  if (!(canny_sigma > 0 && canny_sigma <= 1))
    return Fail(why, "preprocess.canny_sigma must be in (0, 1]");
  if (!(canny_min_threshold >= 0 && canny_min_threshold < 255))
    return Fail(why, "preprocess.canny_min_threshold must be in [0, 255)");
  if (canny_aperture != 3 && canny_aperture != 5 && canny_aperture != 7)
    return Fail(why, "preprocess.canny_aperture must be 3, 5 or 7");
  if (dilate_radius_px < 0 || dilate_radius_px > 15)
    return Fail(why, "preprocess.dilate_radius_px must be in [0, 15]");
  return true;
}

namespace {

double Median8U(const cv::Mat& grey) {
  int histogram[256] = {};
  for (int y = 0; y < grey.rows; ++y) {
    const std::uint8_t* row = grey.ptr<std::uint8_t>(y);
    for (int x = 0; x < grey.cols; ++x) ++histogram[row[x]];
  }
  const long half = (static_cast<long>(grey.total()) + 1) / 2;
  long seen = 0;
  for (int v = 0; v < 256; ++v) {
    seen += histogram[v];
    if (seen >= half) return v;
  }
  return 255;
}

void EdgesValid(const PreprocessOptions& options, Preprocessed* result, PreprocessScratch* scratch);

// Preprocess on validated inputs into *out; OpenCV may still throw (out of
// memory).
void PreprocessValid(const cv::Mat& image, const PreprocessOptions& options, PreprocessParts parts,
                     Preprocessed* result, PreprocessScratch* scratch) {
  Preprocessed& out = *result;
  out.status = Preprocessed::Status::kOk;
  out.message.clear();
  out.canny_low = out.canny_high = 0;
  // A grey call leaves `grey` sharing the image's memory: not to be written.
  if (out.grey.data == out.image.data) out.grey.release();
  const bool want_image =
      parts == PreprocessParts::kAll || parts == PreprocessParts::kEqualizedOnly;
  if (!want_image) {
    out.image.release();
    if (image.channels() == 1) {
      if (options.equalize) {
        cv::equalizeHist(image, out.grey);
      } else {
        image.copyTo(out.grey);
      }
    } else if (options.equalize) {
      // Y of YCrCb, as below (the same weights as COLOR_BGR2GRAY, but kept
      // as the colour path computes it).
      cv::cvtColor(image, scratch->ycrcb, cv::COLOR_BGR2YCrCb);
      cv::extractChannel(scratch->ycrcb, scratch->channels[0], 0);
      cv::equalizeHist(scratch->channels[0], out.grey);
    } else {
      cv::cvtColor(image, out.grey, cv::COLOR_BGR2GRAY);
    }
  } else if (image.channels() == 1) {
    if (options.equalize) {
      cv::equalizeHist(image, out.image);
    } else {
      image.copyTo(out.image);
    }
    out.grey = out.image;
  } else {
    if (options.equalize) {
      cv::cvtColor(image, scratch->ycrcb, cv::COLOR_BGR2YCrCb);
      cv::split(scratch->ycrcb, scratch->channels);
      cv::equalizeHist(scratch->channels[0], scratch->channels[0]);
      cv::merge(scratch->channels, 3, scratch->ycrcb);
      cv::cvtColor(scratch->ycrcb, out.image, cv::COLOR_YCrCb2BGR);
      scratch->channels[0].copyTo(out.grey);  // its own: the scratch serves the next image
    } else {
      image.copyTo(out.image);
      cv::cvtColor(image, out.grey, cv::COLOR_BGR2GRAY);
    }
  }

  if (parts == PreprocessParts::kEqualizedOnly || parts == PreprocessParts::kGreyOnly) {
    out.gradient.release();
    out.edges.release();
    return;
  }
  EdgesValid(options, result, scratch);
}

// The gradient and edges of out->grey, on validated inputs; OpenCV may
// still throw.
void EdgesValid(const PreprocessOptions& options, Preprocessed* result,
                PreprocessScratch* scratch) {
  Preprocessed& out = *result;
  cv::Sobel(out.grey, scratch->gx, CV_32F, 1, 0, 3, 1, 0, cv::BORDER_REPLICATE);
  cv::Sobel(out.grey, scratch->gy, CV_32F, 0, 1, 3, 1, 0, cv::BORDER_REPLICATE);
  cv::magnitude(scratch->gx, scratch->gy, out.gradient);

  // Thresholds from the median: the common "auto Canny" rule. A median of an
  // equalized image sits near 128, so this stays sensible for dark or bright
  // scenes; the floor keeps sensor noise out of flat regions.
  const double median = Median8U(out.grey);
  out.canny_low = std::max(options.canny_min_threshold, (1.0 - options.canny_sigma) * median);
  out.canny_high = std::min(255.0, (1.0 + options.canny_sigma) * median);
  if (out.canny_high <= out.canny_low) out.canny_high = std::min(255.0, out.canny_low * 2 + 1);
  cv::Canny(out.grey, out.edges, out.canny_low, out.canny_high, options.canny_aperture, true);
  if (options.dilate_radius_px > 0) {
    const int k = 2 * options.dilate_radius_px + 1;
    cv::dilate(out.edges, out.edges, cv::getStructuringElement(cv::MORPH_RECT, {k, k}));
  }
}

}  // namespace

void Preprocess(const cv::Mat& image, const PreprocessOptions& options, PreprocessParts parts,
                Preprocessed* out, PreprocessScratch* scratch) {
  using Status = Preprocessed::Status;
  const auto fail = [&](Status status, std::string message) {
    *out = Failed<Preprocessed>(status, "Preprocess: " + std::move(message));
  };
  std::string why;
  if (!options.IsValid(&why)) return fail(Status::kInvalidInput, why);
  if (image.empty()) return fail(Status::kInvalidInput, "empty image");
  if (image.type() != CV_8UC1 && image.type() != CV_8UC3)
    return fail(Status::kInvalidInput, "image must be CV_8UC1 or CV_8UC3 (BGR)");
  try {
    PreprocessValid(image, options, parts, out, scratch);
  } catch (const std::exception& e) {  // cv::Exception, std::bad_alloc
    fail(Status::kFailed, e.what());
  }
}

void PreprocessEdges(const PreprocessOptions& options, Preprocessed* out,
                     PreprocessScratch* scratch) {
  const auto fail = [&](Preprocessed::Status status, std::string message) {
    *out = Failed<Preprocessed>(status, "PreprocessEdges: " + std::move(message));
  };
  std::string why;
  if (!options.IsValid(&why)) return fail(Preprocessed::Status::kInvalidInput, why);
  if (!out->IsUsable() || out->grey.empty() || out->grey.type() != CV_8UC1)
    return fail(Preprocessed::Status::kInvalidInput, "no usable grey image to take edges of");
  try {
    EdgesValid(options, out, scratch);
  } catch (const std::exception& e) {  // cv::Exception, std::bad_alloc
    fail(Preprocessed::Status::kFailed, e.what());
  }
}

Preprocessed Preprocess(const cv::Mat& image, const PreprocessOptions& options,
                        PreprocessParts parts) {
  Preprocessed out;
  PreprocessScratch scratch;
  Preprocess(image, options, parts, &out, &scratch);
  return out;
}

}  // namespace craftscan
