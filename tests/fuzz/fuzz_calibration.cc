// Fuzz target: LoadCalibration (pipeline/calibration.h, OpenCV YAML) on
// arbitrary file contents. Properties: a success is a calibration that
// passes IsValid; a failure names the problem and leaves the output as it was.
#include <string>
#include <string_view>

#include "craftscan/pipeline/calib/calibration.h"
#include "fuzz_target.h"

CRAFTSCAN_FUZZ_TARGET(calibration) {
  const std::string path = WriteTempFile(
      "calibration.yaml", std::string_view(reinterpret_cast<const char*>(data), size));
  StereoCalibration calibration;
  calibration.image_size = cv::Size(-7, -7);  // a sentinel: must survive a failure
  std::string error;
  if (!Outcome(LoadCalibration(path, &calibration, &error), error)) {
    CRAFTSCAN_FUZZ_CHECK(calibration.image_size == cv::Size(-7, -7));
    return 0;
  }
  std::string why;
  CRAFTSCAN_FUZZ_CHECK(calibration.IsValid(&why));
  return 0;
}
