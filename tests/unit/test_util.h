// Helpers for the unit tests (and the session and systemd-file tests that
// include this file): a fixture with a fresh folder per test, synthetic
// stereo pairs with known disparity, and the path of the shared data set.
// Helpers for every test folder: tests/*_util.h.
#pragma once

#include <gtest/gtest.h>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>
#include <random>
#include <string>
#include "test_paths.h"

namespace craftscan::testing {

inline std::filesystem::path SharedData() { return ::craftscan::testing::SharedDataDir(); }

// A fixture with a fresh temporary folder per test, removed afterwards.
class TempDirTest : public ::testing::Test {
 protected:
  void SetUp() override {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    dir_ = std::filesystem::temp_directory_path() /
           ("craftscan_test_" + std::string(info->test_suite_name()) + "_" + info->name() + "_" +
            std::to_string(std::random_device{}()));
    std::filesystem::create_directories(dir_);
  }
  void TearDown() override { std::filesystem::remove_all(dir_); }

  std::string Path(const std::string& name) const { return (dir_ / name).string(); }

  // Writes `bytes` to the file `name` in the folder; returns its path.
  std::string WriteBytes(const std::string& name, const std::string& bytes) const {
    std::ofstream out(Path(name), std::ios::binary);
    out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
    return Path(name);
  }

  std::filesystem::path dir_;
};

// A smooth random colour texture (band-limited so bilinear resampling is
// accurate), width × height, CV_8UC3, reproducible from `seed`.
inline cv::Mat RandomTexture(int width, int height, unsigned seed, int channels = 3) {
  std::mt19937 rng(seed);
  std::uniform_int_distribution<int> u(0, 255);
  cv::Mat coarse((height + 1) / 2 + 1, (width + 1) / 2 + 1, CV_8UC(channels));
  for (int y = 0; y < coarse.rows; ++y)
    for (int x = 0; x < coarse.cols * channels; ++x) coarse.ptr<std::uint8_t>(y)[x] = u(rng);
  cv::Mat up;
  cv::resize(coarse, up, cv::Size(coarse.cols * 2, coarse.rows * 2), 0, 0, cv::INTER_CUBIC);
  cv::GaussianBlur(up, up, cv::Size(3, 3), 0.6);
  return up(cv::Rect(0, 0, width, height)).clone();
}

// Right image of a fronto-parallel or slanted plane seen in `left`: the left
// pixel (x, y) has disparity d(x, y) = a + b·x + c·y, so the right image at
// x_r shows the left image at x with x − d(x, y) = x_r. Returns the right
// image; *gt receives d for every left pixel (CV_32F).
inline cv::Mat RenderRightView(const cv::Mat& left, double a, double b, double c, cv::Mat* gt) {
  cv::Mat map_x(left.size(), CV_32F), map_y(left.size(), CV_32F);
  gt->create(left.size(), CV_32F);
  for (int y = 0; y < left.rows; ++y) {
    for (int xr = 0; xr < left.cols; ++xr) {
      map_x.at<float>(y, xr) = static_cast<float>((xr + a + c * y) / (1.0 - b));
      map_y.at<float>(y, xr) = static_cast<float>(y);
    }
    for (int x = 0; x < left.cols; ++x) gt->at<float>(y, x) = static_cast<float>(a + b * x + c * y);
  }
  cv::Mat right;
  cv::remap(left, right, map_x, map_y, cv::INTER_LINEAR, cv::BORDER_REFLECT);
  return right;
}

}  // namespace craftscan::testing
