// Camera pixel formats and their conversion (pixel_conversion.h).
#include "pixel_conversion.h"

#include <arv.h>

#include <algorithm>
#include <cstdio>

#include <opencv2/imgproc.hpp>

namespace craftscan::aravis {
namespace {

using drivers::PixelFormat;

// OpenCV names a Bayer pattern after the 2nd row's 2nd and 3rd pixels,
// GenICam after the 1st row's 1st and 2nd: GenICam RG = OpenCV BG, etc.
int BayerCode(std::uint32_t pfnc, bool to_bgr) {
  switch (pfnc) {
    case ARV_PIXEL_FORMAT_BAYER_RG_8:
      return to_bgr ? cv::COLOR_BayerBG2BGR : cv::COLOR_BayerBG2GRAY;
    case ARV_PIXEL_FORMAT_BAYER_BG_8:
      return to_bgr ? cv::COLOR_BayerRG2BGR : cv::COLOR_BayerRG2GRAY;
    case ARV_PIXEL_FORMAT_BAYER_GB_8:
      return to_bgr ? cv::COLOR_BayerGR2BGR : cv::COLOR_BayerGR2GRAY;
    case ARV_PIXEL_FORMAT_BAYER_GR_8:
      return to_bgr ? cv::COLOR_BayerGB2BGR : cv::COLOR_BayerGB2GRAY;
    default:
      return -1;
  }
}

// Significant bits of an unpacked mono format stored in 16 bits.
int MonoBits(std::uint32_t pfnc) {
  switch (pfnc) {
    case ARV_PIXEL_FORMAT_MONO_10:
      return 10;
    case ARV_PIXEL_FORMAT_MONO_12:
      return 12;
    case ARV_PIXEL_FORMAT_MONO_16:
      return 16;
    default:
      return 8;
  }
}

}  // namespace

const std::vector<CameraFormat>& CameraFormats() {
  static const std::vector<CameraFormat> formats = {
      {ARV_PIXEL_FORMAT_MONO_8, "Mono8", 1, false},
      {ARV_PIXEL_FORMAT_MONO_10, "Mono10", 2, false},
      {ARV_PIXEL_FORMAT_MONO_12, "Mono12", 2, false},
      {ARV_PIXEL_FORMAT_MONO_16, "Mono16", 2, false},
      {ARV_PIXEL_FORMAT_BGR_8_PACKED, "BGR8", 3, true},
      {ARV_PIXEL_FORMAT_RGB_8_PACKED, "RGB8", 3, true},
      {ARV_PIXEL_FORMAT_BAYER_RG_8, "BayerRG8", 1, true},
      {ARV_PIXEL_FORMAT_BAYER_BG_8, "BayerBG8", 1, true},
      {ARV_PIXEL_FORMAT_BAYER_GB_8, "BayerGB8", 1, true},
      {ARV_PIXEL_FORMAT_BAYER_GR_8, "BayerGR8", 1, true},
  };
  return formats;
}

const CameraFormat* FindCameraFormat(std::uint32_t pfnc) {
  for (const CameraFormat& f : CameraFormats()) {
    if (f.pfnc == pfnc) return &f;
  }
  return nullptr;
}

const CameraFormat* FindCameraFormat(std::string_view name) {
  if (name == "RGB8Packed") name = "RGB8";
  if (name == "BGR8Packed") name = "BGR8";
  for (const CameraFormat& f : CameraFormats()) {
    if (f.name == name) return &f;
  }
  return nullptr;
}

std::string FormatNames(const std::vector<std::uint32_t>& pfnc) {
  std::string names;
  for (std::uint32_t value : pfnc) {
    if (!names.empty()) names += ", ";
    if (const CameraFormat* f = FindCameraFormat(value)) {
      names += f->name;
    } else {
      char hex[16];
      std::snprintf(hex, sizeof(hex), "0x%08x", static_cast<unsigned>(value));
      names += hex;
    }
  }
  return names.empty() ? "none" : names;
}

bool CanConvert(const CameraFormat& camera, PixelFormat out, std::string* why) {
  if (out == PixelFormat::kBgr8 && !camera.colour) {
    if (why != nullptr) {
      *why = "pixel_format bgr8 cannot be made from the mono camera format " +
             std::string(camera.name) + " (use pixel_format mono8)";
    }
    return false;
  }
  return true;
}

const CameraFormat* ChooseCameraFormat(const std::vector<std::uint32_t>& offered, PixelFormat out) {
  static const std::uint32_t kMonoOrder[] = {
      ARV_PIXEL_FORMAT_MONO_8,      ARV_PIXEL_FORMAT_MONO_10,    ARV_PIXEL_FORMAT_MONO_12,
      ARV_PIXEL_FORMAT_MONO_16,     ARV_PIXEL_FORMAT_BAYER_RG_8, ARV_PIXEL_FORMAT_BAYER_BG_8,
      ARV_PIXEL_FORMAT_BAYER_GB_8,  ARV_PIXEL_FORMAT_BAYER_GR_8, ARV_PIXEL_FORMAT_BGR_8_PACKED,
      ARV_PIXEL_FORMAT_RGB_8_PACKED};
  static const std::uint32_t kBgrOrder[] = {
      ARV_PIXEL_FORMAT_BGR_8_PACKED, ARV_PIXEL_FORMAT_RGB_8_PACKED, ARV_PIXEL_FORMAT_BAYER_RG_8,
      ARV_PIXEL_FORMAT_BAYER_BG_8,   ARV_PIXEL_FORMAT_BAYER_GB_8,   ARV_PIXEL_FORMAT_BAYER_GR_8};
  const auto pick = [&](const auto& order) -> const CameraFormat* {
    for (std::uint32_t want : order) {
      for (std::uint32_t have : offered) {
        if (have == want) return FindCameraFormat(want);
      }
    }
    return nullptr;
  };
  return out == PixelFormat::kMono8 ? pick(kMonoOrder) : pick(kBgrOrder);
}

bool ConvertImage(const void* data, std::size_t size, int width, int height, std::size_t stride,
                  const CameraFormat& format, PixelFormat out, cv::Mat* image, std::string* why) {
  if (!CanConvert(format, out, why)) return false;
  const std::size_t row_bytes = static_cast<std::size_t>(width) * format.bytes_per_pixel;
  if (data == nullptr || width <= 0 || height <= 0 || stride < row_bytes ||
      size < stride * static_cast<std::size_t>(height - 1) + row_bytes) {
    if (why != nullptr) {
      *why = std::to_string(width) + "x" + std::to_string(height) + " " + std::string(format.name) +
             " image does not fit its " + std::to_string(size) + "-byte buffer";
    }
    return false;
  }
  void* bytes = const_cast<void*>(data);
  switch (format.pfnc) {
    case ARV_PIXEL_FORMAT_MONO_8:
      *image = cv::Mat(height, width, CV_8UC1, bytes, stride).clone();
      return true;
    case ARV_PIXEL_FORMAT_MONO_10:
    case ARV_PIXEL_FORMAT_MONO_12:
    case ARV_PIXEL_FORMAT_MONO_16: {
      const int shift = MonoBits(format.pfnc) - 8;
      image->create(height, width, CV_8UC1);
      for (int y = 0; y < height; ++y) {
        const auto* row =
            static_cast<const std::uint8_t*>(data) + static_cast<std::size_t>(y) * stride;
        auto* dst = image->ptr<std::uint8_t>(y);
        for (int x = 0; x < width; ++x) {
          const unsigned v =
              static_cast<unsigned>(row[2 * x]) | (static_cast<unsigned>(row[2 * x + 1]) << 8);
          dst[x] = static_cast<std::uint8_t>(std::min(255u, v >> shift));
        }
      }
      return true;
    }
    case ARV_PIXEL_FORMAT_BGR_8_PACKED: {
      const cv::Mat src(height, width, CV_8UC3, bytes, stride);
      if (out == PixelFormat::kBgr8) {
        *image = src.clone();
      } else {
        cv::cvtColor(src, *image, cv::COLOR_BGR2GRAY);
      }
      return true;
    }
    case ARV_PIXEL_FORMAT_RGB_8_PACKED: {
      const cv::Mat src(height, width, CV_8UC3, bytes, stride);
      cv::cvtColor(src, *image, out == PixelFormat::kBgr8 ? cv::COLOR_RGB2BGR : cv::COLOR_RGB2GRAY);
      return true;
    }
    default: {
      const int code = BayerCode(format.pfnc, out == PixelFormat::kBgr8);
      if (code < 0) break;
      const cv::Mat src(height, width, CV_8UC1, bytes, stride);
      cv::cvtColor(src, *image, code);
      return true;
    }
  }
  if (why != nullptr) *why = "no conversion from " + std::string(format.name);
  return false;
}

}  // namespace craftscan::aravis
