// Time, image, stereo capture and disparity conversions.
#include <algorithm>
#include <cmath>
#include <cstring>
#include <initializer_list>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "convert_internal.h"
#include "craftscan/dds/convert.h"

namespace craftscan::dds {
namespace {

using internal::Fail;

constexpr int64_t kNsPerSecond = 1'000'000'000;

struct Encoding {
  std::string_view name;
  int cv_type;
  int bytes_per_pixel;
  int bytes_per_channel;
};
constexpr Encoding kEncodings[] = {
    {"mono8", CV_8UC1, 1, 1},
    {"bgr8", CV_8UC3, 3, 1},
    {"32FC1", CV_32FC1, 4, 4},
};

const Encoding* FindEncoding(std::string_view name) {
  for (const Encoding& encoding : kEncodings) {
    if (encoding.name == name) return &encoding;
  }
  return nullptr;
}

const Encoding* FindEncoding(int cv_type) {
  for (const Encoding& encoding : kEncodings) {
    if (encoding.cv_type == cv_type) return &encoding;
  }
  return nullptr;
}

std::string SizeText(uint64_t width, uint64_t height) {
  return std::to_string(width) + "x" + std::to_string(height);
}

// Checks a Mat that is to be sent: not empty, 2-D, one of `allowed` types,
// row bytes and total bytes within a sequence's 32-bit length.
const Encoding* CheckOutgoingMat(const cv::Mat& mat, std::string_view what,
                                 std::initializer_list<int> allowed, std::string* error) {
  if (mat.empty() || mat.dims != 2) {
    Fail(error, std::string(what) + " is empty");
    return nullptr;
  }
  const Encoding* encoding = FindEncoding(mat.type());
  if (!encoding || std::find(allowed.begin(), allowed.end(), mat.type()) == allowed.end()) {
    std::string names;
    for (int type : allowed) {
      names += (names.empty() ? "" : ", ") + std::string(FindEncoding(type)->name);
    }
    Fail(error, std::string(what) + ": unsupported pixel type " + cv::typeToString(mat.type()) +
                    " (expected " + names + ")");
    return nullptr;
  }
  const uint64_t bytes = static_cast<uint64_t>(mat.total()) * encoding->bytes_per_pixel;
  if (bytes > std::numeric_limits<uint32_t>::max()) {
    Fail(error, std::string(what) + ": " + SizeText(mat.cols, mat.rows) +
                    " is too large for one DDS sample");
    return nullptr;
  }
  return encoding;
}

// Checks received pixels: known encoding among `allowed`, size > 0, step and
// data length consistent. Returns the encoding or null.
const Encoding* CheckIncomingPixels(std::string_view what, std::string_view encoding_name,
                                    std::initializer_list<std::string_view> allowed, uint32_t width,
                                    uint32_t height, uint64_t step, uint64_t data_bytes,
                                    std::string* error) {
  const Encoding* encoding = FindEncoding(encoding_name);
  if (!encoding || std::find(allowed.begin(), allowed.end(), encoding_name) == allowed.end()) {
    std::string names;
    for (std::string_view name : allowed) names += (names.empty() ? "" : ", ") + std::string(name);
    Fail(error, std::string(what) + ": unsupported encoding '" + std::string(encoding_name) +
                    "' (expected " + names + ")");
    return nullptr;
  }
  if (width == 0 || height == 0) {
    Fail(error, std::string(what) + ": empty (" + SizeText(width, height) + ")");
    return nullptr;
  }
  if (width > static_cast<uint32_t>(std::numeric_limits<int>::max()) ||
      height > static_cast<uint32_t>(std::numeric_limits<int>::max())) {
    Fail(error, std::string(what) + ": " + SizeText(width, height) + " is too large");
    return nullptr;
  }
  const uint64_t row_bytes = static_cast<uint64_t>(width) * encoding->bytes_per_pixel;
  if (step < row_bytes || step % encoding->bytes_per_channel != 0) {
    Fail(error, std::string(what) + ": step " + std::to_string(step) + " does not fit " +
                    std::to_string(width) + " " + std::string(encoding->name) +
                    " pixels (needs ≥ " + std::to_string(row_bytes) + ", a multiple of " +
                    std::to_string(encoding->bytes_per_channel) + ")");
    return nullptr;
  }
  if (data_bytes != step * height) {
    Fail(error, std::string(what) + ": data has " + std::to_string(data_bytes) +
                    " bytes, expected step × height = " + std::to_string(step * height));
    return nullptr;
  }
  return encoding;
}

// Checks a disparity map (CV_32FC1) and its meta data before sending.
bool CheckDisparityInput(const cv::Mat& disparity, const DisparityMeta& meta, std::string* error) {
  if (!CheckOutgoingMat(disparity, "disparity", {CV_32FC1}, error)) return false;
  if (!std::isfinite(meta.f_px) || meta.f_px <= 0) {
    return Fail(error, "disparity: f_px must be finite and > 0");
  }
  if (!std::isfinite(meta.baseline_mm) || meta.baseline_mm <= 0) {
    return Fail(error, "disparity: baseline_mm must be finite and > 0");
  }
  if (!std::isfinite(meta.cx_offset_px))
    return Fail(error, "disparity: cx_offset_px is not finite");
  if (!std::isfinite(meta.min_disparity) || !std::isfinite(meta.max_disparity) ||
      meta.min_disparity > meta.max_disparity) {
    return Fail(error, "disparity: min_disparity/max_disparity must be finite with min ≤ max");
  }
  return true;
}

}  // namespace

namespace internal {

const uint8_t* PackedPixels(const cv::Mat& image, MessageStorage* storage) {
  if (image.isContinuous()) return image.data;
  auto copy = std::make_shared<cv::Mat>(image.clone());
  storage->KeepAlive(copy);
  return copy->data;
}

bool FillImage(const cv::Mat& mat, int64_t stamp_ns, std::string_view frame_id,
               std::string_view what, ros::Image* image, MessageStorage* storage,
               std::string* error) {
  const Encoding* encoding = CheckOutgoingMat(mat, what, {CV_8UC1, CV_8UC3, CV_32FC1}, error);
  if (!encoding) return false;
  image->header.stamp = RosTimeFromNs(stamp_ns);
  image->header.frame_id = storage->Keep(frame_id);
  image->height = static_cast<uint32_t>(mat.rows);
  image->width = static_cast<uint32_t>(mat.cols);
  image->encoding = storage->Keep(encoding->name);
  image->is_bigendian = 0;
  image->step = static_cast<uint32_t>(mat.cols * encoding->bytes_per_pixel);
  Borrow(&image->data, PackedPixels(mat, storage), mat.total() * encoding->bytes_per_pixel);
  return true;
}

}  // namespace internal

// --- Time ---------------------------------------------------------------------

ros::Time RosTimeFromNs(int64_t stamp_ns) {
  int64_t sec = stamp_ns / kNsPerSecond;
  int64_t nanosec = stamp_ns % kNsPerSecond;
  if (nanosec < 0) {
    nanosec += kNsPerSecond;
    --sec;
  }
  ros::Time time;
  if (sec > std::numeric_limits<int32_t>::max()) {
    time.sec = std::numeric_limits<int32_t>::max();
    time.nanosec = kNsPerSecond - 1;
  } else if (sec < std::numeric_limits<int32_t>::min()) {
    time.sec = std::numeric_limits<int32_t>::min();
    time.nanosec = 0;
  } else {
    time.sec = static_cast<int32_t>(sec);
    time.nanosec = static_cast<uint32_t>(nanosec);
  }
  return time;
}

int64_t NsFromRosTime(const ros::Time& time) {
  return static_cast<int64_t>(time.sec) * kNsPerSecond + time.nanosec;
}

// --- Images -------------------------------------------------------------------

std::string_view ImageEncoding(const cv::Mat& image) {
  const Encoding* encoding = FindEncoding(image.type());
  return encoding ? encoding->name : std::string_view();
}

bool MakeImage(const cv::Mat& image, int64_t stamp_ns, std::string_view frame_id,
               Outgoing<ros::Image>* out, std::string* error) {
  *out = Outgoing<ros::Image>();
  return internal::FillImage(image, stamp_ns, frame_id, "image", &out->msg(), out, error);
}

bool ImageToMat(const ros::Image& image, cv::Mat* mat, std::string* error) {
  const Encoding* encoding =
      CheckIncomingPixels("image", View(image.encoding), {"mono8", "bgr8", "32FC1"}, image.width,
                          image.height, image.step, image.data._length, error);
  if (!encoding) return false;
  cv::Mat view(static_cast<int>(image.height), static_cast<int>(image.width), encoding->cv_type,
               image.data._buffer, image.step);
  if (image.is_bigendian && encoding->bytes_per_channel > 1) {
    cv::Mat swapped(view.size(), view.type());
    const int row_bytes = view.cols * encoding->bytes_per_pixel;
    const int channel = encoding->bytes_per_channel;
    for (int y = 0; y < view.rows; ++y) {
      const uint8_t* src = view.ptr<uint8_t>(y);
      uint8_t* dst = swapped.ptr<uint8_t>(y);
      for (int i = 0; i < row_bytes; i += channel)
        std::reverse_copy(src + i, src + i + channel, dst + i);
    }
    *mat = swapped;
    return true;
  }
  *mat = view;
  return true;
}

// --- Stereo captures --------------------------------------------------------

bool MakeStereoCapture(const cv::Mat& left, const cv::Mat& right, const StereoCaptureMeta& meta,
                       Outgoing<msg::StereoCapture>* out, std::string* error) {
  const Encoding* encoding = CheckOutgoingMat(left, "left image", {CV_8UC1, CV_8UC3}, error);
  if (!encoding || !CheckOutgoingMat(right, "right image", {CV_8UC1, CV_8UC3}, error)) return false;
  if (left.size() != right.size() || left.type() != right.type()) {
    return Fail(error, "stereo capture: left is " + SizeText(left.cols, left.rows) + " " +
                           cv::typeToString(left.type()) + ", right is " +
                           SizeText(right.cols, right.rows) + " " + cv::typeToString(right.type()) +
                           " (they must match)");
  }
  *out = Outgoing<msg::StereoCapture>();
  msg::StereoCapture& m = out->msg();
  m.session = out->Keep(meta.session);
  m.view_index = meta.view_index;
  m.angle_deg = meta.angle_deg;
  m.exposure_us = meta.exposure_us;
  m.gain_db = meta.gain_db;
  m.width = static_cast<uint32_t>(left.cols);
  m.height = static_cast<uint32_t>(left.rows);
  m.encoding = out->Keep(encoding->name);
  const std::size_t bytes = left.total() * encoding->bytes_per_pixel;
  Borrow(&m.left_data, internal::PackedPixels(left, out), bytes);
  Borrow(&m.right_data, internal::PackedPixels(right, out), bytes);
  m.left_stamp_ns = meta.left_stamp_ns;
  m.right_stamp_ns = meta.right_stamp_ns;
  m.left_frame_id = out->Keep(meta.left_frame_id);
  m.right_frame_id = out->Keep(meta.right_frame_id);
  return true;
}

bool StereoCaptureToMats(const msg::StereoCapture& capture, cv::Mat* left, cv::Mat* right,
                         std::string* error) {
  const Encoding* encoding = FindEncoding(View(capture.encoding));
  const uint64_t step =
      static_cast<uint64_t>(capture.width) * (encoding ? encoding->bytes_per_pixel : 1);
  for (int side = 0; side < 2; ++side) {
    const dds_sequence_octet& data = side == 0 ? capture.left_data : capture.right_data;
    if (!CheckIncomingPixels(side == 0 ? "stereo capture, left" : "stereo capture, right",
                             View(capture.encoding), {"mono8", "bgr8"}, capture.width,
                             capture.height, step, data._length, error)) {
      return false;
    }
  }
  *left = cv::Mat(static_cast<int>(capture.height), static_cast<int>(capture.width),
                  encoding->cv_type, capture.left_data._buffer);
  *right = cv::Mat(static_cast<int>(capture.height), static_cast<int>(capture.width),
                   encoding->cv_type, capture.right_data._buffer);
  return true;
}

// --- Disparity ----------------------------------------------------------------

bool MakeDisparity(const cv::Mat& disparity, const DisparityMeta& meta,
                   Outgoing<msg::Disparity>* out, std::string* error) {
  if (!CheckDisparityInput(disparity, meta, error)) return false;
  *out = Outgoing<msg::Disparity>();
  msg::Disparity& m = out->msg();
  m.session = out->Keep(meta.session);
  m.view_index = meta.view_index;
  m.width = static_cast<uint32_t>(disparity.cols);
  m.height = static_cast<uint32_t>(disparity.rows);
  Borrow(&m.data, reinterpret_cast<const float*>(internal::PackedPixels(disparity, out)),
         disparity.total());
  m.f_px = meta.f_px;
  m.baseline_mm = meta.baseline_mm;
  m.cx_offset_px = meta.cx_offset_px;
  m.min_disparity = meta.min_disparity;
  m.max_disparity = meta.max_disparity;
  m.stamp_ns = meta.stamp_ns;
  m.frame_id = out->Keep(meta.frame_id);
  return true;
}

bool DisparityToMat(const msg::Disparity& disparity, cv::Mat* mat, std::string* error) {
  if (!CheckIncomingPixels("disparity", "32FC1", {"32FC1"}, disparity.width, disparity.height,
                           static_cast<uint64_t>(disparity.width) * sizeof(float),
                           static_cast<uint64_t>(disparity.data._length) * sizeof(float), error)) {
    return false;
  }
  *mat = cv::Mat(static_cast<int>(disparity.height), static_cast<int>(disparity.width), CV_32FC1,
                 disparity.data._buffer);
  return true;
}

bool MakeDisparityImage(const cv::Mat& disparity, const DisparityMeta& meta,
                        Outgoing<ros::DisparityImage>* out, std::string* error) {
  if (!CheckDisparityInput(disparity, meta, error)) return false;
  *out = Outgoing<ros::DisparityImage>();
  ros::DisparityImage& m = out->msg();
  // ROS: d' = x_l − x_r − (cx_l − cx_r); anything below min_disparity is invalid.
  const float min_disparity = meta.min_disparity - meta.cx_offset_px;
  const float invalid = min_disparity - 1.0f;
  auto converted = std::make_shared<cv::Mat>(disparity.size(), CV_32FC1);
  int x_min = disparity.cols, y_min = disparity.rows, x_max = -1, y_max = -1;
  for (int y = 0; y < disparity.rows; ++y) {
    const float* src = disparity.ptr<float>(y);
    float* dst = converted->ptr<float>(y);
    for (int x = 0; x < disparity.cols; ++x) {
      if (!std::isfinite(src[x])) {
        dst[x] = invalid;
        continue;
      }
      dst[x] = src[x] - meta.cx_offset_px;
      x_min = std::min(x_min, x);
      x_max = std::max(x_max, x);
      y_min = std::min(y_min, y);
      y_max = std::max(y_max, y);
    }
  }
  out->KeepAlive(converted);
  if (!internal::FillImage(*converted, meta.stamp_ns, meta.frame_id, "disparity", &m.image, out,
                           error)) {
    return false;
  }
  m.header = m.image.header;
  m.f = meta.f_px;
  m.t = meta.baseline_mm / 1000.0f;
  if (x_max >= 0) {
    m.valid_window.x_offset = static_cast<uint32_t>(x_min);
    m.valid_window.y_offset = static_cast<uint32_t>(y_min);
    m.valid_window.width = static_cast<uint32_t>(x_max - x_min + 1);
    m.valid_window.height = static_cast<uint32_t>(y_max - y_min + 1);
  }
  m.min_disparity = min_disparity;
  m.max_disparity = meta.max_disparity - meta.cx_offset_px;
  m.delta_d = meta.delta_d_px;
  return true;
}

}  // namespace craftscan::dds
