// `craftscan-bench dds`: latency of craftscan's large DDS samples between two
// processes over loopback, with the shipped Cyclone configuration.
//
//   craftscan-bench dds [--repeat N] [--warmup W] [--points P] [--width W --height H]
//                       [--gap-ms G] [--config FILE] [--domain D] [--json FILE]
//
// The bench starts a second process (itself, with the hidden --peer flag) in
// a random domain (or --domain), both on loopback only (--config, default the
// source tree's systemd/cyclonedds.xml, plus LoopbackOnlyConfigXml). For each
// case it writes one sample, the peer takes it (deserialised into its
// Sample) and answers with a small JobProgress carrying the time it had the
// sample (steady clock: CLOCK_MONOTONIC, shared by both processes); the next
// sample is written only after that answer (and --gap-ms more: a station
// sends a capture or cloud every few seconds, not back to back). Cases:
//   capture_mono8    StereoCapture, two W×H mono8 images
//   capture_bgr8     StereoCapture, two W×H bgr8 images
//   cloud            PointCloud, P points with colours (xyz + rgb)
//   cloud_normals    PointCloud, P points with colours and normals
//   pointcloud2      ROS PointCloud2 of the cloud with colours (conversion included)
// Reported per case over N repeats (after W unrecorded warm-up samples):
//   latency_ms   median and p90: from before the Write call (and, for
//                pointcloud2, the conversion) to the peer holding the sample
//   write_ms     median time in the Write call (serialisation + sending)
//   roundtrip_ms median until the writer has the peer's answer
//   mb_per_s     sample size / median latency
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <memory>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "command.h"
#include "craftscan/dds/convert.h"
#include "craftscan/dds/endpoint.h"
#include "craftscan/dds/participant.h"
#include "craftscan/dds/topics.h"

extern char** environ;

namespace craftscan::bench {
namespace {

namespace fs = std::filesystem;
using namespace craftscan::dds;
using Clock = std::chrono::steady_clock;

constexpr std::chrono::milliseconds kTimeout{30000};  // per sample or answer; the machine is shared

int64_t NowNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(Clock::now().time_since_epoch())
      .count();
}

double Ms(int64_t ns) { return static_cast<double>(ns) * 1e-6; }

// Linear-interpolated quantile q (0…1) of `values` (sorted here).
double Percentile(std::vector<double> values, double q) {
  if (values.empty()) return NAN;
  std::sort(values.begin(), values.end());
  const double position = q * static_cast<double>(values.size() - 1);
  const std::size_t below = static_cast<std::size_t>(position);
  const std::size_t above = std::min(below + 1, values.size() - 1);
  return values[below] + (position - static_cast<double>(below)) * (values[above] - values[below]);
}

struct CaseResult {
  std::string name;
  std::size_t bytes = 0;  // payload (pixels or point arrays)
  std::vector<double> latency_ms, write_ms, roundtrip_ms;
};

class DdsCommand : public BenchCommand {
 public:
  CLI::App* Register(CLI::App* app) override {
    CLI::App* sub = app->add_subcommand(
        "dds",
        "Latency of stereo captures and point clouds between two processes over "
        "loopback DDS");
    sub->add_option("--repeat", repeat_, "Samples measured per case")
        ->check(CLI::Range(1, 10000))
        ->capture_default_str();
    sub->add_option("--warmup", warmup_, "Unmeasured samples before each case")
        ->check(CLI::Range(0, 100))
        ->capture_default_str();
    sub->add_option("--points", points_, "Points per cloud")
        ->check(CLI::Range(1, 50'000'000))
        ->capture_default_str();
    sub->add_option("--width", width_, "Capture width, px")
        ->check(CLI::Range(1, 20000))
        ->capture_default_str();
    sub->add_option("--height", height_, "Capture height, px")
        ->check(CLI::Range(1, 20000))
        ->capture_default_str();
    sub->add_option("--gap-ms", gap_ms_,
                    "Pause between an answer and the next sample (0: back to back)")
        ->check(CLI::Range(0, 10000))
        ->capture_default_str();
    sub->add_option("--config", config_path_, "Cyclone DDS configuration file")
        ->capture_default_str();
    sub->add_option("--domain", domain_, "DDS domain id (default: random 1..230)")
        ->check(CLI::Range(0, static_cast<int>(kMaxDomainId)));
    sub->add_option("--json", json_path_, "Write the results as JSON to this file");
    // The second process: the bench runs itself with these.
    sub->add_flag("--peer", peer_)->group("");
    sub->add_option("--station", station_)->group("");
    return sub;
  }

  int Run() override {
    std::error_code ec;
    if (!fs::is_regular_file(config_path_, ec)) {
      return DataError("--config: file '" + config_path_ + "' does not exist");
    }
    if (!json_path_.empty()) {
      const fs::path parent = fs::path(json_path_).parent_path();
      if (!parent.empty() && !fs::is_directory(parent, ec)) {
        return DataError("--json: folder '" + parent.string() + "' does not exist");
      }
    }
    if (domain_ < 0) domain_ = 1 + static_cast<int>(std::random_device{}() % kMaxDomainId);
    if (peer_) return RunPeer();
    return RunBench();
  }

 private:
  static int DataError(const std::string& message) {
    std::cerr << "craftscan-bench dds: " << message << "\n";
    return kExitDataError;
  }
  // DataError for the bool-returning steps.
  static bool Failed(const std::string& message) {
    DataError(message);
    return false;
  }

  std::shared_ptr<Participant> CreateParticipant(std::string* error) const {
    ParticipantOptions options;
    options.domain_id = static_cast<uint32_t>(domain_);
    options.config =
        ConfigFileUri(fs::absolute(config_path_).string()) + "," + LoopbackOnlyConfigXml();
    return Participant::Create(options, error);
  }

  int SamplesPerCase() const { return warmup_ + repeat_; }

  // --- The peer process ---------------------------------------------------

  // Takes SamplesPerCase() samples of one topic; answers each on the
  // progress topic with current = index (−1 if the sample is malformed) and
  // stamp_ns = when it held the sample.
  template <typename Msg, typename Check>
  bool Answer(const std::shared_ptr<Participant>& participant, const TopicSpec<Msg>& topic,
              Writer<msg::JobProgress>* answers, const char* stage, Check check) {
    std::string error;
    auto reader = Reader<Msg>::Create(participant, topic, &error);
    if (!reader) return Failed("peer: " + error);
    Sample<Msg> sample;
    Outgoing<msg::JobProgress> answer;
    answer.msg().job_id = answer.Keep("bench");
    answer.msg().stage = answer.Keep(stage);
    for (int i = 0; i < SamplesPerCase(); ++i) {
      if (reader->Take(kTimeout, &sample, &error) != TakeStatus::kOk) {
        return Failed("peer: no " + std::string(stage) + " sample " + std::to_string(i) +
                      (error.empty() ? "" : ": " + error));
      }
      answer.msg().stamp_ns = NowNs();
      answer.msg().current = check(*sample) ? i : -1;
      if (!answers->Write(answer.msg(), &error)) return Failed("peer: " + error);
    }
    return true;
  }

  int RunPeer() {
    std::string error;
    auto participant = CreateParticipant(&error);
    if (!participant) return DataError("peer: " + error);
    auto answers = Writer<msg::JobProgress>::Create(participant, ProgressTopic(station_), &error);
    if (!answers) return DataError("peer: " + error);
    if (!answers->WaitForReaders(1, kTimeout)) return DataError("peer: the bench is not listening");
    const std::size_t pixels = static_cast<std::size_t>(width_) * height_;
    const auto capture_ok = [&](const msg::StereoCapture& m, std::size_t channels) {
      return m.left_data._length == pixels * channels && m.right_data._length == pixels * channels;
    };
    const std::size_t n = static_cast<std::size_t>(points_);
    const bool ok =
        Answer(participant, CaptureTopic(station_ + "_mono8"), answers.get(), "capture_mono8",
               [&](const msg::StereoCapture& m) { return capture_ok(m, 1); }) &&
        Answer(participant, CaptureTopic(station_ + "_bgr8"), answers.get(), "capture_bgr8",
               [&](const msg::StereoCapture& m) { return capture_ok(m, 3); }) &&
        Answer(participant, CloudTopic(station_), answers.get(), "cloud",
               [&](const msg::PointCloud& m) {
                 return m.xyz._length == 3 * n && m.rgb._length == 3 * n;
               }) &&
        Answer(participant, CloudTopic(station_ + "_normals"), answers.get(), "cloud_normals",
               [&](const msg::PointCloud& m) {
                 return m.xyz._length == 3 * n && m.normals._length == 3 * n;
               }) &&
        Answer(participant, RosCloudTopic(station_), answers.get(), "pointcloud2",
               [&](const ros::PointCloud2& m) { return m.width == n && m.point_step == 16; });
    if (!ok) return kExitDataError;
    if (!answers->WaitForAcks(kTimeout, &error)) return DataError("peer: " + error);
    return kExitOk;
  }

  // --- The measuring process ------------------------------------------------

  // Starts the peer; returns its pid or −1.
  pid_t StartPeer() const {
    const std::vector<std::string> args = {"/proc/self/exe",
                                           "dds",
                                           "--peer",
                                           "--station",
                                           station_,
                                           "--domain",
                                           std::to_string(domain_),
                                           "--config",
                                           config_path_,
                                           "--repeat",
                                           std::to_string(repeat_),
                                           "--warmup",
                                           std::to_string(warmup_),
                                           "--points",
                                           std::to_string(points_),
                                           "--width",
                                           std::to_string(width_),
                                           "--height",
                                           std::to_string(height_)};
    std::vector<char*> argv;
    for (const std::string& arg : args) argv.push_back(const_cast<char*>(arg.c_str()));
    argv.push_back(nullptr);
    pid_t pid = -1;
    if (posix_spawn(&pid, "/proc/self/exe", nullptr, nullptr, argv.data(), environ) != 0) return -1;
    return pid;
  }

  // Writes SamplesPerCase() samples made by make(i) (which returns the message
  // to write; it may convert, and its time counts) and records the
  // measured ones.
  template <typename Msg, typename Make>
  bool Measure(const std::shared_ptr<Participant>& participant, const TopicSpec<Msg>& topic,
               Reader<msg::JobProgress>* answers, Make make, CaseResult* result) {
    std::string error;
    auto writer = Writer<Msg>::Create(participant, topic, &error);
    if (!writer) return Failed(error);
    if (!writer->WaitForReaders(1, kTimeout)) {
      return Failed("the peer did not subscribe to " + topic.name);
    }
    Sample<msg::JobProgress> answer;
    for (int i = 0; i < SamplesPerCase(); ++i) {
      if (gap_ms_ > 0) std::this_thread::sleep_for(std::chrono::milliseconds(gap_ms_));
      const int64_t start_ns = NowNs();
      const Msg& message = make(i);
      const int64_t write_start_ns = NowNs();
      if (!writer->Write(message, &error)) return Failed(error);
      const int64_t write_end_ns = NowNs();
      if (answers->Take(kTimeout, &answer, &error) != TakeStatus::kOk) {
        return Failed("no answer from the peer for " + result->name + " sample " +
                      std::to_string(i) + (error.empty() ? "" : ": " + error));
      }
      const int64_t end_ns = NowNs();
      if (answer->current != i) {
        return Failed("the peer got a malformed " + result->name + " sample " + std::to_string(i));
      }
      if (i < warmup_) continue;
      result->latency_ms.push_back(Ms(answer->stamp_ns - start_ns));
      result->write_ms.push_back(Ms(write_end_ns - write_start_ns));
      result->roundtrip_ms.push_back(Ms(end_ns - start_ns));
    }
    return true;
  }

  bool MeasureAll(const std::shared_ptr<Participant>& participant,
                  Reader<msg::JobProgress>* answers, std::vector<CaseResult>* results) {
    std::string error;
    cv::RNG rng(42);
    for (int channels : {1, 3}) {
      cv::Mat left(height_, width_, CV_8UC(channels)), right(height_, width_, CV_8UC(channels));
      rng.fill(left, cv::RNG::UNIFORM, 0, 256);
      rng.fill(right, cv::RNG::UNIFORM, 0, 256);
      StereoCaptureMeta meta;
      meta.session = "bench";
      Outgoing<msg::StereoCapture> capture;
      if (!MakeStereoCapture(left, right, meta, &capture, &error)) return Failed(error);
      CaseResult result;
      result.name = channels == 1 ? "capture_mono8" : "capture_bgr8";
      result.bytes = 2 * left.total() * left.elemSize();
      const auto make = [&](int i) -> const msg::StereoCapture& {
        capture.msg().view_index = i;
        return capture.msg();
      };
      if (!Measure(participant, CaptureTopic(station_ + (channels == 1 ? "_mono8" : "_bgr8")),
                   answers, make, &result)) {
        return false;
      }
      results->push_back(std::move(result));
    }

    PointCloud cloud;
    cloud.points_mm.resize(points_);
    cloud.colors_rgb.resize(points_);
    rng.fill(cv::Mat(points_, 3, CV_32F, cloud.points_mm.data()), cv::RNG::UNIFORM, -200, 200);
    rng.fill(cv::Mat(points_, 3, CV_8U, cloud.colors_rgb.data()), cv::RNG::UNIFORM, 0, 256);
    for (bool normals : {false, true}) {
      if (normals) cloud.normals.assign(points_, cv::Vec3f(0, 0, 1));
      CloudMeta meta;
      meta.session = "bench";
      Outgoing<msg::PointCloud> message;
      if (!MakeCloud(cloud, meta, &message, &error)) return Failed(error);
      CaseResult result;
      result.name = normals ? "cloud_normals" : "cloud";
      result.bytes = cloud.size() * (normals ? 27 : 15);
      const auto make = [&](int i) -> const msg::PointCloud& {
        message.msg().stamp_ns = i;
        return message.msg();
      };
      if (!Measure(participant, CloudTopic(station_ + (normals ? "_normals" : "")), answers, make,
                   &result)) {
        return false;
      }
      results->push_back(std::move(result));
    }

    cloud.normals.clear();
    Outgoing<ros::PointCloud2> ros_cloud;
    CaseResult result;
    result.name = "pointcloud2";
    result.bytes = cloud.size() * 16;
    bool converted = true;
    const auto make = [&](int i) -> const ros::PointCloud2& {
      converted = converted && MakePointCloud2(cloud, i, "world", &ros_cloud, &error);
      return ros_cloud.msg();
    };
    if (!Measure(participant, RosCloudTopic(station_), answers, make, &result)) return false;
    if (!converted) return Failed(error);
    results->push_back(std::move(result));
    return true;
  }

  int RunBench() {
    station_ = "bench" + std::to_string(getpid());
    std::string error;
    auto participant = CreateParticipant(&error);
    if (!participant) return DataError(error);
    auto answers = Reader<msg::JobProgress>::Create(participant, ProgressTopic(station_), &error);
    if (!answers) return DataError(error);
    const pid_t peer = StartPeer();
    if (peer < 0) return DataError("cannot start the peer process");

    std::vector<CaseResult> results;
    const bool ok = MeasureAll(participant, answers.get(), &results);
    int status = 0;
    if (!ok) kill(peer, SIGKILL);
    const auto deadline = Clock::now() + kTimeout;
    while (waitpid(peer, &status, WNOHANG) == 0) {
      if (Clock::now() > deadline) {
        kill(peer, SIGKILL);
        waitpid(peer, &status, 0);
        break;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    if (!ok) return kExitDataError;
    if (!WIFEXITED(status) || WEXITSTATUS(status) != 0) return DataError("the peer process failed");

    Print(results);
    return json_path_.empty() ? kExitOk : WriteJson(results);
  }

  void Print(const std::vector<CaseResult>& results) const {
    std::printf(
        "DDS over loopback between two processes, domain %d, %d samples per case "
        "(+%d warm-up), %d ms apart, config %s\n",
        domain_, repeat_, warmup_, gap_ms_, config_path_.c_str());
    std::printf("%-14s %9s %12s %12s %10s %13s %9s\n", "case", "MB", "latency_med", "latency_p90",
                "write_med", "roundtrip_med", "MB/s");
    for (const CaseResult& r : results) {
      const double median = Percentile(r.latency_ms, 0.5);
      std::printf("%-14s %9.2f %10.2fms %10.2fms %8.2fms %11.2fms %9.0f\n", r.name.c_str(),
                  r.bytes / 1e6, median, Percentile(r.latency_ms, 0.9), Percentile(r.write_ms, 0.5),
                  Percentile(r.roundtrip_ms, 0.5), r.bytes / 1e6 / (median / 1e3));
    }
  }

  int WriteJson(const std::vector<CaseResult>& results) const {
    nlohmann::ordered_json root;
    root["bench"] = "dds";
    root["transport"] = "udp loopback, two processes";
    root["config"] = config_path_;
    root["repeat"] = repeat_;
    root["warmup"] = warmup_;
    root["points"] = points_;
    root["width"] = width_;
    root["height"] = height_;
    root["gap_ms"] = gap_ms_;
    nlohmann::ordered_json cases = nlohmann::ordered_json::array();
    for (const CaseResult& r : results) {
      const double median = Percentile(r.latency_ms, 0.5);
      nlohmann::ordered_json c;
      c["case"] = r.name;
      c["bytes"] = r.bytes;
      c["latency_median_ms"] = median;
      c["latency_p90_ms"] = Percentile(r.latency_ms, 0.9);
      c["write_median_ms"] = Percentile(r.write_ms, 0.5);
      c["roundtrip_median_ms"] = Percentile(r.roundtrip_ms, 0.5);
      c["mb_per_s"] = r.bytes / 1e6 / (median / 1e3);
      cases.push_back(c);
    }
    root["cases"] = cases;
    std::ofstream out(json_path_, std::ios::trunc);
    out << root.dump(2) << "\n";
    out.close();
    if (!out) return DataError("cannot write --json file '" + json_path_ + "'");
    return kExitOk;
  }

  int repeat_ = 20;
  int warmup_ = 2;
  int points_ = 1'000'000;
  int width_ = 1280;
  int height_ = 1024;
  int gap_ms_ = 0;
  std::string config_path_ = CRAFTSCAN_CYCLONEDDS_XML;
  int domain_ = -1;
  std::string json_path_;
  bool peer_ = false;
  std::string station_;
};

}  // namespace

std::unique_ptr<BenchCommand> MakeDdsCommand() { return std::make_unique<DdsCommand>(); }

}  // namespace craftscan::bench
