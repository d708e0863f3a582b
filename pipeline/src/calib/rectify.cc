#include "craftscan/pipeline/calib/rectify.h"

#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>
#include <string>
#include <vector>

#include "calibration_internal.h"

namespace craftscan {

using calib_internal::Fail;

namespace {

bool SameGeometry(const StereoCalibration& a, const StereoCalibration& b) {
  return a.image_size == b.image_size && a.left.camera_matrix == b.left.camera_matrix &&
         a.right.camera_matrix == b.right.camera_matrix && a.left.distortion == b.left.distortion &&
         a.right.distortion == b.right.distortion &&
         a.left.distortion_rational == b.left.distortion_rational &&
         a.right.distortion_rational == b.right.distortion_rational && a.R1 == b.R1 &&
         a.R2 == b.R2 && a.P1 == b.P1 && a.P2 == b.P2;
}

std::vector<cv::Point2f> RectifyPoints(const std::vector<cv::Point2f>& raw,
                                       const CameraIntrinsics& camera, const cv::Matx33d& r,
                                       const cv::Matx34d& p) {
  std::vector<cv::Point2f> out;
  if (raw.empty()) return out;
  cv::undistortPoints(raw, out, cv::Mat(camera.camera_matrix), camera.DistortionCoeffs(),
                      cv::Mat(r), cv::Mat(p));
  return out;
}

}  // namespace

bool Rectifier::Init(const StereoCalibration& calibration, std::string* error) {
  std::string why;
  if (!calibration.IsValid(&why)) {
    *this = Rectifier();
    return Fail(error, "Rectifier: invalid calibration: " + why);
  }
  if (IsReady() && SameGeometry(calibration, calibration_)) {
    calibration_ = calibration;  // report or turntable may differ; the maps do not
    return true;
  }
  cv::Mat l1, l2, r1, r2;
  try {
    cv::initUndistortRectifyMap(cv::Mat(calibration.left.camera_matrix),
                                calibration.left.DistortionCoeffs(), cv::Mat(calibration.R1),
                                cv::Mat(calibration.P1), calibration.image_size, CV_16SC2, l1, l2);
    cv::initUndistortRectifyMap(cv::Mat(calibration.right.camera_matrix),
                                calibration.right.DistortionCoeffs(), cv::Mat(calibration.R2),
                                cv::Mat(calibration.P2), calibration.image_size, CV_16SC2, r1, r2);
  } catch (const cv::Exception& e) {
    *this = Rectifier();
    return Fail(error, std::string("Rectifier: initUndistortRectifyMap failed: ") +
                           calib_internal::CvErrorText(e));
  }
  calibration_ = calibration;
  left_map1_ = l1;
  left_map2_ = l2;
  right_map1_ = r1;
  right_map2_ = r2;
  ++maps_built_;
  return true;
}

bool Rectifier::Rectify(const cv::Mat& left, const cv::Mat& right, cv::Mat* left_rectified,
                        cv::Mat* right_rectified, std::string* error) const {
  if (!IsReady()) return Fail(error, "Rectifier: not initialised (call Init first)");
  if (left_rectified == nullptr || right_rectified == nullptr) {
    return Fail(error, "Rectifier: null output");
  }
  const cv::Size size = calibration_.image_size;
  if (left.size() != size || right.size() != size) {
    return Fail(error, "Rectifier: images are " + std::to_string(left.cols) + "x" +
                           std::to_string(left.rows) + " and " + std::to_string(right.cols) + "x" +
                           std::to_string(right.rows) + ", the calibration is for " +
                           std::to_string(size.width) + "x" + std::to_string(size.height));
  }
  if (left.type() != right.type()) return Fail(error, "Rectifier: left and right types differ");
  try {
    cv::remap(left, *left_rectified, left_map1_, left_map2_, cv::INTER_LINEAR, cv::BORDER_CONSTANT,
              cv::Scalar::all(0));
    cv::remap(right, *right_rectified, right_map1_, right_map2_, cv::INTER_LINEAR,
              cv::BORDER_CONSTANT, cv::Scalar::all(0));
  } catch (const cv::Exception& e) {
    return Fail(error, std::string("Rectifier: remap failed: ") + calib_internal::CvErrorText(e));
  }
  return true;
}

bool Rectifier::RectifyLeft(const cv::Mat& left, cv::Mat* left_rectified,
                            std::string* error) const {
  if (!IsReady()) return Fail(error, "Rectifier: not initialised (call Init first)");
  if (left_rectified == nullptr) return Fail(error, "Rectifier: null output");
  const cv::Size size = calibration_.image_size;
  if (left.size() != size) {
    return Fail(error, "Rectifier: the image is " + std::to_string(left.cols) + "x" +
                           std::to_string(left.rows) + ", the calibration is for " +
                           std::to_string(size.width) + "x" + std::to_string(size.height));
  }
  try {
    cv::remap(left, *left_rectified, left_map1_, left_map2_, cv::INTER_LINEAR, cv::BORDER_CONSTANT,
              cv::Scalar::all(0));
  } catch (const cv::Exception& e) {
    return Fail(error, std::string("Rectifier: remap failed: ") + calib_internal::CvErrorText(e));
  }
  return true;
}

std::vector<cv::Point2f> Rectifier::RectifyLeftPoints(const std::vector<cv::Point2f>& raw) const {
  if (!IsReady()) return {};
  return RectifyPoints(raw, calibration_.left, calibration_.R1, calibration_.P1);
}

std::vector<cv::Point2f> Rectifier::RectifyRightPoints(const std::vector<cv::Point2f>& raw) const {
  if (!IsReady()) return {};
  return RectifyPoints(raw, calibration_.right, calibration_.R2, calibration_.P2);
}

}  // namespace craftscan
