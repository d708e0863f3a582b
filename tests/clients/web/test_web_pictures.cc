// The console's pictures (craftscan/web/pictures.h): base64, JPEG data URLs
// and the false-colour disparity pictures of the "disparity" message.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "craftscan/web/pictures.h"

namespace craftscan::web {
namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
constexpr float kInf = std::numeric_limits<float>::infinity();
const std::string kJpegPrefix = "data:image/jpeg;base64,";

// Turbo's colour (BGR) at 8-bit index `i`.
cv::Vec3b Turbo(int i) {
  cv::Mat index(1, 1, CV_8UC1, cv::Scalar(i)), colour;
  cv::applyColorMap(index, colour, cv::COLORMAP_TURBO);
  return colour.at<cv::Vec3b>(0, 0);
}

int Distance(const cv::Vec3b& a, const cv::Vec3b& b) {
  return std::abs(a[0] - b[0]) + std::abs(a[1] - b[1]) + std::abs(a[2] - b[2]);
}

// The image in a JPEG data URL (empty if it is not one).
cv::Mat DecodeDataUrl(const std::string& url) {
  if (url.rfind(kJpegPrefix, 0) != 0) return {};
  std::vector<unsigned char> bytes;
  unsigned bits = 0;
  int count = 0;
  for (char c : url.substr(kJpegPrefix.size())) {
    const std::string table = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    const std::size_t v = table.find(c);
    if (v == std::string::npos) break;  // '=' padding
    bits = (bits << 6) | static_cast<unsigned>(v);
    if ((count += 6) >= 8) bytes.push_back(static_cast<unsigned char>(bits >> (count -= 8)));
  }
  return cv::imdecode(bytes, cv::IMREAD_COLOR);
}

TEST(WebPictures, Base64OfTheRfcExamples) {
  auto b64 = [](const std::string& s) { return Base64({s.begin(), s.end()}); };
  EXPECT_EQ(b64(""), "");
  EXPECT_EQ(b64("f"), "Zg==");
  EXPECT_EQ(b64("fo"), "Zm8=");
  EXPECT_EQ(b64("foo"), "Zm9v");
  EXPECT_EQ(b64("foob"), "Zm9vYg==");
  EXPECT_EQ(b64("fooba"), "Zm9vYmE=");
  EXPECT_EQ(b64("foobar"), "Zm9vYmFy");
}

TEST(WebPictures, JpegDataUrlShrinksWideImagesOnly) {
  const cv::Mat wide(480, 1280, CV_8UC3, cv::Scalar(10, 200, 30));
  cv::Mat back = DecodeDataUrl(JpegDataUrl(wide));
  ASSERT_FALSE(back.empty());
  EXPECT_EQ(back.size(), cv::Size(320, 120));
  EXPECT_LT(Distance(back.at<cv::Vec3b>(60, 160), {10, 200, 30}), 12);
  const cv::Mat narrow(100, 200, CV_8UC1, cv::Scalar(90));
  back = DecodeDataUrl(JpegDataUrl(narrow));
  EXPECT_EQ(back.size(), cv::Size(200, 100));
  EXPECT_EQ(JpegDataUrl(cv::Mat()), "");
  EXPECT_EQ(JpegDataUrl(cv::Mat(4, 4, CV_32FC2, cv::Scalar(1, 2))), "") << "no JPEG of that";
}

// A 640 × 480 map: a horizontal ramp 10 … 50 px on the left half (in
// steps of two pixels, as the picture at half the size samples it), NaN on
// the right half, and a band of ±inf rows: invalid pixels black, valid ones
// coloured from Turbo's first colour to its last, the fraction exact.
TEST(WebPictures, DisparityValidPixelsColouredInvalidBlackFractionExact) {
  cv::Mat map(480, 640, CV_32FC1, cv::Scalar(kNaN));
  for (int y = 0; y < 480; ++y) {
    for (int x = 0; x < 320; ++x) map.at<float>(y, x) = 10.0f + 40.0f * (x / 2) / 159;
  }
  for (int x = 0; x < 640; ++x) {
    for (int y = 400; y < 420; ++y) map.at<float>(y, x) = (y % 2 ? kInf : -kInf);
  }
  const DisparityPicture p = RenderDisparity(map);
  ASSERT_EQ(p.bgr.type(), CV_8UC3);
  EXPECT_EQ(p.bgr.size(), cv::Size(320, 240));
  EXPECT_EQ(p.valid_pixels, 320 * (480 - 20));
  EXPECT_DOUBLE_EQ(p.valid_fraction, 320.0 * 460 / (640.0 * 480));
  EXPECT_FLOAT_EQ(p.scale_min, 10);
  EXPECT_FLOAT_EQ(p.scale_max, 50);

  const cv::Vec3b black(0, 0, 0);
  int coloured = 0, dark = 0;
  for (int y = 0; y < 240; ++y) {
    for (int x = 0; x < 320; ++x) {
      const bool valid = x < 160 && !(y >= 200 && y < 210);
      const cv::Vec3b c = p.bgr.at<cv::Vec3b>(y, x);
      if (valid) coloured += c != black;
      if (!valid) dark += c == black;
    }
  }
  EXPECT_EQ(coloured, 160 * 230) << "every valid pixel coloured (Turbo has no black)";
  EXPECT_EQ(dark, 320 * 240 - 160 * 230) << "every invalid pixel black";
  // The ramp's ends get the map's ends; the middle another colour.
  EXPECT_LE(Distance(p.bgr.at<cv::Vec3b>(10, 0), Turbo(0)), 3);
  EXPECT_LE(Distance(p.bgr.at<cv::Vec3b>(10, 159), Turbo(255)), 3);
  EXPECT_LE(Distance(p.bgr.at<cv::Vec3b>(10, 80), Turbo(128)), 12);
  EXPECT_GT(Distance(p.bgr.at<cv::Vec3b>(10, 0), p.bgr.at<cv::Vec3b>(10, 159)), 100);
}

TEST(WebPictures, DisparityWithoutValidPixelsOrWithOneValue) {
  const DisparityPicture none = RenderDisparity(cv::Mat(100, 200, CV_32FC1, cv::Scalar(kNaN)));
  EXPECT_EQ(none.bgr.size(), cv::Size(200, 100)) << "narrow maps keep their size";
  EXPECT_EQ(cv::countNonZero(none.bgr.reshape(1)), 0);
  EXPECT_EQ(none.valid_fraction, 0);
  EXPECT_TRUE(std::isnan(none.scale_min) && std::isnan(none.scale_max));

  const DisparityPicture flat = RenderDisparity(cv::Mat(100, 200, CV_32FC1, cv::Scalar(42)));
  EXPECT_EQ(flat.valid_fraction, 1);
  EXPECT_DOUBLE_EQ(flat.scale_min, 41.5);
  EXPECT_DOUBLE_EQ(flat.scale_max, 42.5);
  EXPECT_LE(Distance(flat.bgr.at<cv::Vec3b>(50, 100), Turbo(128)), 12);

  EXPECT_TRUE(RenderDisparity(cv::Mat()).bgr.empty());
  EXPECT_TRUE(RenderDisparity(cv::Mat(10, 10, CV_8UC1, cv::Scalar(3))).bgr.empty());
}

TEST(WebPictures, DisparityMessageCarriesTheMapsFiguresAndPicture) {
  client::DisparityUpdate u;
  u.session = "20240102-030405-box";
  u.view_index = 3;
  u.min_disparity = 0;
  u.max_disparity = 127;
  u.disparity = cv::Mat(512, 640, CV_32FC1, cv::Scalar(kNaN));
  u.disparity(cv::Rect(0, 0, 640, 128)).setTo(20);
  u.disparity(cv::Rect(0, 128, 640, 128)).setTo(60);
  const nlohmann::json m = DisparityMessage(u);
  EXPECT_EQ(m.value("type", ""), "disparity");
  EXPECT_EQ(m.value("session", ""), u.session);
  EXPECT_EQ(m.value("view_index", -1), 3);
  EXPECT_EQ(m.value("width", 0), 640);
  EXPECT_EQ(m.value("height", 0), 512);
  EXPECT_EQ(m.value("min_disparity", -1.0), 0);
  EXPECT_EQ(m.value("max_disparity", -1.0), 127);
  EXPECT_EQ(m.value("scale_min", -1.0), 20);
  EXPECT_EQ(m.value("scale_max", -1.0), 60);
  EXPECT_DOUBLE_EQ(m.value("valid_fraction", -1.0), 0.5);
  const cv::Mat image = DecodeDataUrl(m.value("image", ""));
  ASSERT_FALSE(image.empty()) << m.value("image", "").substr(0, 80);
  EXPECT_EQ(image.size(), cv::Size(320, 256));
  EXPECT_LE(Distance(image.at<cv::Vec3b>(32, 160), Turbo(0)), 30) << "JPEG: near";
  EXPECT_LE(Distance(image.at<cv::Vec3b>(96, 160), Turbo(255)), 30);
  EXPECT_LE(Distance(image.at<cv::Vec3b>(200, 160), {0, 0, 0}), 12);

  u.disparity.setTo(kNaN);
  const nlohmann::json empty = DisparityMessage(u);
  EXPECT_TRUE(empty["scale_min"].is_null() && empty["scale_max"].is_null()) << empty.dump();
  EXPECT_EQ(empty.value("valid_fraction", -1.0), 0);
}

}  // namespace
}  // namespace craftscan::web
