// PFM files (common/pfm.h): bit-exact round trips (one and three channels,
// ROIs), byte order and row order, header tolerance, errors; a Middlebury
// 2014 ground truth when ../shared/data is present.
#include "craftscan/pipeline/common/pfm.h"
#include "mat_util.h"
#include "test_util.h"

#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>
#include "test_paths.h"

namespace craftscan {
namespace {

namespace fs = std::filesystem;
using testing::BitExact;

using Pfm = testing::TempDirTest;

// Bytes of `values` as float32 in the given byte order.
std::string FloatBytes(const std::vector<float>& values, bool little_endian) {
  std::string out;
  for (float v : values) {
    std::uint32_t bits;
    std::memcpy(&bits, &v, sizeof(bits));
    for (int i = 0; i < 4; ++i) {
      const int shift = little_endian ? 8 * i : 8 * (3 - i);
      out.push_back(static_cast<char>((bits >> shift) & 0xFF));
    }
  }
  return out;
}

cv::Mat RandomImage(int rows, int cols, int type) {
  cv::Mat image(rows, cols, type);
  cv::randu(image, -1000.0, 1000.0);
  return image;
}

TEST_F(Pfm, RoundTripsOneChannel) {
  cv::Mat image = RandomImage(7, 5, CV_32FC1);
  image.at<float>(0, 0) = std::numeric_limits<float>::quiet_NaN();
  image.at<float>(6, 4) = std::numeric_limits<float>::infinity();
  std::string error;
  ASSERT_TRUE(WritePfm(Path("a.pfm"), image, &error)) << error;
  cv::Mat back;
  ASSERT_TRUE(ReadPfm(Path("a.pfm"), &back, &error)) << error;
  EXPECT_TRUE(BitExact(image, back));
}

TEST_F(Pfm, RoundTripsThreeChannels) {
  const cv::Mat image = RandomImage(4, 9, CV_32FC3);
  std::string error;
  ASSERT_TRUE(WritePfm(Path("c.pfm"), image, &error)) << error;
  cv::Mat back;
  ASSERT_TRUE(ReadPfm(Path("c.pfm"), &back, &error)) << error;
  EXPECT_TRUE(BitExact(image, back));
}

TEST_F(Pfm, RoundTripsNonContinuousRoi) {
  const cv::Mat big = RandomImage(10, 10, CV_32FC1);
  const cv::Mat roi = big(cv::Rect(2, 3, 5, 4));
  std::string error;
  ASSERT_TRUE(WritePfm(Path("roi.pfm"), roi, &error)) << error;
  cv::Mat back;
  ASSERT_TRUE(ReadPfm(Path("roi.pfm"), &back, &error)) << error;
  EXPECT_TRUE(BitExact(roi.clone(), back));
}

TEST_F(Pfm, WritesLittleEndianBottomRowFirst) {
  cv::Mat image = (cv::Mat_<float>(2, 2) << 1, 2, 3, 4);
  std::string error;
  ASSERT_TRUE(WritePfm(Path("w.pfm"), image, &error)) << error;
  std::ifstream in(Path("w.pfm"), std::ios::binary);
  const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const std::string header = "Pf\n2 2\n-1.0\n";
  ASSERT_EQ(bytes.size(), header.size() + 16);
  EXPECT_EQ(bytes.substr(0, header.size()), header);
  EXPECT_EQ(bytes.substr(header.size()), FloatBytes({3, 4, 1, 2}, /*little_endian=*/true));
}

TEST_F(Pfm, ReadsBigEndian) {
  // 3 wide, 2 high; stored bottom row (4 5 6) first.
  const std::string path =
      WriteBytes("be.pfm", "Pf\n3 2\n1.0\n" + FloatBytes({4, 5, 6, 1, 2, 3.5f}, false));
  cv::Mat image;
  std::string error;
  ASSERT_TRUE(ReadPfm(path, &image, &error)) << error;
  ASSERT_EQ(image.type(), CV_32FC1);
  ASSERT_EQ(image.size(), cv::Size(3, 2));
  EXPECT_EQ(image.at<float>(0, 0), 1);
  EXPECT_EQ(image.at<float>(0, 2), 3.5f);
  EXPECT_EQ(image.at<float>(1, 0), 4);
  EXPECT_EQ(image.at<float>(1, 2), 6);
}

TEST_F(Pfm, ReadsLittleEndianColourAsBgr) {
  // One pixel, stored R G B = 1 2 3; scale magnitude is ignored.
  const std::string path =
      WriteBytes("le.pfm", "PF\n1 1\n-0.003922\n" + FloatBytes({1, 2, 3}, true));
  cv::Mat image;
  std::string error;
  ASSERT_TRUE(ReadPfm(path, &image, &error)) << error;
  ASSERT_EQ(image.type(), CV_32FC3);
  EXPECT_EQ(image.at<cv::Vec3f>(0, 0), cv::Vec3f(3, 2, 1));
}

TEST_F(Pfm, ToleratesIrregularHeaderWhitespace) {
  const std::string path = WriteBytes("ws.pfm", "Pf 2\t1\n\n-1\n" + FloatBytes({7, 8}, true));
  cv::Mat image;
  std::string error;
  ASSERT_TRUE(ReadPfm(path, &image, &error)) << error;
  EXPECT_EQ(image.at<float>(0, 1), 8);
}

TEST_F(Pfm, MissingFileIsAnError) {
  cv::Mat image;
  std::string error;
  EXPECT_FALSE(ReadPfm(Path("nope.pfm"), &image, &error));
  EXPECT_NE(error.find("nope.pfm"), std::string::npos) << error;
  EXPECT_NE(error.find("cannot open"), std::string::npos) << error;
}

TEST_F(Pfm, TruncatedDataIsAnError) {
  const std::string path = WriteBytes("t.pfm", "Pf\n4 4\n-1\n" + FloatBytes({1, 2, 3}, true));
  cv::Mat image;
  std::string error;
  EXPECT_FALSE(ReadPfm(path, &image, &error));
  EXPECT_NE(error.find("truncated"), std::string::npos) << error;
  EXPECT_TRUE(image.empty());
}

struct MalformedCase {
  const char* name;
  std::string bytes;
  const char* expected;  // substring of the error
};

TEST_F(Pfm, MalformedHeadersAreErrors) {
  const std::string pixel = FloatBytes({1}, true);
  const std::vector<MalformedCase> cases = {
      {"empty", "", "bad magic"},
      {"ppm", "P6\n1 1\n255\n", "bad magic"},
      {"pf_lowercase", "pf\n1 1\n-1\n" + pixel, "bad magic"},
      {"header_only", "Pf\n", "width/height"},
      {"letters", "Pf\nab 1\n-1\n" + pixel, "width/height"},
      {"float_width", "Pf\n1.5 1\n-1\n" + pixel, "width/height"},
      {"zero_width", "Pf\n0 1\n-1\n", "bad dimensions"},
      {"negative_height", "Pf\n1 -3\n-1\n", "bad dimensions"},
      {"huge", "Pf\n40000 40000\n-1\n" + pixel, "bad dimensions"},
      {"overflow", "Pf\n99999999999999999999 1\n-1\n", "width/height"},
      {"zero_scale", "Pf\n1 1\n0\n" + pixel, "scale"},
      {"nan_scale", "Pf\n1 1\nnan\n" + pixel, "scale"},
      {"no_scale", "Pf\n1 1\n", "scale"},
      {"long_token", "Pf\n" + std::string(1000, '1') + " 1\n-1\n", "width/height"},
  };
  for (const MalformedCase& c : cases) {
    const std::string path = WriteBytes(std::string(c.name) + ".pfm", c.bytes);
    cv::Mat image;
    std::string error;
    EXPECT_FALSE(ReadPfm(path, &image, &error)) << c.name;
    EXPECT_NE(error.find(c.expected), std::string::npos) << c.name << ": " << error;
    EXPECT_NE(error.find(path), std::string::npos) << c.name << ": " << error;
  }
}

TEST_F(Pfm, WriteRejectsBadInput) {
  std::string error;
  EXPECT_FALSE(WritePfm(Path("e.pfm"), cv::Mat(), &error));
  EXPECT_FALSE(WritePfm(Path("u8.pfm"), cv::Mat(2, 2, CV_8UC1, cv::Scalar(1)), &error));
  EXPECT_NE(error.find("CV_32FC1"), std::string::npos) << error;
  EXPECT_FALSE(WritePfm(Path("c2.pfm"), cv::Mat(2, 2, CV_32FC2, cv::Scalar(1)), &error));
  EXPECT_FALSE(
      WritePfm((dir_ / "no_such_dir" / "x.pfm").string(), cv::Mat(2, 2, CV_32FC1), &error));
  // Writes are atomic (a temporary beside the target), so the failure is the
  // temporary's creation in the missing folder.
  EXPECT_NE(error.find("cannot create a temporary file"), std::string::npos) << error;
  EXPECT_NE(error.find("no_such_dir"), std::string::npos) << error;
  EXPECT_TRUE(WritePfm(Path("null_error.pfm"), cv::Mat(1, 1, CV_32FC1, cv::Scalar(0)), nullptr));
}

TEST_F(Pfm, EncodeGivesTheBytesWritePfmWrites) {
  for (int type : {CV_32FC1, CV_32FC3}) {
    const cv::Mat image = RandomImage(5, 7, type);
    std::string bytes, error;
    ASSERT_TRUE(EncodePfm(image, &bytes, &error)) << error;
    const std::string path = Path("encoded.pfm");
    ASSERT_TRUE(WritePfm(path, image, &error)) << error;
    std::ifstream in(path, std::ios::binary);
    const std::string written{std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
    EXPECT_EQ(bytes, written);
  }
  std::string bytes = "stale", error;
  EXPECT_FALSE(EncodePfm(cv::Mat(), &bytes, &error));
  EXPECT_TRUE(bytes.empty());
  EXPECT_NE(error.find("empty image"), std::string::npos) << error;
  EXPECT_FALSE(EncodePfm(cv::Mat(2, 2, CV_8UC1, cv::Scalar(1)), &bytes, &error));
  EXPECT_NE(error.find("CV_32FC1"), std::string::npos) << error;
  EXPECT_FALSE(EncodePfm(cv::Mat(2, 2, CV_32FC1), nullptr, nullptr));
}

TEST_F(Pfm, ReadsMiddlebury2014GroundTruth) {
  const fs::path path = fs::path(::craftscan::testing::SharedDataDir()) / "stereo" /
                        "adirondack_2014_q" / "disp_left.pfm";
  if (!fs::exists(path)) GTEST_SKIP() << "shared data absent: " << path;
  cv::Mat gt;
  std::string error;
  ASSERT_TRUE(ReadPfm(path.string(), &gt, &error)) << error;
  ASSERT_EQ(gt.type(), CV_32FC1);
  EXPECT_EQ(gt.size(), cv::Size(718, 496));
  // README: finite range 9.463 … 63.045 px, +inf = unknown.
  double lo = 1e9, hi = -1e9;
  for (int y = 0; y < gt.rows; ++y) {
    for (int x = 0; x < gt.cols; ++x) {
      const float v = gt.at<float>(y, x);
      if (!std::isfinite(v)) continue;
      lo = std::min(lo, static_cast<double>(v));
      hi = std::max(hi, static_cast<double>(v));
    }
  }
  EXPECT_NEAR(lo, 9.463, 1e-3);
  EXPECT_NEAR(hi, 63.045, 1e-3);
}

}  // namespace
}  // namespace craftscan
