// craftscan-record end to end: this process publishes captures, clouds and
// disparity maps of two stations on a private DDS domain kept on loopback;
// the real craftscan-record binary runs as a subprocess and archives them.
// Checks: files bit-exact, index lines, the file limit (stop) and the byte
// limit (rotate), --count/--duration, hostile session names, malformed
// samples skipped, SIGKILL mid-write leaves only whole files, SIGTERM → exit
// 0 with a summary, bad arguments and one recorder per archive.
//
// No cross-talk with tests running in parallel: each process picks a random
// domain id, traffic stays on loopback, and every test uses its own stations.
#include <gtest/gtest.h>

#include <signal.h>
#include <stdlib.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <memory>
#include <random>
#include <regex>
#include <string>
#include <thread>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "bagit_check.h"
#include "craftscan/dds/convert.h"
#include "craftscan/dds/endpoint.h"
#include "craftscan/dds/participant.h"
#include "craftscan/dds/topics.h"
#include "craftscan/pipeline/common/pfm.h"
#include "craftscan/pipeline/common/point_cloud.h"
#include "dds_test_util.h"
#include "file_util.h"
#include "mat_util.h"
#include "process_util.h"
#include "record_test_util.h"
#include "test_paths.h"
#include "wait_util.h"

namespace craftscan::dds {
namespace {

namespace fs = std::filesystem;
using std::chrono::milliseconds;
using testing::BitExact;
using testing::ReadFile;
using testing::ReadIndex;
using testing::WaitFor;
constexpr milliseconds kTimeout{20000};  // generous: the machine is shared

using ::craftscan::testing::ProcessDomainId;
using ::craftscan::testing::TestDdsConfig;
using ::craftscan::testing::UniqueStation;

// One participant per process: it creates the domain with the test config.
std::shared_ptr<Participant> SharedParticipant() {
  static const std::shared_ptr<Participant> participant = testing::MakeTestParticipant();
  return participant;
}

// A temporary folder with the archive in <root>/a/out (so that <root>/a
// shows whether anything escaped it) and the recorder's stdout/stderr.
class TempRoot {
 public:
  const std::string& root() const { return dir_.path(); }
  std::string out() const { return dir_.path() + "/a/out"; }

 private:
  testing::TempDir dir_{"craftscan-record-test"};
};

// craftscan-record as a child process; killed if still running at the end.
class RecorderProcess {
 public:
  RecorderProcess(const std::string& log_dir, const std::vector<std::string>& extra_args,
                  const std::string& name = "recorder")
      : stdout_path_(log_dir + "/" + name + ".stdout"),
        stderr_path_(log_dir + "/" + name + ".stderr") {
    std::vector<std::string> args = {::craftscan::testing::RecordPath(), "--domain",
                                     std::to_string(ProcessDomainId()), "--dds-config",
                                     TestDdsConfig()};
    args.insert(args.end(), extra_args.begin(), extra_args.end());
    testing::SpawnOptions options;
    options.stdout_path = stdout_path_;
    options.stderr_path = stderr_path_;
    testing::Spawn(args, options, &child_);
  }
  bool started() const { return child_.started(); }

  // The exit code (128 + signal if killed by one), or −1 if it did not exit
  // within `timeout` (then it is killed).
  int Wait(milliseconds timeout = kTimeout) {
    const int code = child_.Wait(timeout);
    if (code == -1) child_.Kill();
    return code;
  }
  int Terminate() {
    child_.Signal(SIGTERM);
    return Wait();
  }

  // True once the recorder has said it records (archive open, readers made).
  bool WaitUntilRecording() {
    return WaitFor([&] { return Stderr().find("recording ") != std::string::npos || !Alive(); },
                   kTimeout) &&
           Alive();
  }
  bool Alive() { return child_.Running(); }

  std::string Stdout() const { return ReadFile(stdout_path_); }
  std::string Stderr() const { return ReadFile(stderr_path_); }

 private:
  std::string stdout_path_, stderr_path_;
  testing::ChildProcess child_;  // killed if still running
};

// Writers for one station's capture, cloud and disparity topics.
struct StationPublisher {
  explicit StationPublisher(std::string station_id) : station(std::move(station_id)) {
    std::string error;
    auto participant = SharedParticipant();
    if (!participant) return;
    captures = Writer<msg::StereoCapture>::Create(participant, CaptureTopic(station), &error);
    clouds = Writer<msg::PointCloud>::Create(participant, CloudTopic(station), &error);
    disparities = Writer<msg::Disparity>::Create(participant, DisparityTopic(station), &error);
    EXPECT_TRUE(captures && clouds && disparities) << error;
  }
  bool ok() const { return captures && clouds && disparities; }

  // Writes and waits until the recorder's reader has the sample.
  template <typename Msg>
  static ::testing::AssertionResult Publish(Writer<Msg>* writer, const Msg& message) {
    std::string error;
    if (!writer->Write(message, &error) || !writer->WaitForAcks(kTimeout, &error)) {
      return ::testing::AssertionFailure() << writer->topic_name() << ": " << error;
    }
    return ::testing::AssertionSuccess();
  }

  ::testing::AssertionResult Capture(const std::string& session, int view, const cv::Mat& left,
                                     const cv::Mat& right, int wire_width = 0) {
    StereoCaptureMeta meta;
    meta.session = session;
    meta.view_index = view;
    meta.angle_deg = 15.0 * view;
    meta.left_stamp_ns = meta.right_stamp_ns = 1'718'100'000'000'000'000 + view;
    Outgoing<msg::StereoCapture> out;
    std::string error;
    if (!MakeStereoCapture(left, right, meta, &out, &error)) {
      return ::testing::AssertionFailure() << error;
    }
    if (wire_width > 0) out.msg().width = static_cast<uint32_t>(wire_width);  // malformed
    return Publish(captures.get(), out.msg());
  }

  ::testing::AssertionResult Cloud(const std::string& session, int view, const PointCloud& cloud,
                                   int wire_point_count = -1) {
    CloudMeta meta;
    meta.session = session;
    meta.view_index = view;
    meta.kind = view < 0 ? "fused" : "view";
    meta.world_from_view(0, 3) = 10.0 * view;
    meta.stamp_ns = 1'718'100'000'000'000'000 + view;
    Outgoing<msg::PointCloud> out;
    std::string error;
    if (!MakeCloud(cloud, meta, &out, &error)) return ::testing::AssertionFailure() << error;
    if (wire_point_count >= 0) out.msg().point_count = static_cast<uint32_t>(wire_point_count);
    return Publish(clouds.get(), out.msg());
  }

  ::testing::AssertionResult Disparity(const std::string& session, int view, const cv::Mat& map) {
    DisparityMeta meta;
    meta.session = session;
    meta.view_index = view;
    meta.f_px = 1200;
    meta.baseline_mm = 80;
    meta.max_disparity = 128;
    Outgoing<msg::Disparity> out;
    std::string error;
    if (!MakeDisparity(map, meta, &out, &error)) return ::testing::AssertionFailure() << error;
    return Publish(disparities.get(), out.msg());
  }

  std::string station;
  std::unique_ptr<Writer<msg::StereoCapture>> captures;
  std::unique_ptr<Writer<msg::PointCloud>> clouds;
  std::unique_ptr<Writer<msg::Disparity>> disparities;
};

PointCloud RandomCloud(int points, int seed, bool attributes) {
  PointCloud cloud;
  cv::RNG rng(seed);
  for (int i = 0; i < points; ++i) {
    cloud.points_mm.emplace_back(rng.uniform(-60.f, 60.f), rng.uniform(-60.f, 60.f),
                                 rng.uniform(0.f, 90.f));
    if (attributes) {
      cloud.colors_rgb.emplace_back(rng.uniform(0, 256), rng.uniform(0, 256), rng.uniform(0, 256));
      const cv::Vec3f n(rng.uniform(-1.f, 1.f), rng.uniform(-1.f, 1.f), 1.f);
      cloud.normals.push_back(n / cv::norm(n));
    }
  }
  return cloud;
}

cv::Mat RandomImage(int type, int seed) {
  cv::Mat image(48, 64, type);
  cv::RNG(seed).fill(image, cv::RNG::UNIFORM, 0, 256);
  return image;
}

// The summary row of `station`: files, bytes, captures, clouds, disparity,
// malformed, refused; empty if absent.
std::vector<uint64_t> SummaryRow(const std::string& summary, const std::string& station) {
  std::smatch match;
  const std::regex row("(^|\\n)" + station +
                       " +([0-9]+) +([0-9]+) +([0-9]+) +([0-9]+) +([0-9]+) +([0-9]+) +([0-9]+)\\n");
  if (!std::regex_search(summary, match, row)) return {};
  std::vector<uint64_t> values;
  for (int i = 2; i <= 8; ++i) values.push_back(std::stoull(match[i].str()));
  return values;
}

// Every entry below `out` resolves inside it; no temporaries are left.
void ExpectOnlyWholeFilesInside(const std::string& out) {
  const fs::path root = fs::canonical(out);
  for (const auto& entry : fs::recursive_directory_iterator(root)) {
    const fs::path real = fs::weakly_canonical(entry.path());
    EXPECT_EQ(real.string().rfind(root.string() + "/", 0), 0u) << real;
    EXPECT_EQ(entry.path().filename().string().find(".tmp"), std::string::npos) << entry.path();
  }
}

TEST(Record, TwoStationsBitExactThenSigtermGivesExitZeroAndASummary) {
  TempRoot temp;
  StationPublisher a(UniqueStation("r")), b(UniqueStation("r"));
  ASSERT_TRUE(a.ok() && b.ok());
  RecorderProcess recorder(temp.root(), {"--station", a.station, "--station", b.station, "--out",
                                         temp.out(), "--what", "clouds,captures,disparity"});
  ASSERT_TRUE(recorder.started());
  for (StationPublisher* p : {&a, &b}) {
    ASSERT_TRUE(p->captures->WaitForReaders(1, kTimeout)) << recorder.Stderr();
    ASSERT_TRUE(p->clouds->WaitForReaders(1, kTimeout));
    ASSERT_TRUE(p->disparities->WaitForReaders(1, kTimeout));
  }
  const std::string session = "20240611-101500-carved_egg";
  const cv::Mat a_left = RandomImage(CV_8UC1, 1), a_right = RandomImage(CV_8UC1, 2);
  const cv::Mat b_left = RandomImage(CV_8UC3, 3), b_right = RandomImage(CV_8UC3, 4);
  const PointCloud a_view = RandomCloud(2000, 5, true), a_fused = RandomCloud(3000, 6, true);
  const PointCloud b_view = RandomCloud(1500, 7, false);
  cv::Mat disparity(40, 50, CV_32FC1);
  cv::RNG(8).fill(disparity, cv::RNG::UNIFORM, 5.f, 120.f);
  disparity.at<float>(3, 4) = std::nanf("");
  ASSERT_TRUE(a.Capture(session, 0, a_left, a_right));
  ASSERT_TRUE(a.Cloud(session, 0, a_view));
  ASSERT_TRUE(a.Cloud(session, -1, a_fused));
  ASSERT_TRUE(a.Disparity(session, 0, disparity));
  ASSERT_TRUE(b.Capture(session, 7, b_left, b_right));
  ASSERT_TRUE(b.Cloud(session, 7, b_view));

  const fs::path a_dir = fs::path(temp.out()) / a.station / session;
  const fs::path b_dir = fs::path(temp.out()) / b.station / session;
  ASSERT_TRUE(WaitFor([&] { return ReadIndex(a_dir).size() == 5 && ReadIndex(b_dir).size() == 3; },
                      kTimeout))
      << recorder.Stderr();

  EXPECT_TRUE(
      BitExact(cv::imread((a_dir / "view_000_left.png").string(), cv::IMREAD_UNCHANGED), a_left));
  EXPECT_TRUE(
      BitExact(cv::imread((a_dir / "view_000_right.png").string(), cv::IMREAD_UNCHANGED), a_right));
  EXPECT_TRUE(
      BitExact(cv::imread((b_dir / "view_007_left.png").string(), cv::IMREAD_UNCHANGED), b_left));
  EXPECT_TRUE(
      BitExact(cv::imread((b_dir / "view_007_right.png").string(), cv::IMREAD_UNCHANGED), b_right));
  const std::vector<std::pair<fs::path, const PointCloud*>> clouds = {
      {a_dir / "cloud_000.ply", &a_view},
      {a_dir / "fused.ply", &a_fused},
      {b_dir / "cloud_007.ply", &b_view}};
  for (const auto& [path, sent] : clouds) {
    PointCloud got;
    std::string error;
    ASSERT_TRUE(ReadPly(path.string(), &got, &error)) << error;
    EXPECT_EQ(got.points_mm, sent->points_mm) << path;
    EXPECT_EQ(got.colors_rgb, sent->colors_rgb) << path;
    EXPECT_EQ(got.normals, sent->normals) << path;
  }
  cv::Mat got_disparity;
  std::string error;
  ASSERT_TRUE(ReadPfm((a_dir / "disparity_000.pfm").string(), &got_disparity, &error)) << error;
  EXPECT_TRUE(BitExact(got_disparity, disparity));

  uint64_t a_bytes = 0;
  for (const nlohmann::json& line : ReadIndex(a_dir)) {
    EXPECT_EQ(line["station"], a.station);
    EXPECT_EQ(line["session"], session);
    EXPECT_EQ(line["bytes"], fs::file_size(a_dir / line["file"].get<std::string>()));
    a_bytes += line["bytes"].get<uint64_t>();
    if (line["file"] == "cloud_000.ply") {
      EXPECT_EQ(line["world_from_view"][3], 0.0);
      EXPECT_EQ(line["points"], 2000);
    }
    if (line["file"] == "fused.ply") {
      EXPECT_EQ(line["view"], -1);
    }
  }

  EXPECT_EQ(recorder.Terminate(), 0) << recorder.Stderr();
  const std::string summary = recorder.Stdout();
  EXPECT_NE(summary.find("(requested): SIGTERM"), std::string::npos) << summary;
  // files, bytes, captures, clouds, disparity, malformed, refused
  EXPECT_EQ(SummaryRow(summary, a.station), (std::vector<uint64_t>{5, a_bytes, 1, 2, 1, 0, 0}))
      << summary;
  const std::vector<uint64_t> b_row = SummaryRow(summary, b.station);
  ASSERT_EQ(b_row.size(), 7u) << summary;
  EXPECT_EQ(b_row[0], 3u);
  EXPECT_EQ(b_row[2], 1u);
  EXPECT_EQ(b_row[3], 1u);
  EXPECT_FALSE(fs::exists(fs::path(temp.out()) / ".staging"));
  ExpectOnlyWholeFilesInside(temp.out());
}

// One publishing station (a_), an archive folder (temp_.out()), and the
// arguments that point craftscan-record at both.
class RecordOneStation : public ::testing::Test {
 protected:
  void SetUp() override { ASSERT_TRUE(a_.ok()); }

  // --station <a_> --out <temp_.out()> followed by `extra`.
  std::vector<std::string> Args(const std::vector<std::string>& extra) const {
    std::vector<std::string> args = {"--station", a_.station, "--out", temp_.out()};
    args.insert(args.end(), extra.begin(), extra.end());
    return args;
  }

  TempRoot temp_;
  StationPublisher a_{UniqueStation("r")};
};

TEST_F(RecordOneStation, StopsAtTheFileLimitWithoutExceedingIt) {
  RecorderProcess recorder(temp_.root(), Args({"--what", "captures", "--max-files", "5"}));
  ASSERT_TRUE(a_.captures->WaitForReaders(1, kTimeout)) << recorder.Stderr();
  const cv::Mat image = RandomImage(CV_8UC1, 11);
  for (int view = 0; view < 3; ++view) ASSERT_TRUE(a_.Capture("s", view, image, image));
  // The third capture would make 6 files: the recorder stops by itself.
  EXPECT_EQ(recorder.Wait(), 0) << recorder.Stderr();
  EXPECT_NE(recorder.Stdout().find("(limit_reached)"), std::string::npos) << recorder.Stdout();
  EXPECT_NE(recorder.Stderr().find("--max-files 5"), std::string::npos) << recorder.Stderr();
  EXPECT_EQ(ReadIndex(fs::path(temp_.out()) / a_.station / "s").size(), 4u);
  EXPECT_TRUE(fs::exists(fs::path(temp_.out()) / a_.station / "s" / "view_001_right.png"));
  EXPECT_FALSE(fs::exists(fs::path(temp_.out()) / a_.station / "s" / "view_002_left.png"));
  EXPECT_EQ(SummaryRow(recorder.Stdout(), a_.station).at(0), 4u);
  ExpectOnlyWholeFilesInside(temp_.out());
}

TEST_F(RecordOneStation, RotatesTheOldestFilesToStayUnderTheByteLimit) {
  const PointCloud cloud = RandomCloud(400, 12, true);
  std::string error;
  ASSERT_TRUE(WritePly(temp_.root() + "/probe.ply", cloud, true, &error)) << error;
  const uint64_t ply_bytes = fs::file_size(temp_.root() + "/probe.ply");
  fs::remove(temp_.root() + "/probe.ply");
  const uint64_t limit = ply_bytes * 5 / 2;
  RecorderProcess recorder(
      temp_.root(), Args({"--what", "clouds", "--max-bytes", std::to_string(limit), "--rotate"}));
  ASSERT_TRUE(a_.clouds->WaitForReaders(1, kTimeout)) << recorder.Stderr();
  for (int view = 0; view < 5; ++view) ASSERT_TRUE(a_.Cloud("s", view, cloud));
  const fs::path dir = fs::path(temp_.out()) / a_.station / "s";
  ASSERT_TRUE(WaitFor(
      [&] {
        const auto index = ReadIndex(dir);
        return !index.empty() && index.back()["file"] == "cloud_004.ply";
      },
      kTimeout))
      << recorder.Stderr();
  EXPECT_EQ(recorder.Terminate(), 0) << recorder.Stderr();

  std::vector<std::string> files;
  uint64_t bytes = 0;
  for (const auto& entry : fs::directory_iterator(dir)) {
    if (entry.path().filename() == "index.jsonl") continue;
    files.push_back(entry.path().filename());
    bytes += entry.file_size();
  }
  std::sort(files.begin(), files.end());
  EXPECT_EQ(files, (std::vector<std::string>{"cloud_003.ply", "cloud_004.ply"}));
  EXPECT_LE(bytes, limit);
  EXPECT_EQ(ReadIndex(dir).size(), 2u);
  PointCloud got;
  ASSERT_TRUE(ReadPly((dir / "cloud_004.ply").string(), &got, &error)) << error;
  EXPECT_EQ(got.points_mm, cloud.points_mm);
  const std::string summary = recorder.Stdout();
  EXPECT_NE(summary.find("rotation deleted 3 files, " + std::to_string(3 * ply_bytes) + " bytes"),
            std::string::npos)
      << summary;
  EXPECT_EQ(SummaryRow(summary, a_.station).at(0), 5u);  // recorded this run
}

TEST_F(RecordOneStation, HostileSessionNamesStayInsideOut) {
  RecorderProcess recorder(temp_.root(), Args({"--what", "clouds"}));
  ASSERT_TRUE(a_.clouds->WaitForReaders(1, kTimeout)) << recorder.Stderr();
  const PointCloud cloud = RandomCloud(50, 13, false);
  ASSERT_TRUE(a_.Cloud("../../x", 0, cloud));
  ASSERT_TRUE(a_.Cloud("..", 1, cloud));
  ASSERT_TRUE(a_.Cloud("x/../../y", 4, cloud));
  ASSERT_TRUE(a_.Cloud("evil/name\n", 2, cloud));
  ASSERT_TRUE(a_.Cloud("good", 3, cloud));
  const fs::path good = fs::path(temp_.out()) / a_.station / "good" / "cloud_003.ply";
  ASSERT_TRUE(WaitFor([&] { return fs::exists(good); }, kTimeout)) << recorder.Stderr();
  EXPECT_EQ(recorder.Terminate(), 0) << recorder.Stderr();

  const std::string log = recorder.Stderr();
  EXPECT_NE(log.find("skipped cloud of session '../../x' view 0"), std::string::npos) << log;
  EXPECT_NE(log.find("session name '../../x' starts with '.'"), std::string::npos) << log;
  EXPECT_NE(log.find("session '..' view 1"), std::string::npos) << log;
  EXPECT_NE(log.find("session name 'x/../../y' contains '..'"), std::string::npos) << log;
  EXPECT_TRUE(fs::exists(fs::path(temp_.out()) / a_.station / "evil_name_" / "cloud_002.ply"));
  EXPECT_EQ(SummaryRow(recorder.Stdout(), a_.station),
            (std::vector<uint64_t>{2, 2 * fs::file_size(good), 0, 2, 0, 0, 3}))
      << recorder.Stdout();
  // Nothing escaped: <root>/a holds only the archive, <root> only a/ and the logs.
  std::vector<std::string> above;
  for (const auto& entry : fs::directory_iterator(fs::path(temp_.out()).parent_path())) {
    above.push_back(entry.path().filename());
  }
  EXPECT_EQ(above, std::vector<std::string>{"out"});
  for (const auto& entry : fs::directory_iterator(temp_.root())) {
    EXPECT_TRUE(entry.path().filename() == "a" || entry.path().extension() == ".stdout" ||
                entry.path().extension() == ".stderr")
        << entry.path();
  }
  ExpectOnlyWholeFilesInside(temp_.out());
}

TEST_F(RecordOneStation, MalformedSamplesAreLoggedAndSkipped) {
  RecorderProcess recorder(temp_.root(), Args({"--what", "clouds,captures"}));
  ASSERT_TRUE(a_.clouds->WaitForReaders(1, kTimeout)) << recorder.Stderr();
  ASSERT_TRUE(a_.captures->WaitForReaders(1, kTimeout));
  const PointCloud cloud = RandomCloud(30, 14, true);
  const cv::Mat image = RandomImage(CV_8UC3, 15);
  ASSERT_TRUE(a_.Cloud("s", 0, cloud, /*wire_point_count=*/31));
  ASSERT_TRUE(a_.Capture("s", 0, image, image, /*wire_width=*/60));
  ASSERT_TRUE(a_.Cloud("s", 1, cloud));
  ASSERT_TRUE(a_.Capture("s", 1, image, image));
  const fs::path dir = fs::path(temp_.out()) / a_.station / "s";
  ASSERT_TRUE(WaitFor([&] { return ReadIndex(dir).size() == 3; }, kTimeout)) << recorder.Stderr();
  EXPECT_EQ(recorder.Terminate(), 0) << recorder.Stderr();

  const std::string log = recorder.Stderr();
  EXPECT_NE(log.find("skipped malformed cloud of session 's' view 0"), std::string::npos) << log;
  EXPECT_NE(log.find("skipped malformed capture of session 's' view 0"), std::string::npos) << log;
  EXPECT_FALSE(fs::exists(dir / "cloud_000.ply"));
  EXPECT_FALSE(fs::exists(dir / "view_000_left.png"));
  EXPECT_TRUE(
      BitExact(cv::imread((dir / "view_001_left.png").string(), cv::IMREAD_UNCHANGED), image));
  const std::vector<uint64_t> row = SummaryRow(recorder.Stdout(), a_.station);
  ASSERT_EQ(row.size(), 7u) << recorder.Stdout();
  EXPECT_EQ(row[0], 3u);  // files
  EXPECT_EQ(row[5], 2u);  // malformed
}

TEST_F(RecordOneStation, KilledMidWriteLeavesOnlyWholeFiles) {
  // Incompressible 640×480 colour pairs (~1 MB of PNG per image): writing
  // them takes long enough for the kill to land while files are in flight.
  constexpr int kViews = 6;
  std::vector<cv::Mat> images;
  for (int i = 0; i < kViews; ++i) {
    images.emplace_back(480, 640, CV_8UC3);
    cv::RNG(100 + i).fill(images.back(), cv::RNG::UNIFORM, 0, 256);
  }
  const fs::path dir = fs::path(temp_.out()) / a_.station / "s";
  {
    RecorderProcess recorder(temp_.root(), Args({"--what", "captures"}));
    ASSERT_TRUE(a_.captures->WaitForReaders(1, kTimeout)) << recorder.Stderr();
    // All samples reach the recorder's reader (history 8) before the kill,
    // so no write waits for acknowledgements from a dead reader.
    for (int view = 0; view < kViews; ++view) {
      ASSERT_TRUE(a_.Capture("s", view, images[view], images[view]));
    }
    ASSERT_TRUE(WaitFor([&] { return !ReadIndex(dir).empty(); }, kTimeout)) << recorder.Stderr();
  }  // ~RecorderProcess: SIGKILL
  // Every data file decodes to what was sent; every index line names a file
  // of that size; no temporary sits in the session folder.
  int files = 0;
  for (const auto& entry : fs::directory_iterator(dir)) {
    const std::string name = entry.path().filename();
    if (name == "index.jsonl") continue;
    ++files;
    std::smatch match;
    ASSERT_TRUE(std::regex_match(name, match, std::regex("view_00([0-9])_(left|right)\\.png")))
        << name;
    EXPECT_TRUE(BitExact(cv::imread(entry.path().string(), cv::IMREAD_UNCHANGED),
                         images[std::stoi(match[1].str())]))
        << name;
  }
  EXPECT_GE(files, 2);
  for (const nlohmann::json& line : ReadIndex(dir)) {
    const fs::path file = dir / line["file"].get<std::string>();
    ASSERT_TRUE(fs::exists(file)) << file;
    EXPECT_EQ(line["bytes"], fs::file_size(file));
  }
  // A new run clears the staging folder and counts exactly the whole files.
  RecorderProcess next(temp_.root(), Args({"--duration", "0.2"}), "next");
  EXPECT_EQ(next.Wait(), 0) << next.Stderr();
  EXPECT_NE(next.Stderr().find("(holds " + std::to_string(files) + " files,"), std::string::npos)
      << next.Stderr();
  EXPECT_FALSE(fs::exists(fs::path(temp_.out()) / ".staging"));
}

TEST_F(RecordOneStation, StopsAfterCountAndAfterDuration) {
  {
    RecorderProcess recorder(temp_.root(), Args({"--what", "clouds", "--count", "2"}));
    ASSERT_TRUE(a_.clouds->WaitForReaders(1, kTimeout)) << recorder.Stderr();
    const PointCloud cloud = RandomCloud(20, 16, false);
    ASSERT_TRUE(a_.Cloud("s", 0, cloud));
    ASSERT_TRUE(a_.Cloud("s", 1, cloud));
    EXPECT_EQ(recorder.Wait(), 0) << recorder.Stderr();
    EXPECT_NE(recorder.Stdout().find("(count_reached)"), std::string::npos) << recorder.Stdout();
    EXPECT_EQ(ReadIndex(fs::path(temp_.out()) / a_.station / "s").size(), 2u);
  }
  RecorderProcess recorder(temp_.root(), Args({"--duration", "0.5"}), "timed");
  EXPECT_EQ(recorder.Wait(), 0) << recorder.Stderr();
  EXPECT_NE(recorder.Stdout().find("--duration 0.5 s elapsed"), std::string::npos)
      << recorder.Stdout();
  // The earlier files are counted in the archive's totals.
  EXPECT_NE(recorder.Stdout().find(": 2 files,"), std::string::npos) << recorder.Stdout();
}

TEST_F(RecordOneStation, BagitWritesAVerifiableBagPerSessionAndRefusesAFullTarget) {
  const std::string session = "20260101-093000-box";
  const std::string bags = temp_.root() + "/bags";
  {
    RecorderProcess recorder(
        temp_.root(), Args({"--count", "2", "--bagit", bags, "--source-organization", "Museum B"}));
    ASSERT_TRUE(a_.captures->WaitForReaders(1, kTimeout)) << recorder.Stderr();
    ASSERT_TRUE(a_.clouds->WaitForReaders(1, kTimeout)) << recorder.Stderr();
    const cv::Mat left = RandomImage(CV_8UC3, 21), right = RandomImage(CV_8UC3, 22);
    ASSERT_TRUE(a_.Capture(session, 0, left, right));
    ASSERT_TRUE(a_.Cloud(session, -1, RandomCloud(50, 23, true)));
    ASSERT_EQ(recorder.Wait(), 0) << recorder.Stderr();
    EXPECT_NE(recorder.Stdout().find("bag '" + bags + "/" + a_.station + "/" + session + "'"),
              std::string::npos)
        << recorder.Stdout();
  }
  // Checked independently (tests/bagit_check.h): sha256sum -c inside the
  // bag and RFC 8493's structure rules; the payload is the archive's folder.
  const std::string bag = bags + "/" + a_.station + "/" + session;
  std::string out;
  EXPECT_EQ(testing::RunSha256sumCheck(bag, "manifest-sha256.txt", &out), 0) << out;
  EXPECT_EQ(testing::RunSha256sumCheck(bag, "tagmanifest-sha256.txt", &out), 0) << out;
  EXPECT_EQ(testing::BagStructureProblems(bag, "Museum B", session), std::vector<std::string>{});
  const fs::path archived = fs::path(temp_.out()) / a_.station / session;
  int files = 0;
  for (const auto& entry : fs::directory_iterator(archived)) {
    ++files;
    EXPECT_TRUE(ReadFile(entry.path()) ==
                ReadFile(bag + "/data/" + entry.path().filename().string()))
        << entry.path();
  }
  EXPECT_EQ(files, 4);  // two images, fused.ply, index.jsonl
  // A flipped payload byte: sha256sum -c fails, naming the file.
  {
    std::fstream f(bag + "/data/fused.ply", std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(-1, std::ios::end);
    f.put('\x7f');
  }
  EXPECT_EQ(testing::RunSha256sumCheck(bag, "manifest-sha256.txt", &out), 1) << out;
  EXPECT_NE(out.find("data/fused.ply: FAILED"), std::string::npos) << out;

  // The target is now not empty: refused at start, before recording.
  RecorderProcess again(temp_.root(), Args({"--bagit", bags, "--source-organization", "M"}),
                        "again");
  EXPECT_EQ(again.Wait(), 1) << again.Stderr();
  EXPECT_NE(again.Stderr().find("exists and is not empty"), std::string::npos) << again.Stderr();
  RecorderProcess no_org(temp_.root(), Args({"--bagit", temp_.root() + "/b2"}), "no_org");
  EXPECT_EQ(no_org.Wait(), 2) << no_org.Stderr();
  EXPECT_NE(no_org.Stderr().find("Source-Organization"), std::string::npos) << no_org.Stderr();
}

TEST_F(RecordOneStation, RefusesBadArgumentsAndASecondRecorderOnTheSameArchive) {
  RecorderProcess bad_size(temp_.root(), Args({"--max-bytes", "12X"}), "bad_size");
  EXPECT_EQ(bad_size.Wait(), 2);
  EXPECT_NE(bad_size.Stderr().find("--max-bytes"), std::string::npos) << bad_size.Stderr();
  RecorderProcess bad_station(temp_.root(), {"--station", "../x", "--out", temp_.out()},
                              "bad_station");
  EXPECT_EQ(bad_station.Wait(), 2);
  RecorderProcess bad_what(temp_.root(), Args({"--what", "clouds,meshes"}), "bad_what");
  EXPECT_EQ(bad_what.Wait(), 2);
  RecorderProcess nowhere(temp_.root(), {"--station", a_.station}, "nowhere");
  EXPECT_EQ(nowhere.Wait(), 2);
  EXPECT_NE(nowhere.Stderr().find("--out or --mcap is needed"), std::string::npos)
      << nowhere.Stderr();
  RecorderProcess bad_mcap(temp_.root(),
                           {"--station", a_.station, "--mcap", temp_.root() + "/no/such/x.mcap"},
                           "bad_mcap");
  EXPECT_EQ(bad_mcap.Wait(), 1);
  EXPECT_NE(bad_mcap.Stderr().find("cannot create '" + temp_.root() + "/no/such/x.mcap'"),
            std::string::npos)
      << bad_mcap.Stderr();

  RecorderProcess first(temp_.root(), Args({}), "first");
  ASSERT_TRUE(first.WaitUntilRecording()) << first.Stderr();
  RecorderProcess second(temp_.root(), Args({}), "second");
  EXPECT_EQ(second.Wait(), 1);
  EXPECT_NE(second.Stderr().find("in use by another craftscan-record"), std::string::npos)
      << second.Stderr();
  EXPECT_EQ(first.Terminate(), 0) << first.Stderr();
}

}  // namespace
}  // namespace craftscan::dds
