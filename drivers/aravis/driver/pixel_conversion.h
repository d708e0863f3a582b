// Camera pixel formats the aravis driver accepts and their conversion to the
// driver API's output formats (implementation header; pure, no I/O).
//
//   camera format            -> mono8                  -> bgr8
//   Mono8                       copy                      refused (mono camera)
//   Mono10, Mono12, Mono16      high 8 bits (v >> n−8)    refused
//   (unpacked, little-endian)
//   BGR8 / RGB8 (packed)        cv::cvtColor to gray      copy / channel swap
//   BayerRG8/BG8/GB8/GR8        demosaic to gray          demosaic (bilinear)
//
// A mono camera is never asked for colour: the driver refuses bgr8 rather
// than replicate gray into three channels.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include <opencv2/core.hpp>

#include "craftscan/drivers/camera.h"

namespace craftscan::aravis {

struct CameraFormat {
  std::uint32_t pfnc = 0;   // the GenICam PFNC value (ArvPixelFormat)
  std::string_view name;    // GenICam name, e.g. "Mono16"
  int bytes_per_pixel = 1;  // 1, 2 or 3
  bool colour = false;      // BGR8/RGB8/Bayer
};

// Every camera format the driver converts.
const std::vector<CameraFormat>& CameraFormats();
// Null if the driver does not convert that format.
const CameraFormat* FindCameraFormat(std::uint32_t pfnc);
// By GenICam name ("Mono16"; "RGB8Packed"/"BGR8Packed" are accepted as
// aliases of RGB8/BGR8). Null if unknown.
const CameraFormat* FindCameraFormat(std::string_view name);
// "Mono8, Mono16, ..." (unknown values as hex).
std::string FormatNames(const std::vector<std::uint32_t>& pfnc);

// Whether `out` can be made from `camera`; false and *why otherwise.
bool CanConvert(const CameraFormat& camera, drivers::PixelFormat out, std::string* why);

// The camera format to use for `out` among the camera's `offered` formats,
// in order of preference (no conversion, then the cheapest); null if none.
const CameraFormat* ChooseCameraFormat(const std::vector<std::uint32_t>& offered,
                                       drivers::PixelFormat out);

// Converts one image of width×height pixels whose rows are `stride` bytes
// apart (stride ≥ width·bytes_per_pixel) to `out` (CV_8UC1, or CV_8UC3 BGR).
// False and *why on a buffer shorter than the image or an impossible
// conversion. *image gets its own memory.
bool ConvertImage(const void* data, std::size_t size, int width, int height, std::size_t stride,
                  const CameraFormat& format, drivers::PixelFormat out, cv::Mat* image,
                  std::string* why);

}  // namespace craftscan::aravis
