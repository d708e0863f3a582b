// The archive of craftscan-record without DDS: byte sizes and wire names,
// files read back bit-exactly, the index, refusals, and the limits (stop,
// rotate, re-opened archives, one writer per folder).
#include <gtest/gtest.h>

#include <stdlib.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "craftscan/pipeline/common/pfm.h"
#include "craftscan/pipeline/common/point_cloud.h"
#include "craftscan/record/archive.h"
#include "file_util.h"
#include "mat_util.h"
#include "record_test_util.h"

namespace craftscan::record {
namespace {

namespace fs = std::filesystem;

using testing::BitExact;
using testing::ReadIndex;
using testing::TempDir;

std::unique_ptr<Archive> OpenArchive(const std::string& dir, uint64_t max_files = 0,
                                     uint64_t max_bytes = 0,
                                     LimitPolicy policy = LimitPolicy::kStop) {
  ArchiveOptions options;
  options.out_dir = dir;
  options.max_files = max_files;
  options.max_bytes = max_bytes;
  options.on_limit = policy;
  std::string error;
  auto archive = Archive::Open(options, &error);
  EXPECT_NE(archive, nullptr) << error;
  return archive;
}

PointCloud MakeCloud(int points, int seed) {
  PointCloud cloud;
  cv::RNG rng(seed);
  for (int i = 0; i < points; ++i) {
    cloud.points_mm.emplace_back(rng.uniform(-50.f, 50.f), rng.uniform(-50.f, 50.f),
                                 rng.uniform(0.f, 80.f));
    cloud.colors_rgb.emplace_back(rng.uniform(0, 256), rng.uniform(0, 256), rng.uniform(0, 256));
    cloud.normals.emplace_back(0.f, 0.f, 1.f);
  }
  return cloud;
}

TEST(RecordByteSize, ParsesBinaryMultiples) {
  uint64_t bytes = 0;
  std::string why;
  ASSERT_TRUE(ParseByteSize("1500", &bytes, &why)) << why;
  EXPECT_EQ(bytes, 1500u);
  ASSERT_TRUE(ParseByteSize("2K", &bytes, &why)) << why;
  EXPECT_EQ(bytes, 2048u);
  ASSERT_TRUE(ParseByteSize("3m", &bytes, &why)) << why;
  EXPECT_EQ(bytes, 3u << 20);
  ASSERT_TRUE(ParseByteSize("2GiB", &bytes, &why)) << why;
  EXPECT_EQ(bytes, 2ull << 30);
  ASSERT_TRUE(ParseByteSize("1tb", &bytes, &why)) << why;
  EXPECT_EQ(bytes, 1ull << 40);
}

TEST(RecordByteSize, RefusesNonsenseWithAReason) {
  uint64_t bytes = 7;
  std::string why;
  for (const char* text :
       {"", "K", "12X", "1.5G", "-3", "0", "0M", "99999999999999999999", "20000000000G", "5 M"}) {
    EXPECT_FALSE(ParseByteSize(text, &bytes, &why)) << text;
    EXPECT_FALSE(why.empty()) << text;
    EXPECT_EQ(bytes, 7u) << text;
  }
}

TEST(RecordWireName, KeepsSafeNamesReplacesOthersRefusesDots) {
  std::string safe, why;
  ASSERT_TRUE(SanitizeWireName("20240611-101500-carved_egg.v2", &safe, &why)) << why;
  EXPECT_EQ(safe, "20240611-101500-carved_egg.v2");
  ASSERT_TRUE(SanitizeWireName("a b/c\\d\x01", &safe, &why)) << why;
  EXPECT_EQ(safe, "a_b_c_d_");
  ASSERT_TRUE(SanitizeWireName("\xc3\xa9t\xc3\xa9", &safe, &why)) << why;  // "été"
  EXPECT_EQ(safe, "__t__");
  safe = "unchanged";
  for (const std::string& hostile :
       {std::string("../../x"), std::string(".."), std::string("."), std::string(".hidden"),
        std::string("a/../b"), std::string(""), std::string(201, 'a')}) {
    EXPECT_FALSE(SanitizeWireName(hostile, &safe, &why)) << hostile;
    EXPECT_FALSE(why.empty());
    EXPECT_EQ(safe, "unchanged");
  }
  EXPECT_TRUE(SanitizeWireName(std::string(200, 'a'), &safe, &why));
}

TEST(RecordWireName, PrintableForLogEscapes) {
  EXPECT_EQ(PrintableForLog("ok"), "ok");
  EXPECT_EQ(PrintableForLog("a\x01'\"\n"), "a\\x01\\'\\\"\\x0a");
  EXPECT_EQ(PrintableForLog(std::string(100, 'x')), std::string(80, 'x') + "...");
}

TEST(RecordArchive, StoresCapturesCloudsAndDisparityBitExact) {
  TempDir dir("craftscan-record-test");
  auto archive = OpenArchive(dir.path());
  ASSERT_NE(archive, nullptr);
  cv::RNG rng(7);
  cv::Mat left(48, 64, CV_8UC3), right(48, 64, CV_8UC3);
  rng.fill(left, cv::RNG::UNIFORM, 0, 256);
  rng.fill(right, cv::RNG::UNIFORM, 0, 256);
  const ItemInfo capture{"st1", "20240611-101500-egg", 3, 1234};
  StoreResult result = archive->StoreCapture(capture, left, right, 22.5);
  ASSERT_EQ(result.status, StoreStatus::kStored) << result.message;
  EXPECT_EQ(result.files, 2u);

  const PointCloud cloud = MakeCloud(500, 1);
  cv::Matx44d pose = cv::Matx44d::eye();
  pose(0, 3) = 12.5;
  result = archive->StoreCloud({"st1", "20240611-101500-egg", 3, 99}, cloud, pose);
  ASSERT_EQ(result.status, StoreStatus::kStored) << result.message;
  result = archive->StoreCloud({"st1", "20240611-101500-egg", -1, 100}, cloud, cv::Matx44d::eye());
  ASSERT_EQ(result.status, StoreStatus::kStored) << result.message;

  cv::Mat disparity(30, 40, CV_32FC1);
  rng.fill(disparity, cv::RNG::UNIFORM, 10.f, 90.f);
  disparity.at<float>(5, 7) = std::nanf("");
  result = archive->StoreDisparity({"st1", "20240611-101500-egg", 3, 101}, disparity);
  ASSERT_EQ(result.status, StoreStatus::kStored) << result.message;

  const fs::path folder = fs::path(dir.path()) / "st1" / "20240611-101500-egg";
  const cv::Mat got_left =
      cv::imread((folder / "view_003_left.png").string(), cv::IMREAD_UNCHANGED);
  const cv::Mat got_right =
      cv::imread((folder / "view_003_right.png").string(), cv::IMREAD_UNCHANGED);
  EXPECT_TRUE(BitExact(got_left, left));
  EXPECT_TRUE(BitExact(got_right, right));
  for (const char* name : {"cloud_003.ply", "fused.ply"}) {
    PointCloud got;
    std::string error;
    ASSERT_TRUE(ReadPly((folder / name).string(), &got, &error)) << error;
    EXPECT_EQ(got.points_mm, cloud.points_mm) << name;
    EXPECT_EQ(got.colors_rgb, cloud.colors_rgb) << name;
    EXPECT_EQ(got.normals, cloud.normals) << name;
  }
  cv::Mat got_disparity;
  std::string error;
  ASSERT_TRUE(ReadPfm((folder / "disparity_003.pfm").string(), &got_disparity, &error)) << error;
  EXPECT_TRUE(BitExact(got_disparity, disparity));  // NaN bits included

  const std::vector<nlohmann::json> index = ReadIndex(folder);
  ASSERT_EQ(index.size(), 5u);
  EXPECT_EQ(index[0]["file"], "view_003_left.png");
  EXPECT_EQ(index[0]["kind"], "left");
  EXPECT_EQ(index[0]["station"], "st1");
  EXPECT_EQ(index[0]["session"], "20240611-101500-egg");
  EXPECT_EQ(index[0]["view"], 3);
  EXPECT_EQ(index[0]["stamp_ns"], 1234);
  EXPECT_EQ(index[0]["angle_deg"], 22.5);
  EXPECT_EQ(index[0]["bytes"], fs::file_size(folder / "view_003_left.png"));
  EXPECT_EQ(index[2]["kind"], "cloud");
  EXPECT_EQ(index[2]["points"], 500);
  EXPECT_EQ(index[2]["world_from_view"][3], 12.5);
  EXPECT_EQ(index[3]["file"], "fused.ply");
  EXPECT_EQ(index[3]["view"], -1);
  EXPECT_EQ(index[4]["kind"], "disparity");
  EXPECT_TRUE(index[0]["time"].is_string());

  const ArchiveTotals totals = archive->totals();
  EXPECT_EQ(totals.files, 5u);
  uint64_t on_disk = 0;
  for (const auto& entry : fs::directory_iterator(folder)) {
    if (entry.path().filename() != "index.jsonl") on_disk += entry.file_size();
  }
  EXPECT_EQ(totals.bytes, on_disk);
  EXPECT_TRUE(fs::is_empty(fs::path(dir.path()) / ".staging"));
}

TEST(RecordArchive, HostileAndOddNamesStayInside) {
  // The archive two levels down in the test's own folder, so that a name
  // escaping one or two levels would land where the test can see it (and
  // not in a shared /tmp, where another program's /tmp/x made it fail).
  TempDir dir("craftscan-record-test");
  const std::string out = dir.path() + "/a/out";
  auto archive = OpenArchive(out);
  ASSERT_NE(archive, nullptr);
  const PointCloud cloud = MakeCloud(10, 2);
  for (const char* session : {"../../x", "..", "/etc", ".staging", "a/../../b"}) {
    const StoreResult result =
        archive->StoreCloud({"st1", session, 0, 0}, cloud, cv::Matx44d::eye());
    if (std::string(session) == "/etc") {
      EXPECT_EQ(result.status, StoreStatus::kStored) << result.message;  // as "_etc"
    } else {
      EXPECT_EQ(result.status, StoreStatus::kRefused) << session;
      EXPECT_NE(result.message.find("name"), std::string::npos) << result.message;
    }
  }
  EXPECT_EQ(archive->StoreCloud({"../st", "s", 0, 0}, cloud, cv::Matx44d::eye()).status,
            StoreStatus::kRefused);
  EXPECT_TRUE(fs::exists(fs::path(out) / "st1" / "_etc" / "cloud_000.ply"));
  const std::vector<nlohmann::json> index = ReadIndex(fs::path(out) / "st1" / "_etc");
  ASSERT_EQ(index.size(), 1u);
  EXPECT_EQ(index[0]["session_raw"], "/etc");
  // Nothing but the archive in the two folders above it.
  const auto names = [](const fs::path& folder) {
    std::vector<std::string> found;
    for (const auto& entry : fs::directory_iterator(folder))
      found.push_back(entry.path().filename());
    return found;
  };
  EXPECT_EQ(names(dir.path()), std::vector<std::string>{"a"});
  EXPECT_EQ(names(fs::path(dir.path()) / "a"), std::vector<std::string>{"out"});
}

TEST(RecordArchive, RefusesInconsistentItems) {
  TempDir dir("craftscan-record-test");
  auto archive = OpenArchive(dir.path());
  ASSERT_NE(archive, nullptr);
  const cv::Mat a(10, 10, CV_8UC1, cv::Scalar(1)), b(10, 12, CV_8UC1, cv::Scalar(2));
  const cv::Mat c(10, 10, CV_16UC1, cv::Scalar(3));
  EXPECT_EQ(archive->StoreCapture({"st1", "s", 0, 0}, a, b, 0).status, StoreStatus::kRefused);
  EXPECT_EQ(archive->StoreCapture({"st1", "s", 0, 0}, c, c, 0).status, StoreStatus::kRefused);
  EXPECT_EQ(archive->StoreCapture({"st1", "s", -1, 0}, a, a, 0).status, StoreStatus::kRefused);
  PointCloud bad = MakeCloud(10, 3);
  bad.colors_rgb.pop_back();
  EXPECT_EQ(archive->StoreCloud({"st1", "s", 0, 0}, bad, cv::Matx44d::eye()).status,
            StoreStatus::kRefused);
  EXPECT_EQ(archive->StoreCloud({"st1", "s", -2, 0}, MakeCloud(3, 4), cv::Matx44d::eye()).status,
            StoreStatus::kRefused);
  EXPECT_EQ(archive->StoreDisparity({"st1", "s", 0, 0}, a).status, StoreStatus::kRefused);
  EXPECT_EQ(archive->totals().files, 0u);
  EXPECT_FALSE(fs::exists(fs::path(dir.path()) / "st1"));
}

TEST(RecordArchive, StoresAModelByteForByteAndCountsItWhenReopened) {
  TempDir dir("craftscan-record-test");
  std::string glb = "glTF";
  for (int i = 0; i < 1000; ++i) glb.push_back(static_cast<char>(i * 7));
  {
    auto archive = OpenArchive(dir.path());
    ASSERT_NE(archive, nullptr);
    EXPECT_EQ(archive->StoreModel({"st1", "s", -1, 0}, "").status, StoreStatus::kRefused);
    EXPECT_EQ(archive->StoreModel({"st1", "s", 2, 0}, glb).status, StoreStatus::kRefused);
    const StoreResult result = archive->StoreModel({"st1", "20240611-101500-egg", -1, 77}, glb);
    ASSERT_EQ(result.status, StoreStatus::kStored) << result.message;
    EXPECT_EQ(result.files, 1u);
    EXPECT_EQ(result.bytes, glb.size());
  }
  const fs::path folder = fs::path(dir.path()) / "st1" / "20240611-101500-egg";
  EXPECT_TRUE(testing::ReadFile(folder / "mesh.glb") == glb);
  const std::vector<nlohmann::json> index = ReadIndex(folder);
  ASSERT_EQ(index.size(), 1u);
  EXPECT_EQ(index[0]["file"], "mesh.glb");
  EXPECT_EQ(index[0]["kind"], "model");
  EXPECT_EQ(index[0]["view"], -1);
  EXPECT_EQ(index[0]["bytes"], glb.size());
  auto reopened = OpenArchive(dir.path());  // a data file of the archive: counted
  ASSERT_NE(reopened, nullptr);
  EXPECT_EQ(reopened->totals().files, 1u);
  EXPECT_EQ(reopened->totals().bytes, glb.size());
}

TEST(RecordArchive, SameItemTwiceReplacesTheFile) {
  TempDir dir("craftscan-record-test");
  auto archive = OpenArchive(dir.path(), /*max_files=*/1);
  ASSERT_NE(archive, nullptr);
  ASSERT_EQ(archive->StoreCloud({"st1", "s", 0, 0}, MakeCloud(10, 5), cv::Matx44d::eye()).status,
            StoreStatus::kStored);
  const PointCloud second = MakeCloud(20, 6);
  const StoreResult result = archive->StoreCloud({"st1", "s", 0, 1}, second, cv::Matx44d::eye());
  ASSERT_EQ(result.status, StoreStatus::kStored) << result.message;
  EXPECT_EQ(archive->totals().files, 1u);
  EXPECT_EQ(archive->totals().bytes, fs::file_size(fs::path(dir.path()) / "st1/s/cloud_000.ply"));
  PointCloud got;
  ASSERT_TRUE(ReadPly(dir.path() + "/st1/s/cloud_000.ply", &got, nullptr));
  EXPECT_EQ(got.points_mm, second.points_mm);
  const auto index = ReadIndex(fs::path(dir.path()) / "st1/s");
  ASSERT_EQ(index.size(), 1u);
  EXPECT_EQ(index[0]["stamp_ns"], 1);
}

TEST(RecordArchive, StopPolicyRefusesTheItemThatWouldExceedAndStaysFull) {
  TempDir dir("craftscan-record-test");
  auto archive = OpenArchive(dir.path(), /*max_files=*/3);
  ASSERT_NE(archive, nullptr);
  const cv::Mat image(8, 8, CV_8UC1, cv::Scalar(9));
  ASSERT_EQ(archive->StoreCapture({"st1", "s", 0, 0}, image, image, 0).status,
            StoreStatus::kStored);
  const StoreResult refused = archive->StoreCapture({"st1", "s", 1, 0}, image, image, 0);
  EXPECT_EQ(refused.status, StoreStatus::kLimitReached);
  EXPECT_NE(refused.message.find("--max-files 3"), std::string::npos) << refused.message;
  // A cloud (one file) would fit, but the archive stays full once reached.
  EXPECT_EQ(archive->StoreCloud({"st1", "s", 0, 0}, MakeCloud(3, 1), cv::Matx44d::eye()).status,
            StoreStatus::kLimitReached);
  EXPECT_EQ(archive->totals().files, 2u);
  EXPECT_FALSE(fs::exists(fs::path(dir.path()) / "st1/s/view_001_left.png"));
  EXPECT_EQ(ReadIndex(fs::path(dir.path()) / "st1/s").size(), 2u);
  EXPECT_TRUE(fs::is_empty(fs::path(dir.path()) / ".staging"));
}

TEST(RecordArchive, RotatePolicyDeletesTheOldestAcrossSessions) {
  TempDir dir("craftscan-record-test");
  const PointCloud cloud = MakeCloud(100, 8);
  std::string error;
  ASSERT_TRUE(WritePly(dir.path() + "/probe.ply", cloud, true, &error)) << error;
  const uint64_t ply_bytes = fs::file_size(dir.path() + "/probe.ply");
  fs::remove(dir.path() + "/probe.ply");
  const std::string out = dir.path() + "/out";
  auto archive = OpenArchive(out, 0, /*max_bytes=*/ply_bytes * 5 / 2, LimitPolicy::kRotate);
  ASSERT_NE(archive, nullptr);
  uint64_t rotated = 0;
  for (int view = 0; view < 5; ++view) {
    // Views 0 and 1 in session "a", the rest in "b".
    const StoreResult result =
        archive->StoreCloud({"st1", view < 2 ? "a" : "b", view, view}, cloud, cv::Matx44d::eye());
    ASSERT_EQ(result.status, StoreStatus::kStored) << result.message;
    rotated += result.rotated_files;
    EXPECT_LE(archive->totals().bytes, ply_bytes * 5 / 2);
  }
  EXPECT_EQ(rotated, 3u);
  EXPECT_EQ(archive->totals().files, 2u);
  EXPECT_FALSE(fs::exists(fs::path(out) / "st1/a"));  // emptied session removed
  std::vector<std::string> left;
  for (const auto& line : ReadIndex(fs::path(out) / "st1/b")) left.push_back(line["file"]);
  EXPECT_EQ(left, (std::vector<std::string>{"cloud_003.ply", "cloud_004.ply"}));
  EXPECT_FALSE(fs::exists(fs::path(out) / "st1/b/cloud_002.ply"));

  // An item bigger than the whole limit is skipped, nothing deleted for it.
  const StoreResult huge =
      archive->StoreCloud({"st1", "b", 9, 0}, MakeCloud(1000, 9), cv::Matx44d::eye());
  EXPECT_EQ(huge.status, StoreStatus::kTooLarge);
  EXPECT_EQ(huge.rotated_files, 0u);
  EXPECT_EQ(archive->totals().files, 2u);
}

TEST(RecordArchive, ReopenedArchiveCountsAndRotatesEarlierFiles) {
  TempDir dir("craftscan-record-test");
  const PointCloud cloud = MakeCloud(10, 10);
  {
    auto archive = OpenArchive(dir.path());
    ASSERT_NE(archive, nullptr);
    for (int view = 0; view < 3; ++view) {
      ASSERT_EQ(archive->StoreCloud({"st1", "old", view, 0}, cloud, cv::Matx44d::eye()).status,
                StoreStatus::kStored);
    }
  }
  // A stale staging file from a killed run is cleared; foreign files are left alone.
  fs::create_directories(fs::path(dir.path()) / ".staging");
  std::ofstream(fs::path(dir.path()) / ".staging" / "7-cloud_000.ply") << "half";
  std::ofstream(fs::path(dir.path()) / "st1" / "old" / "notes.txt") << "mine";
  auto archive = OpenArchive(dir.path(), /*max_files=*/2, 0, LimitPolicy::kRotate);
  ASSERT_NE(archive, nullptr);
  EXPECT_EQ(archive->totals().files, 3u);
  EXPECT_TRUE(fs::is_empty(fs::path(dir.path()) / ".staging"));
  const StoreResult result = archive->StoreCloud({"st1", "new", 0, 0}, cloud, cv::Matx44d::eye());
  ASSERT_EQ(result.status, StoreStatus::kStored) << result.message;
  EXPECT_EQ(result.rotated_files, 2u);
  EXPECT_EQ(archive->totals().files, 2u);
  EXPECT_TRUE(fs::exists(fs::path(dir.path()) / "st1/old/notes.txt"));
  EXPECT_TRUE(fs::exists(fs::path(dir.path()) / "st1/new/cloud_000.ply"));
  // The oldest two went: exactly one of the old views is left, with its index line.
  int old_left = 0;
  for (int view = 0; view < 3; ++view) {
    old_left +=
        fs::exists(fs::path(dir.path()) / ("st1/old/cloud_00" + std::to_string(view) + ".ply"));
  }
  EXPECT_EQ(old_left, 1);
  EXPECT_EQ(ReadIndex(fs::path(dir.path()) / "st1/old").size(), 1u);
}

TEST(RecordArchive, OneWriterPerFolder) {
  TempDir dir("craftscan-record-test");
  auto first = OpenArchive(dir.path());
  ASSERT_NE(first, nullptr);
  ArchiveOptions options;
  options.out_dir = dir.path();
  std::string error;
  EXPECT_EQ(Archive::Open(options, &error), nullptr);
  EXPECT_NE(error.find("in use"), std::string::npos) << error;
  first.reset();
  EXPECT_NE(Archive::Open(options, &error), nullptr) << error;
  options.out_dir = "";
  EXPECT_EQ(Archive::Open(options, &error), nullptr);
  options.out_dir = "/proc/craftscan-no-such-place";
  EXPECT_EQ(Archive::Open(options, &error), nullptr);
  EXPECT_NE(error.find("/proc/craftscan-no-such-place"), std::string::npos) << error;
}

}  // namespace
}  // namespace craftscan::record
