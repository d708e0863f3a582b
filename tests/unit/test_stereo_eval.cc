// The benchmark's stereo evaluation (bench library): disparity metrics on
// hand-computed cases, and LoadStereoScene on scene folders the tests write
// (and on Teddy 2003 when ../shared/data is present).
#include "stereo_scene.h"

#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <random>
#include <stdexcept>
#include <string>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "craftscan/pipeline/common/pfm.h"
#include "test_paths.h"
#include "test_util.h"

namespace craftscan {
namespace {

namespace fs = std::filesystem;
constexpr float kNan = std::numeric_limits<float>::quiet_NaN();

// ---------------------------------------------------------------------------
// EvaluateDisparity

// 3×4 case, worked by hand:
//   gt    10   10   10   10  |  20    0  NaN  20  |  5    5    5   5
//   disp  10.5 11.5 13  NaN  |  20    5   20  21  |  6    7  100   5
//   mask  255  255  255 255  |  255 255  255 255  | 255  255  128   0
// Evaluated (mask 255 and valid gt): all of row 0, (1,0), (1,3), (2,0), (2,1)
// = 8 px. Errors: .5 1.5 3 none | 0 1 | 1 2 (exactly 1 is not bad-1, exactly
// 2 is bad-1 but not bad-2).
struct Crafted {
  cv::Mat gt = (cv::Mat_<float>(3, 4) << 10, 10, 10, 10, 20, 0, kNan, 20, 5, 5, 5, 5);
  cv::Mat disp = (cv::Mat_<float>(3, 4) << 10.5f, 11.5f, 13, kNan, 20, 5, 20, 21, 6, 7, 100, 5);
  cv::Mat mask =
      (cv::Mat_<std::uint8_t>(3, 4) << 255, 255, 255, 255, 255, 255, 255, 255, 255, 255, 128, 0);
};

TEST(EvaluateDisparity, HandComputedMetrics) {
  const Crafted c;
  const DisparityMetrics m = EvaluateDisparity(c.disp, c.gt, c.mask);
  EXPECT_EQ(m.count, 8);
  EXPECT_TRUE(m.IsUsable());
  EXPECT_DOUBLE_EQ(m.bad1, 100.0 * 4 / 8);  // 1.5, 3, none, 2
  EXPECT_DOUBLE_EQ(m.bad2, 100.0 * 2 / 8);  // 3, none
  EXPECT_DOUBLE_EQ(m.density, 100.0 * 7 / 8);
  EXPECT_DOUBLE_EQ(m.avgerr, (0.5 + 1.5 + 3 + 0 + 1 + 1 + 2) / 7);
}

TEST(EvaluateDisparity, EmptyMaskMeansAllPixelsWithGroundTruth) {
  const Crafted c;
  const DisparityMetrics m = EvaluateDisparity(c.disp, c.gt, cv::Mat());
  // Adds (2,2) error 95 and (2,3) error 0: 10 px, 9 estimated.
  EXPECT_EQ(m.count, 10);
  EXPECT_DOUBLE_EQ(m.bad1, 100.0 * 5 / 10);
  EXPECT_DOUBLE_EQ(m.bad2, 100.0 * 3 / 10);
  EXPECT_DOUBLE_EQ(m.density, 100.0 * 9 / 10);
  EXPECT_DOUBLE_EQ(m.avgerr, (9.0 + 95 + 0) / 9);
}

TEST(EvaluateDisparity, InfiniteEstimateCountsAsMissing) {
  const cv::Mat gt = (cv::Mat_<float>(1, 2) << 4, 4);
  const cv::Mat disp = (cv::Mat_<float>(1, 2) << std::numeric_limits<float>::infinity(), 4);
  const DisparityMetrics m = EvaluateDisparity(disp, gt, cv::Mat());
  EXPECT_DOUBLE_EQ(m.bad1, 50.0);
  EXPECT_DOUBLE_EQ(m.density, 50.0);
  EXPECT_DOUBLE_EQ(m.avgerr, 0.0);
}

TEST(EvaluateDisparity, NothingToEvaluate) {
  const cv::Mat gt(2, 2, CV_32FC1, cv::Scalar(0));
  const cv::Mat disp(2, 2, CV_32FC1, cv::Scalar(3));
  const DisparityMetrics m = EvaluateDisparity(disp, gt, cv::Mat());
  EXPECT_EQ(m.count, 0);
  EXPECT_FALSE(m.IsUsable());
  EXPECT_TRUE(std::isnan(m.bad1));
  EXPECT_TRUE(std::isnan(m.avgerr));

  // Evaluated pixels but no estimate at all: avgerr undefined, all bad.
  const cv::Mat gt2(2, 2, CV_32FC1, cv::Scalar(3));
  const cv::Mat none(2, 2, CV_32FC1, cv::Scalar(kNan));
  const DisparityMetrics m2 = EvaluateDisparity(none, gt2, cv::Mat());
  EXPECT_DOUBLE_EQ(m2.bad1, 100.0);
  EXPECT_DOUBLE_EQ(m2.density, 0.0);
  EXPECT_TRUE(std::isnan(m2.avgerr));
}

TEST(EvaluateDisparity, RejectsMismatchedInputs) {
  const cv::Mat f(2, 2, CV_32FC1, cv::Scalar(1));
  EXPECT_THROW(EvaluateDisparity(cv::Mat(2, 2, CV_16SC1), f, cv::Mat()), std::invalid_argument);
  EXPECT_THROW(EvaluateDisparity(f, cv::Mat(2, 3, CV_32FC1), cv::Mat()), std::invalid_argument);
  EXPECT_THROW(EvaluateDisparity(f, f, cv::Mat(2, 2, CV_32FC1)), std::invalid_argument);
  EXPECT_THROW(EvaluateDisparity(f, f, cv::Mat(3, 2, CV_8UC1)), std::invalid_argument);
}

// ---------------------------------------------------------------------------
// LoadStereoScene on a scene folder written by the test

class SceneFolder : public testing::TempDirTest {
 protected:
  static constexpr int kWidth = 8, kHeight = 6;

  void SetUp() override {
    TempDirTest::SetUp();
    // A valid scene: colour pair, 8-bit gt ×4 with a zero (unknown) pixel,
    // 2014-style nonocc mask (255 / 128 / 0).
    cv::Mat left(kHeight, kWidth, CV_8UC3), right(kHeight, kWidth, CV_8UC3);
    cv::randu(left, 0, 255);
    cv::randu(right, 0, 255);
    Write("left.png", left);
    Write("right.png", right);
    cv::Mat gt(kHeight, kWidth, CV_8UC1, cv::Scalar(40));  // 10 px
    gt.at<std::uint8_t>(0, 0) = 0;
    gt.at<std::uint8_t>(1, 2) = 42;  // 10.5 px
    Write("gt.png", gt);
    cv::Mat mask(kHeight, kWidth, CV_8UC1, cv::Scalar(255));
    mask.at<std::uint8_t>(2, 2) = 128;
    mask.at<std::uint8_t>(0, 0) = 0;
    Write("mask.png", mask);
    Json(R"({"name": "tiny", "left": "left.png", "right": "right.png", "gt": "gt.png",
             "gt_scale": 4.0, "ndisp": 16, "mask_nonocc": "mask.png"})");
  }
  void Write(const std::string& name, const cv::Mat& image) const {
    ASSERT_TRUE(cv::imwrite((dir_ / name).string(), image)) << name;
  }
  void Json(const std::string& text) const {
    std::ofstream((dir_ / "scene.json").string()) << text;
  }
  // Loads, expecting failure with an error containing every `needles` entry.
  void ExpectError(std::initializer_list<std::string> needles) const {
    StereoScene scene;
    std::string error;
    EXPECT_FALSE(LoadStereoScene(dir_.string(), &scene, &error));
    for (const std::string& needle : needles) {
      EXPECT_NE(error.find(needle), std::string::npos) << "'" << needle << "' not in: " << error;
    }
  }
};

TEST_F(SceneFolder, LoadsValidScene) {
  StereoScene scene;
  std::string error;
  ASSERT_TRUE(LoadStereoScene(dir_.string(), &scene, &error)) << error;
  EXPECT_EQ(scene.name, "tiny");
  EXPECT_EQ(scene.ndisp, 16);
  EXPECT_EQ(scene.left.type(), CV_8UC3);
  EXPECT_EQ(scene.right.type(), CV_8UC3);
  EXPECT_EQ(scene.left.size(), cv::Size(kWidth, kHeight));
  ASSERT_EQ(scene.gt.type(), CV_32FC1);
  EXPECT_TRUE(std::isnan(scene.gt.at<float>(0, 0)));
  EXPECT_FLOAT_EQ(scene.gt.at<float>(1, 2), 10.5f);
  EXPECT_FLOAT_EQ(scene.gt.at<float>(5, 7), 10.0f);
  ASSERT_EQ(scene.mask_nonocc.type(), CV_8UC1);
  EXPECT_EQ(scene.mask_nonocc.at<std::uint8_t>(2, 2), 128);
  EXPECT_FALSE(scene.HasAllAndDiscMasks());
  // The 128 (occluded) and 0 pixels are not evaluated.
  const DisparityMetrics m = EvaluateDisparity(scene.gt, scene.gt, scene.mask_nonocc);
  EXPECT_EQ(m.count, kWidth * kHeight - 2);
  EXPECT_DOUBLE_EQ(m.bad1, 0.0);
}

TEST_F(SceneFolder, DefaultsWithoutOptionalKeys) {
  cv::Mat grey(kHeight, kWidth, CV_8UC1, cv::Scalar(9));
  Write("grey_l.png", grey);
  cv::Mat grey16(kHeight, kWidth, CV_16UC1, cv::Scalar(65535));
  Write("grey_r.png", grey16);
  cv::Mat gt(kHeight, kWidth, CV_32FC1, cv::Scalar(3.25f));
  gt.at<float>(1, 1) = std::numeric_limits<float>::infinity();
  gt.at<float>(1, 2) = 0;
  std::string error;
  ASSERT_TRUE(WritePfm((dir_ / "gt.pfm").string(), gt, &error)) << error;
  Json(R"({"left": "grey_l.png", "right": "grey_r.png", "gt": "gt.pfm", "ndisp": 4,
           "mask_all": "mask.png", "mask_disc": "mask.png"})");
  StereoScene scene;
  ASSERT_TRUE(LoadStereoScene(dir_.string() + "/", &scene, &error)) << error;
  EXPECT_EQ(scene.name, dir_.filename().string());  // folder name, trailing slash ignored
  EXPECT_EQ(scene.left.type(), CV_8UC1);
  EXPECT_EQ(scene.right.type(), CV_8UC1);  // 16-bit scaled to 8-bit
  EXPECT_EQ(scene.right.at<std::uint8_t>(0, 0), 255);
  EXPECT_FLOAT_EQ(scene.gt.at<float>(0, 0), 3.25f);  // PFM: gt_scale defaults to 1
  EXPECT_TRUE(std::isnan(scene.gt.at<float>(1, 1)));
  EXPECT_TRUE(std::isnan(scene.gt.at<float>(1, 2)));
  // No mask_nonocc: every pixel with valid gt.
  EXPECT_EQ(cv::countNonZero(scene.mask_nonocc == 255), kWidth * kHeight - 2);
  EXPECT_TRUE(scene.HasAllAndDiscMasks());
}

TEST_F(SceneFolder, ColourAndGreyPairBecomesColour) {
  Write("right.png", cv::Mat(kHeight, kWidth, CV_8UC1, cv::Scalar(7)));
  cv::Mat rgba(kHeight, kWidth, CV_8UC4, cv::Scalar(1, 2, 3, 4));
  Write("left.png", rgba);
  StereoScene scene;
  std::string error;
  ASSERT_TRUE(LoadStereoScene(dir_.string(), &scene, &error)) << error;
  EXPECT_EQ(scene.left.type(), CV_8UC3);
  EXPECT_EQ(scene.left.at<cv::Vec3b>(0, 0), cv::Vec3b(1, 2, 3));
  EXPECT_EQ(scene.right.type(), CV_8UC3);
  EXPECT_EQ(scene.right.at<cv::Vec3b>(0, 0), cv::Vec3b(7, 7, 7));
}

TEST_F(SceneFolder, MissingFolder) {
  StereoScene scene;
  std::string error;
  EXPECT_FALSE(LoadStereoScene((dir_ / "absent").string(), &scene, &error));
  EXPECT_NE(error.find("does not exist"), std::string::npos) << error;
  EXPECT_NE(error.find("absent"), std::string::npos) << error;
}

TEST_F(SceneFolder, MissingSceneJson) {
  fs::remove(dir_ / "scene.json");
  ExpectError({"scene.json", "not found"});
}

TEST_F(SceneFolder, MalformedSceneJson) {
  Json(R"({"left": "left.png", )");
  ExpectError({"scene.json", "malformed JSON"});
  Json(R"(["left.png"])");
  ExpectError({"scene.json", "not a JSON object"});
}

TEST_F(SceneFolder, MissingKeys) {
  Json(R"({"right": "right.png", "gt": "gt.png", "gt_scale": 4, "ndisp": 16})");
  ExpectError({"scene.json", "missing key \"left\""});
  Json(R"({"left": "left.png", "right": "right.png", "gt": "gt.png", "gt_scale": 4})");
  ExpectError({"missing key \"ndisp\""});
  Json(R"({"left": "left.png", "right": "right.png", "gt": "gt.png", "ndisp": 16})");
  ExpectError({"missing key \"gt_scale\""});  // required for PNG ground truth
}

TEST_F(SceneFolder, MistypedKeys) {
  Json(R"({"left": 3, "right": "right.png", "gt": "gt.png", "gt_scale": 4, "ndisp": 16})");
  ExpectError({"\"left\" must be a non-empty string"});
  Json(R"({"left": "left.png", "right": "right.png", "gt": "gt.png", "gt_scale": 4,
           "ndisp": "16"})");
  ExpectError({"\"ndisp\" must be an integer"});
  Json(R"({"left": "left.png", "right": "right.png", "gt": "gt.png", "gt_scale": 4,
           "ndisp": 2.5})");
  ExpectError({"\"ndisp\" must be an integer"});
  Json(R"({"left": "left.png", "right": "right.png", "gt": "gt.png", "gt_scale": 0,
           "ndisp": 16})");
  ExpectError({"gt_scale"});
}

TEST_F(SceneFolder, NonPositiveNdisp) {
  Json(R"({"left": "left.png", "right": "right.png", "gt": "gt.png", "gt_scale": 4,
           "ndisp": 0})");
  ExpectError({"\"ndisp\" must be in 1..100000"});
  Json(R"({"left": "left.png", "right": "right.png", "gt": "gt.png", "gt_scale": 4,
           "ndisp": -5})");
  ExpectError({"\"ndisp\" must be in 1..100000"});
}

TEST_F(SceneFolder, MissingAndUnreadableImages) {
  fs::remove(dir_ / "right.png");
  ExpectError({"\"right\"", "right.png", "not found"});
  std::ofstream((dir_ / "right.png").string()) << "not a png";
  ExpectError({"right.png", "unreadable image"});
  std::ofstream((dir_ / "mask.png").string()) << "";
  Write("right.png", cv::Mat(kHeight, kWidth, CV_8UC3, cv::Scalar::all(0)));
  ExpectError({"mask.png", "mask_nonocc", "unreadable image"});
}

TEST_F(SceneFolder, SizeMismatch) {
  Write("right.png", cv::Mat(kHeight, kWidth + 1, CV_8UC3, cv::Scalar::all(0)));
  ExpectError({"\"right\" is 9x6", "\"left\" is 8x6"});
  Write("right.png", cv::Mat(kHeight, kWidth, CV_8UC3, cv::Scalar::all(0)));
  Write("gt.png", cv::Mat(kHeight - 1, kWidth, CV_8UC1, cv::Scalar(4)));
  ExpectError({"\"gt\" is 8x5"});
  Write("gt.png", cv::Mat(kHeight, kWidth, CV_8UC1, cv::Scalar(4)));
  Write("mask.png", cv::Mat(1, 1, CV_8UC1, cv::Scalar(255)));
  ExpectError({"\"mask_nonocc\" is 1x1"});
}

TEST_F(SceneFolder, MalformedPfmGroundTruth) {
  std::ofstream((dir_ / "gt.pfm").string()) << "Pf\n8 6\n-1\nshort";
  Json(R"({"left": "left.png", "right": "right.png", "gt": "gt.pfm", "ndisp": 16})");
  ExpectError({"gt.pfm", "truncated", "\"gt\""});
}

// ---------------------------------------------------------------------------
// Real data (found through CRAFTSCAN_SHARED_DATA, set at configure time)

TEST(SharedScene, LoadsTeddy2003) {
  const fs::path dir = fs::path(::craftscan::testing::SharedDataDir()) / "stereo" / "teddy_2003";
  if (!fs::exists(dir / "scene.json")) {
    GTEST_SKIP() << "shared data absent: " << dir
                 << " (configure with -DCRAFTSCAN_SHARED_DATA=...)";
  }
  StereoScene scene;
  std::string error;
  ASSERT_TRUE(LoadStereoScene(dir.string(), &scene, &error)) << error;
  EXPECT_EQ(scene.name, "teddy_2003");
  EXPECT_EQ(scene.left.size(), cv::Size(450, 375));
  EXPECT_EQ(scene.left.type(), CV_8UC3);
  EXPECT_EQ(scene.right.type(), CV_8UC3);
  EXPECT_EQ(scene.ndisp, 60);
  ASSERT_TRUE(scene.HasAllAndDiscMasks());

  // README: gt range 12.5 … 52.75 px, 98.0 % valid.
  double lo = 0, hi = 0;
  cv::minMaxLoc(scene.gt, &lo, &hi, nullptr, nullptr, scene.gt == scene.gt);
  EXPECT_DOUBLE_EQ(lo, 12.5);
  EXPECT_DOUBLE_EQ(hi, 52.75);
  EXPECT_NEAR(100.0 * cv::countNonZero(scene.gt == scene.gt) / scene.gt.total(), 98.0, 0.05);

  // The masks were palette PNGs: check they decoded to nested regions.
  const int nonocc = cv::countNonZero(scene.mask_nonocc == 255);
  const int all = cv::countNonZero(scene.mask_all == 255);
  const int disc = cv::countNonZero(scene.mask_disc == 255);
  EXPECT_GT(nonocc, 0.8 * scene.gt.total());
  EXPECT_GT(all, nonocc);
  EXPECT_GT(disc, 0);
  EXPECT_LT(disc, nonocc);
  EXPECT_EQ(cv::countNonZero((scene.mask_nonocc == 255) & ~(scene.mask_all == 255)), 0);

  // Ground truth scores perfectly against itself.
  const DisparityMetrics m = EvaluateDisparity(scene.gt, scene.gt, scene.mask_all);
  EXPECT_GT(m.count, 0);
  EXPECT_DOUBLE_EQ(m.bad1, 0.0);
  EXPECT_DOUBLE_EQ(m.density, 100.0);
}

}  // namespace
}  // namespace craftscan
