// Fuzz target: ReadPfm (pipeline/pfm.h) on arbitrary file contents.
// Properties: a success is a non-empty CV_32FC1/CV_32FC3 image within the
// size limit whose every pixel is readable; a failure names the problem.
#include <cstring>
#include <string>
#include <string_view>

#include <opencv2/core.hpp>

#include "craftscan/pipeline/common/pfm.h"
#include "fuzz_target.h"

CRAFTSCAN_FUZZ_TARGET(pfm) {
  const std::string path =
      WriteTempFile("input.pfm", std::string_view(reinterpret_cast<const char*>(data), size));
  cv::Mat image;
  std::string error;
  if (!Outcome(ReadPfm(path, &image, &error), error)) return 0;
  CRAFTSCAN_FUZZ_CHECK(!image.empty());
  CRAFTSCAN_FUZZ_CHECK(image.type() == CV_32FC1 || image.type() == CV_32FC3);
  CRAFTSCAN_FUZZ_CHECK(image.rows >= 1 && image.rows <= 32768 && image.cols >= 1 &&
                       image.cols <= 32768);
  // The data section holds exactly the pixels the header promises (or more).
  CRAFTSCAN_FUZZ_CHECK(image.total() * image.elemSize() <= size);
  // Touch every byte from instrumented code, so ASan checks the bounds.
  unsigned char sum = 0;
  for (int y = 0; y < image.rows; ++y) {
    const unsigned char* row = image.ptr<unsigned char>(y);
    for (std::size_t i = 0; i < image.cols * image.elemSize(); ++i) sum ^= row[i];
  }
  volatile unsigned char sink = sum;
  (void)sink;
  return 0;
}
