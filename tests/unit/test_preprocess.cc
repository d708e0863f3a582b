// Preprocessing (method.md §2): equalization, adaptive Canny, dilation.
#include <gtest/gtest.h>

#include <opencv2/imgproc.hpp>

#include "craftscan/pipeline/stereo/preprocess.h"
#include "test_util.h"

namespace craftscan {
namespace {

TEST(Preprocess, EqualizationSpreadsALowContrastImage) {
  // Grey levels squeezed into [100, 131]: equalization must spread them.
  cv::Mat low = testing::RandomTexture(120, 90, 3, 1) / 8 + 100;
  const Preprocessed p = Preprocess(low, {});
  double lo, hi;
  cv::minMaxLoc(p.grey, &lo, &hi);
  EXPECT_LE(lo, 20);
  EXPECT_GE(hi, 235);
  // Colour images keep their hue: equalizing Y leaves a grey image grey.
  cv::Mat bgr;
  cv::cvtColor(low, bgr, cv::COLOR_GRAY2BGR);
  const Preprocessed c = Preprocess(bgr, {});
  std::vector<cv::Mat> ch;
  cv::split(c.image, ch);
  EXPECT_LE(cv::norm(ch[0], ch[2], cv::NORM_INF), 2);
}

TEST(Preprocess, CannyThresholdsFollowTheMedian) {
  cv::Mat img = testing::RandomTexture(100, 80, 4, 1);
  PreprocessOptions o;
  o.equalize = false;
  std::vector<std::uint8_t> v(img.begin<std::uint8_t>(), img.end<std::uint8_t>());
  std::nth_element(v.begin(), v.begin() + (v.size() - 1) / 2, v.end());
  const double median = v[(v.size() - 1) / 2];
  const Preprocessed p = Preprocess(img, o);
  EXPECT_NEAR(p.canny_low, std::max(o.canny_min_threshold, 0.67 * median), 1.0);
  EXPECT_NEAR(p.canny_high, std::min(255.0, 1.33 * median), 1.0);
}

TEST(Preprocess, DilationWidensTheEdgeMap) {
  cv::Mat img(60, 60, CV_8UC1, cv::Scalar(50));
  img(cv::Rect(30, 0, 30, 60)).setTo(200);
  PreprocessOptions o;
  o.dilate_radius_px = 0;
  const int thin = cv::countNonZero(Preprocess(img, o).edges);
  o.dilate_radius_px = 2;
  const Preprocessed p = Preprocess(img, o);
  const int wide = cv::countNonZero(p.edges);
  ASSERT_GT(thin, 0);
  EXPECT_GE(wide, thin * 4);  // a 1–2 px line grows to 5–6 px
  // The gradient is the Sobel magnitude: flat areas zero, the step large.
  EXPECT_EQ(p.gradient.at<float>(30, 5), 0.f);
  EXPECT_GT(p.gradient.at<float>(30, 30), 120.f);
}

TEST(Preprocess, EqualizedOnlySkipsGradientAndEdges) {
  const cv::Mat img = testing::RandomTexture(64, 48, 5);
  const Preprocessed all = Preprocess(img, {});
  const Preprocessed part = Preprocess(img, {}, PreprocessParts::kEqualizedOnly);
  EXPECT_EQ(cv::norm(all.image, part.image, cv::NORM_INF), 0);
  EXPECT_EQ(cv::norm(all.grey, part.grey, cv::NORM_INF), 0);
  EXPECT_TRUE(part.gradient.empty());
  EXPECT_TRUE(part.edges.empty());
  EXPECT_FALSE(all.edges.empty());
}

// The grey parts give the same grey, gradient and edges as everything, for
// grey and colour inputs, with and without equalization, and no image.
TEST(Preprocess, GreyPartsEqualTheWholeWithoutTheImage) {
  const cv::Mat grey = testing::RandomTexture(64, 48, 7, 1);
  cv::Mat colour;
  cv::merge(std::vector<cv::Mat>{testing::RandomTexture(64, 48, 8, 1), grey,
                                 testing::RandomTexture(64, 48, 9, 1)},
            colour);
  for (const cv::Mat& img : {grey, colour}) {
    for (const bool equalize : {true, false}) {
      PreprocessOptions o;
      o.equalize = equalize;
      const Preprocessed all = Preprocess(img, o);
      const Preprocessed edges = Preprocess(img, o, PreprocessParts::kGreyAndEdges);
      const Preprocessed only = Preprocess(img, o, PreprocessParts::kGreyOnly);
      ASSERT_TRUE(edges.IsUsable() && only.IsUsable()) << edges.message << only.message;
      EXPECT_EQ(cv::norm(all.grey, edges.grey, cv::NORM_INF), 0);
      EXPECT_EQ(cv::norm(all.grey, only.grey, cv::NORM_INF), 0);
      EXPECT_EQ(cv::norm(all.gradient, edges.gradient, cv::NORM_INF), 0);
      EXPECT_EQ(cv::norm(all.edges, edges.edges, cv::NORM_INF), 0);
      EXPECT_EQ(all.canny_low, edges.canny_low);
      EXPECT_TRUE(edges.image.empty());
      EXPECT_TRUE(only.image.empty());
      EXPECT_TRUE(only.edges.empty());
      EXPECT_TRUE(only.gradient.empty());
    }
  }
}

// The edges taken after the grey image are the edges of the whole; an
// unusable result gets a reason, not edges.
TEST(Preprocess, EdgesAfterTheGreyImageEqualTheWhole) {
  const cv::Mat img = testing::RandomTexture(80, 60, 11);
  const Preprocessed all = Preprocess(img, {});
  Preprocessed part = Preprocess(img, {}, PreprocessParts::kGreyOnly);
  PreprocessScratch scratch;
  PreprocessEdges({}, &part, &scratch);
  ASSERT_TRUE(part.IsUsable()) << part.message;
  EXPECT_EQ(cv::norm(all.gradient, part.gradient, cv::NORM_INF), 0);
  EXPECT_EQ(cv::norm(all.edges, part.edges, cv::NORM_INF), 0);
  EXPECT_EQ(all.canny_high, part.canny_high);
  EXPECT_GT(cv::countNonZero(part.edges), 0);

  Preprocessed failed = Preprocess(cv::Mat(), {});
  PreprocessEdges({}, &failed, &scratch);
  EXPECT_EQ(failed.status, Preprocessed::Status::kInvalidInput);
  EXPECT_NE(failed.message.find("no usable grey image"), std::string::npos) << failed.message;
}

// The inputs that used to throw std::invalid_argument: a failed result that
// says why, never an exception.
TEST(Preprocess, BadInputFailsWithTheReason) {
  PreprocessOptions o;
  auto expect_invalid = [](const Preprocessed& p, const std::string& needle) {
    EXPECT_EQ(p.status, Preprocessed::Status::kInvalidInput);
    EXPECT_FALSE(p.IsUsable());
    EXPECT_NE(p.message.find(needle), std::string::npos) << p.message;
    EXPECT_TRUE(p.image.empty() && p.grey.empty() && p.gradient.empty() && p.edges.empty());
  };
  Preprocessed p;
  EXPECT_NO_THROW(p = Preprocess(cv::Mat(), o));
  expect_invalid(p, "empty image");
  EXPECT_NO_THROW(p = Preprocess(cv::Mat(10, 10, CV_32F), o));
  expect_invalid(p, "CV_8UC1 or CV_8UC3");
  o.canny_aperture = 4;
  std::string why;
  EXPECT_FALSE(o.IsValid(&why));
  EXPECT_NE(why.find("canny_aperture"), std::string::npos);
  EXPECT_NO_THROW(p = Preprocess(cv::Mat(10, 10, CV_8UC1, cv::Scalar(7)), o));
  expect_invalid(p, "canny_aperture");
}

}  // namespace
}  // namespace craftscan
