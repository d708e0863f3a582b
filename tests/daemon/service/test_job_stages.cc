// The scan's stages and the JobEngine without DDS: a fake JobSink and the
// real sim devices (plugin craftscan-driver-sim, 320x256 images) through a
// DeviceManager, a SessionStore in a temporary folder. Cancel at each stage,
// a camera lost mid-scan, a full disk, and resume after each; "done" and
// "failed" published only once the session is closed.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <sys/statvfs.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <condition_variable>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "../sessions/status_util.h"
#include "craftscan/daemon/config.h"
#include "craftscan/daemon/devices.h"
#include "craftscan/daemon/jobs.h"
#include "craftscan/daemon/report.h"
#include "craftscan/daemon/session_store.h"
#include "craftscan/daemon/stages.h"
#include "craftscan/sim/driver_options.h"
#include "craftscan/sim/station.h"
#include "private_mount.h"
#include "test_paths.h"

using craftscan::testing::Ok;
using craftscan::testing::StatusInto;

namespace craftscan::daemon {
namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;

constexpr const char* kImageSize = "320x256";
constexpr int kViews = 4;

// Threads of the sim renderer and the pipeline: 2, or CRAFTSCAN_TEST_THREADS
// (1 under TSan; see daemon_fixture.h).
int TestThreads() {
  const char* value = std::getenv("CRAFTSCAN_TEST_THREADS");
  const int n = value != nullptr ? std::atoi(value) : 0;
  return n >= 1 ? n : 2;
}

bool Contains(const std::string& text, const std::string& part) {
  return text.find(part) != std::string::npos;
}

bool IsTerminal(const std::string& stage) {
  return stage == "done" || stage == "failed" || stage == "cancelled";
}

// Records what the jobs publish. Thread-safe. The hooks run on the job's
// threads, inside the call, before it is recorded as seen.
class FakeSink : public JobSink {
 public:
  struct Event {
    std::string job, stage;
    int current = 0, total = 0;
    std::string message;
  };
  std::function<void(const Event&)> on_progress;  // every Progress
  std::function<void(int view)> on_capture;       // after a capture is acknowledged

  void Progress(const std::string& job, const std::string& stage, int current, int total,
                const std::string& message) override {
    const Event event{job, stage, current, total, message};
    if (on_progress) on_progress(event);
    std::lock_guard lock(mutex_);
    events_.push_back(event);
    if (IsTerminal(stage)) {
      ++ends_;
      changed_.notify_all();
    }
  }
  void Capture(const std::string&, int view, double, const drivers::StereoFrame&) override {
    if (on_capture) on_capture(view);
    std::lock_guard lock(mutex_);
    captures_.push_back(view);
  }
  void Disparity(const std::string&, int view, const cv::Mat& disparity, double focal_px,
                 double baseline_mm, int, int) override {
    EXPECT_FALSE(disparity.empty());
    EXPECT_GT(focal_px, 0);
    EXPECT_GT(baseline_mm, 0);
    std::lock_guard lock(mutex_);
    disparities_.push_back(view);
  }
  void Cloud(const std::string&, int view, const PointCloud& cloud, const cv::Matx44d&) override {
    EXPECT_GT(cloud.size(), 0u) << "view " << view;
    std::lock_guard lock(mutex_);
    clouds_.push_back(view);
  }
  void Preview(const PreviewFrame& frame) override {
    std::lock_guard lock(mutex_);
    overlays_.push_back(nlohmann::json::parse(frame.overlay, nullptr, false));
  }
  std::vector<nlohmann::json> overlays() const {
    std::lock_guard lock(mutex_);
    return overlays_;
  }

  // Waits until `n` jobs have published their end.
  bool WaitEnds(int n, std::chrono::seconds timeout = 300s) {
    std::unique_lock lock(mutex_);
    return changed_.wait_for(lock, timeout, [&] { return ends_ >= n; });
  }
  std::vector<int> captures() const { return Sorted(captures_); }
  std::vector<int> disparities() const { return Sorted(disparities_); }
  std::vector<int> clouds() const { return Sorted(clouds_); }
  std::vector<Event> events() const {
    std::lock_guard lock(mutex_);
    return events_;
  }
  // Forgets what was published (not the count of ends) and the hooks.
  void Clear() {
    std::lock_guard lock(mutex_);
    events_.clear();
    captures_.clear();
    disparities_.clear();
    clouds_.clear();
    on_progress = nullptr;
    on_capture = nullptr;
  }

 private:
  std::vector<int> Sorted(const std::vector<int>& v) const {
    std::lock_guard lock(mutex_);
    std::vector<int> out = v;
    std::sort(out.begin(), out.end());
    return out;
  }
  mutable std::mutex mutex_;
  std::vector<nlohmann::json> overlays_;
  std::condition_variable changed_;
  std::vector<Event> events_;
  std::vector<int> captures_, disparities_, clouds_;
  int ends_ = 0;
};

std::vector<int> Range(int from, int to) {
  std::vector<int> out;
  for (int i = from; i < to; ++i) out.push_back(i);
  return out;
}

// The engine's world: sim devices, a store, the fake sink, the engine, and
// the check made when a session job publishes its end: the session opens.
class Station {
 public:
  // `data_dir` must exist. `extra`: more sim driver keys (fault knobs).
  explicit Station(std::string data_dir, drivers::DriverConfig extra = {})
      : data_dir_(std::move(data_dir)), extra_(std::move(extra)) {}
  ~Station() {
    if (engine_) engine_->Shutdown();
  }

  // Writes the sim rig's exact calibration as the current one and opens
  // everything. "" or what failed.
  std::string Open() {
    std::string error;
    sim::SimDriverOptions sim_options;
    const std::string image_size =
        extra_.count("image_size") ? extra_.at("image_size") : std::string(kImageSize);
    if (!sim::SimDriverOptionsFromConfig({{"image_size", image_size}}, &sim_options, &error))
      return error;
    auto rig = sim::SimStation::Create(sim::SimRigOptions(sim_options), &error);
    if (!rig) return error;
    truth_ = rig->calibration();
    fs::create_directories(data_dir_ + "/calibration");
    if (!SaveCalibration(data_dir_ + "/calibration/current.yaml", rig->calibration(), &error))
      return error;

    DeviceSetup setup;
    setup.plugin_path = ::craftscan::testing::PluginDir();
    drivers::DriverConfig config = {{"image_size", kImageSize},
                                    {"threads", std::to_string(TestThreads())}};
    for (const auto& [key, value] : extra_) config[key] = value;
    setup.camera = {"sim", config};
    setup.turntable = {"sim", config};
    devices_ = std::make_unique<DeviceManager>(setup, Logger(), nullptr);
    if (!devices_->Open(&error)) return "devices: " + error;
    store_ = SessionStore::Open(data_dir_, StatusInto(&error));
    if (!store_) return "store: " + error;

    JobEngineOptions options;
    options.data_dir = data_dir_;
    options.default_views = kViews;
    options.default_step_deg = 360.0 / kViews;
    options.settle = 0ms;
    options.threads = TestThreads();
    options.calibration_guided = guided;
    PipelineSettings pipeline;  // the carved box with a margin, as daemon_fixture.h
    pipeline.threads = TestThreads();
    pipeline.volume.radius_mm = 65;
    pipeline.volume.max_height_mm = 70;
    options.view.volume = pipeline.volume;
    options.view.min_texture_std = pipeline.min_texture_std;
    options.scan = ReconstructionOptions(pipeline);
    options.board =
        sim::DefaultSimBoard(sim::SimSceneType::kHeldBoard, BoardSpec::Type::kChessboard);
    options.turntable_board =
        sim::DefaultSimBoard(sim::SimSceneType::kPlatterBoard, BoardSpec::Type::kChessboard);
    const ReportWriter report = [this](const ReportInputs& inputs, ReportFiles* files,
                                       std::string*) {
      ++reports_;
      EXPECT_EQ(inputs.disparities.size(), static_cast<std::size_t>(kViews));
      files->files.push_back({"report.html", "<html>" + inputs.session_id + "</html>"});
      return true;
    };
    engine_ = std::make_unique<JobEngine>(options, devices_.get(), store_.get(), &sink_, Logger(),
                                          report);
    if (!engine_->LoadCurrentCalibration(&error)) return "calibration: " + error;
    return {};
  }

  bool guided = false;  // JobEngineOptions::calibration_guided, set before Open
  const StereoCalibration& truth() const { return truth_; }

  // Waits for the job started last to end (its final Progress included).
  JobInfo Wait() {
    ++jobs_;
    EXPECT_TRUE(sink_.WaitEnds(jobs_)) << Log();
    return engine_->Current();
  }
  // Starts a scan of kViews views and arms the end-of-job check.
  JobInfo Scan() {
    ArmEndCheck();
    ScanRequest request;
    request.object = "box";
    request.views = kViews;
    JobInfo info;
    std::string error;
    EXPECT_TRUE(engine_->StartScan(request, &info, &error)) << error;
    return info;
  }
  JobInfo Resume(const std::string& session) {
    ArmEndCheck();
    JobInfo info;
    std::string error;
    EXPECT_TRUE(engine_->StartResume(session, &info, &error)) << error;
    return info;
  }

  // Waits for a scan started with Scan() that is to be cancelled; checks it
  // ended cancelled, its session interrupted and closed. Its session id.
  std::string ExpectCancelled(const JobInfo& started) {
    const JobInfo job = Wait();
    EXPECT_EQ(job.state, JobState::kCancelled) << job.message << "\n" << Log();
    EXPECT_EQ(job.message, "session " + started.session + " interrupted: cancelled");
    ExpectOpenedAtEnd();
    EXPECT_EQ(ManifestOf(started.session).state, SessionState::kInterrupted);
    return started.session;
  }
  // From a hook on the job's thread.
  void Cancel() { EXPECT_TRUE(engine_->Cancel(nullptr)); }

  // The session's manifest, read by opening it (which also proves that no
  // job holds it).
  Manifest ManifestOf(const std::string& id) {
    std::string error;
    std::unique_ptr<Session> session = store_->OpenSession(id, StatusInto(&error));
    EXPECT_TRUE(session) << error;
    return session ? session->manifest() : Manifest{};
  }
  std::vector<int> ViewsWithCloud(const std::string& id) {
    std::vector<int> out;
    for (const auto& [view, record] : ManifestOf(id).views) {
      if (record.HasCloud()) out.push_back(view);
    }
    return out;
  }

  // Resumes `id` and checks it completes: done, every view captured once
  // overall (only the views not durable before are captured now), the
  // fused cloud published, the report written.
  void ExpectResumeCompletes(const std::string& id) {
    const std::vector<int> durable = ManifestOf(id).CapturedViews();
    std::vector<int> missing;
    for (int k = 0; k < kViews; ++k) {
      if (std::find(durable.begin(), durable.end(), k) == durable.end()) missing.push_back(k);
    }
    sink_.Clear();
    const int reports_before = reports_;
    Resume(id);
    const JobInfo job = Wait();
    EXPECT_EQ(job.state, JobState::kDone) << job.message << "\n" << Log();
    EXPECT_EQ(sink_.captures(), missing) << "resume recaptured a durable view";
    const std::vector<int> clouds = sink_.clouds();
    EXPECT_EQ(clouds.front(), -1) << "no fused cloud published";
    EXPECT_EQ(std::vector<int>(clouds.begin() + 1, clouds.end()), Range(0, kViews));
    EXPECT_EQ(reports_, reports_before + 1);
    const Manifest manifest = ManifestOf(id);
    EXPECT_EQ(manifest.state, SessionState::kDone);
    EXPECT_EQ(manifest.CapturedViews(), Range(0, kViews));
    EXPECT_TRUE(manifest.outputs.count("fused.ply"));
    EXPECT_TRUE(manifest.outputs.count("report.html"));
    ExpectOpenedAtEnd();
  }

  // The session could be opened from inside the final Progress.
  void ExpectOpenedAtEnd() {
    std::lock_guard lock(mutex_);
    EXPECT_TRUE(opened_at_end_) << "the session was still held when its end was published: "
                                << open_error_;
  }

  std::string Log() const {
    std::lock_guard lock(mutex_);
    return log_;
  }

  FakeSink& sink() { return sink_; }
  JobEngine& engine() { return *engine_; }
  DeviceManager& devices() { return *devices_; }
  SessionStore& store() { return *store_; }
  const std::string& data_dir() const { return data_dir_; }
  int reports() const { return reports_; }

 private:
  LogFn Logger() {
    return [this](drivers::LogLevel, std::string_view line) {
      std::lock_guard lock(mutex_);
      log_.append(line).append("\n");
    };
  }
  // On the final Progress of the next job: opens its session.
  void ArmEndCheck() {
    {
      std::lock_guard lock(mutex_);
      opened_at_end_ = false;
      open_error_ = "no end published";
    }
    auto previous = sink_.on_progress;
    sink_.on_progress = [this, previous](const FakeSink::Event& event) {
      if (previous) previous(event);
      if (!IsTerminal(event.stage)) return;
      std::string error;
      const bool opened =
          store_->OpenSession(engine_->Current().session, StatusInto(&error)) != nullptr;
      std::lock_guard lock(mutex_);
      opened_at_end_ = opened;
      open_error_ = error;
    };
  }

  std::string data_dir_;
  drivers::DriverConfig extra_;
  StereoCalibration truth_;
  FakeSink sink_;
  std::unique_ptr<DeviceManager> devices_;
  std::unique_ptr<SessionStore> store_;
  std::unique_ptr<JobEngine> engine_;
  std::atomic<int> reports_{0};
  int jobs_ = 0;
  mutable std::mutex mutex_;
  std::string log_;
  bool opened_at_end_ = false;
  std::string open_error_;
};

// A fresh folder per test, removed afterwards.
class JobStages : public ::testing::Test {
 protected:
  void SetUp() override {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    dir_ = fs::temp_directory_path() / ("craftscan_stages_" + std::string(info->name()) + "_" +
                                        std::to_string(std::random_device{}()));
    fs::create_directories(dir_ / "data");
  }
  void TearDown() override { fs::remove_all(dir_); }
  std::string data_dir() const { return (dir_ / "data").string(); }

  fs::path dir_;
};

#define OPEN_STATION(station)               \
  do {                                      \
    const std::string why = station.Open(); \
    ASSERT_EQ(why, "");                     \
  } while (0)

TEST_F(JobStages, ScanIsDoneWithEveryViewAndPublishesDoneOnlyAfterTheSessionIsClosed) {
  Station station(data_dir());
  OPEN_STATION(station);
  const JobInfo started = station.Scan();
  const JobInfo job = station.Wait();
  ASSERT_EQ(job.state, JobState::kDone) << job.message << "\n" << station.Log();
  EXPECT_EQ(job.id, started.id);
  EXPECT_TRUE(Contains(job.message, "session " + started.session + ": 4 views, ")) << job.message;
  EXPECT_EQ(job.result.value("views", 0), kViews);
  EXPECT_GT(job.result.value("fused_points", 0), 1000);
  station.ExpectOpenedAtEnd();
  FakeSink& sink = station.sink();
  EXPECT_EQ(sink.captures(), Range(0, kViews));
  EXPECT_EQ(sink.disparities(), Range(0, kViews));
  EXPECT_EQ(sink.clouds(), Range(-1, kViews));
  EXPECT_EQ(station.reports(), 1);
  // Progress in stage order, the end last and once.
  const std::vector<FakeSink::Event> events = sink.events();
  ASSERT_FALSE(events.empty());
  EXPECT_EQ(events.back().stage, "done");
  EXPECT_EQ(std::count_if(events.begin(), events.end(),
                          [](const FakeSink::Event& e) { return IsTerminal(e.stage); }),
            1);
  const auto first = [&](const std::string& stage) {
    return std::find_if(events.begin(), events.end(),
                        [&](const FakeSink::Event& e) { return e.stage == stage; }) -
           events.begin();
  };
  EXPECT_LT(first("capture"), first("match"));
  EXPECT_LT(first("match"), first("register"));
  EXPECT_LT(first("register"), first("write"));
  EXPECT_LT(first("write"), first("report"));
  const Manifest manifest = station.ManifestOf(started.session);
  EXPECT_EQ(manifest.state, SessionState::kDone);
  EXPECT_EQ(station.ViewsWithCloud(started.session), Range(0, kViews));
  for (const char* output :
       {"fused.ply", "mesh.ply", "mesh.obj", "mesh.glb", "report.json", "report.html"}) {
    EXPECT_TRUE(manifest.outputs.count(output)) << output;
  }
}

TEST_F(JobStages, OneViewCaptureIsDoneAndClosedBeforeItsEnd) {
  Station station(data_dir());
  OPEN_STATION(station);
  JobInfo info;
  std::string error;
  ASSERT_TRUE(station.engine().StartCapture("box", &info, &error)) << error;
  const JobInfo job = station.Wait();
  ASSERT_EQ(job.state, JobState::kDone) << job.message << "\n" << station.Log();
  EXPECT_EQ(job.message, "session " + info.session + ": 1 view captured");
  EXPECT_EQ(station.sink().captures(), std::vector<int>{0});
  EXPECT_EQ(station.sink().clouds(), std::vector<int>{0});
  EXPECT_EQ(station.reports(), 0);
  const Manifest manifest = station.ManifestOf(info.session);
  EXPECT_EQ(manifest.state, SessionState::kDone);
  EXPECT_EQ(station.ViewsWithCloud(info.session), std::vector<int>{0});
}

TEST_F(JobStages, CancelDuringCaptureInterruptsTheScanAndResumeCompletesIt) {
  Station station(data_dir());
  OPEN_STATION(station);
  station.sink().on_capture = [&](int view) {
    if (view == 1) station.Cancel();
  };
  const std::string id = station.ExpectCancelled(station.Scan());
  // The capture stage stops at its next view: both acknowledged views are
  // durable, no other was taken.
  EXPECT_EQ(station.sink().captures(), Range(0, 2));
  const Manifest manifest = station.ManifestOf(id);
  EXPECT_EQ(manifest.CapturedViews(), Range(0, 2));
  EXPECT_EQ(station.reports(), 0);
  station.ExpectResumeCompletes(id);
}

TEST_F(JobStages, CancelDuringMatchingInterruptsTheScanAndResumeCompletesIt) {
  Station station(data_dir());
  OPEN_STATION(station);
  station.sink().on_progress = [&](const FakeSink::Event& e) {
    if (e.stage == "match" && e.current == 1) station.Cancel();
  };
  const std::string id = station.ExpectCancelled(station.Scan());
  // The matcher finished view 0 and took no other.
  EXPECT_EQ(station.sink().disparities(), std::vector<int>{0});
  EXPECT_EQ(station.ViewsWithCloud(id), std::vector<int>{0});
  station.ExpectResumeCompletes(id);
}

TEST_F(JobStages, CancelDuringReconstructionInterruptsTheScanAndResumeCompletesIt) {
  Station station(data_dir());
  OPEN_STATION(station);
  station.sink().on_progress = [&](const FakeSink::Event& e) {
    if (e.stage == "register") station.Cancel();
  };
  const std::string id = station.ExpectCancelled(station.Scan());
  const Manifest manifest = station.ManifestOf(id);
  EXPECT_EQ(station.ViewsWithCloud(id), Range(0, kViews));
  EXPECT_TRUE(manifest.outputs.empty()) << "outputs written after the cancel";
  EXPECT_EQ(station.reports(), 0);
  // Resume captures and matches nothing again: every cloud is durable.
  station.ExpectResumeCompletes(id);
  EXPECT_TRUE(station.sink().disparities().empty());
}

// Waits until the job's turntable is on its way (past 0.5 degrees); false
// if the job ended first.
bool WaitMoving(Station& station) {
  for (auto deadline = std::chrono::steady_clock::now() + 60s;
       std::chrono::steady_clock::now() < deadline && station.engine().Busy();
       std::this_thread::sleep_for(5ms)) {
    const drivers::TurntableStatus s = station.devices().TurntableStatusNow();
    if (s.state == drivers::TurntableState::kMoving && s.angle_deg > 0.5) return true;
  }
  return false;
}

TEST_F(JobStages, CancelAbortsATurntableMoveInProgress) {
  // 90 degrees at 10 deg/s: a 9 s move, which the cancel must stop.
  Station station(data_dir(), {{"turntable_speed_deg_s", "10"}});
  OPEN_STATION(station);
  const JobInfo started = station.Scan();
  ASSERT_TRUE(WaitMoving(station)) << station.Log();
  std::string error;
  ASSERT_TRUE(station.engine().Cancel(&error)) << error;
  station.ExpectCancelled(started);
  const drivers::TurntableStatus s = station.devices().TurntableStatusNow();
  EXPECT_EQ(s.state, drivers::TurntableState::kReady);
  EXPECT_LT(s.angle_deg, 80) << "the move ran to its end";
  EXPECT_EQ(station.sink().captures(), std::vector<int>{0});
}

// Found by the refactor: calibrate-turntable did not mark its moves, so a
// cancel waited for the move to end (here 60 s) instead of aborting it.
TEST_F(JobStages, CancelAbortsACalibrateTurntableMove) {
  Station station(data_dir(), {{"turntable_speed_deg_s", "1"}});
  OPEN_STATION(station);
  const std::string calibration_before = station.engine().calibration_id();
  JobInfo info;
  std::string error;
  ASSERT_TRUE(station.engine().StartCalibrateTurntable(&info, &error)) << error;
  ASSERT_TRUE(WaitMoving(station)) << station.Log();
  const auto cancelled_at = std::chrono::steady_clock::now();
  ASSERT_TRUE(station.engine().Cancel(&error)) << error;
  const JobInfo job = station.Wait();
  EXPECT_LT(std::chrono::steady_clock::now() - cancelled_at, 30s) << "the move was not aborted";
  EXPECT_EQ(job.state, JobState::kCancelled) << job.message << "\n" << station.Log();
  EXPECT_EQ(job.message, "calibrate-turntable cancelled; nothing changed");
  EXPECT_EQ(station.engine().calibration_id(), calibration_before);
}

// Guided calibrate-turntable with the sim's technician laying the board
// (PlatterTechnicianAt): the platter waits while it is empty, while the
// board slides and while their hand adjusts it; it turns only once the board
// lies still, waits out their leaning in over the platter at one angle, and
// finds the axis as exactly as the unguided job (test_daemon: direction
// 0.2°, point 2 mm).
TEST_F(JobStages, GuidedCalibrateTurntableWaitsForTheBoardToLieStillAndFindsTheAxis) {
  Station station(data_dir(), {{"image_size", "640x512"},
                               {"technician", "1"},
                               {"technician_fps", "8"},
                               {"supersampling", "1"}});
  station.guided = true;
  OPEN_STATION(station);
  JobInfo info;
  std::string error;
  ASSERT_TRUE(station.engine().StartCalibrateTurntable(&info, &error)) << error;
  const JobInfo job = station.Wait();
  ASSERT_EQ(job.state, JobState::kDone) << job.message << "\n" << station.Log();
  std::printf("guided calibrate-turntable: %s\n", job.result.dump().c_str());
  EXPECT_EQ(job.result.value("steps_used", 0), 6);

  // What the person was told, in order: lay the board, let go, hands off,
  // then the turns, one of them waiting for the board to be seen again.
  std::vector<std::string> place, capture;
  for (const auto& e : station.sink().events()) {
    if (e.stage == "place") place.push_back(e.message);
    if (e.stage == "capture") capture.push_back(e.message);
  }
  auto index_of = [](const std::vector<std::string>& list, const std::string& part) {
    for (std::size_t i = 0; i < list.size(); ++i) {
      if (Contains(list[i], part)) return static_cast<int>(i);
    }
    return -1;
  };
  const int lay = index_of(place, "Lay the board"), let_go = index_of(place, "Let go"),
            hands_off = index_of(place, "Hands off"), turns = index_of(place, "platter turns");
  EXPECT_EQ(lay, 0) << ::testing::PrintToString(place);
  EXPECT_GT(let_go, lay) << ::testing::PrintToString(place);
  EXPECT_GT(hands_off, let_go) << ::testing::PrintToString(place);
  EXPECT_GT(turns, hands_off) << ::testing::PrintToString(place);
  int measured = 0;
  for (const std::string& m : capture) measured += Contains(m, "Board measured") ? 1 : 0;
  EXPECT_EQ(measured, 6) << ::testing::PrintToString(capture);
  EXPECT_GE(index_of(capture, "Looking for the board"), 0)
      << "the lean-in was not waited out: " << ::testing::PrintToString(capture);

  // The overlays the console draws: the turntable's, with corners while the
  // board lies, and the angles measured.
  int with_corners = 0;
  nlohmann::json last;
  for (const nlohmann::json& o : station.sink().overlays()) {
    ASSERT_TRUE(o.is_object());
    EXPECT_EQ(o.value("mode", ""), "turntable");
    if (o["board"].is_object() && o["board"]["left"].size() > 0) ++with_corners;
    last = o;
  }
  EXPECT_GT(with_corners, 3);
  EXPECT_EQ(last["steps"].size(), 6u) << last.dump();

  StereoCalibration measured_calibration;
  ASSERT_TRUE(
      LoadCalibration(data_dir() + "/calibration/current.yaml", &measured_calibration, &error))
      << error;
  const TurntableAxis& axis = measured_calibration.turntable;
  const TurntableAxis& truth = station.truth().turntable;
  ASSERT_TRUE(axis.valid);
  const double cos_angle = axis.direction_in_rig.dot(truth.direction_in_rig);
  EXPECT_LT(std::acos(std::min(1.0, cos_angle)) * 180 / CV_PI, 0.2);
  EXPECT_LT(cv::norm(axis.point_in_rig_mm - truth.point_in_rig_mm), 2.0);
}

TEST_F(JobStages, CameraLostMidScanInterruptsTheScanAndResumeCompletesIt) {
  // Two frames per connection, and no reconnect succeeds.
  Station station(data_dir(), {{"disconnect_after", "2"},
                               {"reconnect_failures", "1000"},
                               {"reconnect_attempts", "2"},
                               {"reconnect_delay_ms", "10"},
                               {"reconnect_max_delay_ms", "10"}});
  OPEN_STATION(station);
  const JobInfo started = station.Scan();
  const JobInfo job = station.Wait();
  ASSERT_EQ(job.state, JobState::kFailed) << job.message << "\n" << station.Log();
  EXPECT_TRUE(Contains(job.message, "session " + started.session +
                                        " interrupted: view 2: camera lost and not recovered"))
      << job.message;
  station.ExpectOpenedAtEnd();
  EXPECT_EQ(station.sink().captures(), Range(0, 2));
  const Manifest manifest = station.ManifestOf(started.session);
  EXPECT_EQ(manifest.state, SessionState::kInterrupted);
  EXPECT_EQ(manifest.CapturedViews(), Range(0, 2));
  EXPECT_TRUE(Contains(manifest.error, "camera lost")) << manifest.error;
  // A new connection has two frames again: the two views left.
  std::string error;
  ASSERT_TRUE(station.devices().Open(&error)) << error;
  station.ExpectResumeCompletes(started.session);
}

// Enters a private mount namespace and mounts a tmpfs of `size` on `dir`
// (in *tmpfs, unmounted when it goes); "" or why not (the test skips).
std::string OnPrivateTmpfs(const std::string& dir, const std::string& size,
                           std::optional<testing::ScopedTmpfs>* tmpfs) {
  std::string why = testing::EnterPrivateMountNamespace();
  if (!why.empty()) return why;
  tmpfs->emplace(dir, size);
  return (*tmpfs)->error();
}

// Fills the file system of `dir` (a tmpfs) up to the last block.
std::string FillDisk(const std::string& path) {
  struct statvfs vfs {};
  if (::statvfs(fs::path(path).parent_path().c_str(), &vfs) != 0) return std::strerror(errno);
  const int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0600);
  if (fd < 0) return std::strerror(errno);
  off_t bytes = static_cast<off_t>(vfs.f_bavail) * static_cast<off_t>(vfs.f_frsize);
  int rc = -1;
  for (; bytes > 0 && (rc = ::posix_fallocate(fd, 0, bytes)) == ENOSPC; bytes -= 4096) {
  }
  ::close(fd);
  return rc == 0 ? "" : std::strerror(rc);
}

TEST_F(JobStages, DiskFullMidScanInterruptsTheScanAndResumeCompletesOnceSpaceIsFreed) {
  // Before any thread exists: a user namespace needs a single-threaded process.
  std::optional<testing::ScopedTmpfs> tmpfs;
  const std::string why = OnPrivateTmpfs(data_dir(), "24m", &tmpfs);
  if (!why.empty()) GTEST_SKIP() << why;
  Station station(data_dir());
  OPEN_STATION(station);
  const std::string filler = data_dir() + "/filler";
  station.sink().on_capture = [&](int view) {
    if (view == 1) {
      EXPECT_EQ(FillDisk(filler), "");
    }
  };
  const JobInfo started = station.Scan();
  const JobInfo job = station.Wait();
  ASSERT_EQ(job.state, JobState::kFailed) << job.message << "\n" << station.Log();
  EXPECT_TRUE(Contains(job.message, "session " + started.session + " interrupted: view "))
      << job.message;
  EXPECT_TRUE(Contains(job.message, std::strerror(ENOSPC))) << job.message;
  EXPECT_TRUE(
      Contains(job.message, "disk full: free space in the data directory '" + data_dir() + "'"))
      << job.message;
  EXPECT_TRUE(Contains(job.message, "then resume " + started.session)) << job.message;
  station.ExpectOpenedAtEnd();
  const Manifest manifest = station.ManifestOf(started.session);
  EXPECT_EQ(manifest.state, SessionState::kInterrupted);
  const std::vector<int> durable = manifest.CapturedViews();
  ASSERT_GE(durable.size(), 2u);
  EXPECT_EQ(std::vector<int>(durable.begin(), durable.begin() + 2), Range(0, 2));
  // Every acknowledged capture is durable.
  for (int view : station.sink().captures()) {
    EXPECT_NE(std::find(durable.begin(), durable.end(), view), durable.end()) << view;
  }
  ASSERT_TRUE(fs::remove(filler));
  station.ExpectResumeCompletes(started.session);
}

// A scan session of kViews views in state capturing; null with *error.
std::unique_ptr<Session> CapturingSession(SessionStore& store, std::string* error) {
  std::unique_ptr<Session> session =
      store.Create("box", "scan", {{"views", kViews}, {"step_deg", 90}},
                   std::chrono::system_clock::now(), StatusInto(error));
  if (session && !Ok(session->SetState(SessionState::kCapturing, "test"), error)) return nullptr;
  return session;
}

// The context a stage runs in: `session`, `sink`, stopped by *stop.
StageContext ContextFor(Session* session, JobSink* sink, std::atomic<bool>* stop) {
  StageContext context;
  context.session = session;
  context.sink = sink;
  context.stop = stop;
  return context;
}

// The stages alone, without the engine: Run() on queues.
TEST_F(JobStages, CaptureStageStopsAtItsNextViewAndMatchStageFinishesTheViewInHand) {
  Station station(data_dir());
  OPEN_STATION(station);
  std::string error;
  std::unique_ptr<Session> session = CapturingSession(station.store(), &error);
  ASSERT_TRUE(session) << error;
  std::atomic<bool> stop{false};
  const StageContext context = ContextFor(session.get(), &station.sink(), &stop);
  station.sink().on_capture = [&](int view) {
    if (view == 0) stop = true;
  };
  BoundedQueue<CapturedView> q1(kViews);
  CaptureStage capture(context, &station.devices(), {kViews, 90, 0ms});
  const StageOutcome captured = capture.Run(q1);
  EXPECT_TRUE(captured.cancelled()) << captured.message;
  EXPECT_EQ(captured.code, ErrorCode::kCancelled);
  EXPECT_TRUE(captured.resumable);
  EXPECT_EQ(session->DurableViews(), std::vector<int>{0});
  q1.Close();

  // The view in hand is matched and stored although Q2 refuses it.
  const std::optional<StereoCalibration> calibration = station.engine().calibration();
  ASSERT_TRUE(calibration);
  ViewProcessor processor;
  ViewProcessorOptions view_options;
  // The threads the daemon fixtures use (1 under TSan: TBB's workers
  // synchronise inside libtbb, where TSan cannot see it).
  view_options.num_threads = TestThreads();
  view_options.volume.radius_mm = 65;
  view_options.volume.max_height_mm = 70;
  ASSERT_TRUE(processor.Init(*calibration, view_options, &error)) << error;
  stop = false;
  BoundedQueue<MatchedView> q2(1);
  q2.Close();
  MatchStage match(context, &processor, &*calibration, kViews);
  const StageOutcome matched = match.Run(q1, q2);
  EXPECT_TRUE(matched.cancelled()) << matched.message;
  EXPECT_EQ(station.sink().disparities(), std::vector<int>{0});
  const Manifest manifest = session->manifest();
  ASSERT_TRUE(manifest.views.count(0));
  EXPECT_TRUE(manifest.views.at(0).HasCloud());
}

// A store the disk refuses: the stage's outcome carries the code of the
// failing write (kDiskFull from ENOSPC), marked as the data disk's, and is
// resumable; a device's kIoError is not marked so.
TEST_F(JobStages, CaptureStageOnAFullDiskCarriesDiskFull) {
  // Before any thread exists: a user namespace needs a single-threaded process.
  std::optional<testing::ScopedTmpfs> tmpfs;
  const std::string why = OnPrivateTmpfs(data_dir(), "24m", &tmpfs);
  if (!why.empty()) GTEST_SKIP() << why;
  Station station(data_dir());
  OPEN_STATION(station);
  std::string error;
  std::unique_ptr<Session> session = CapturingSession(station.store(), &error);
  ASSERT_TRUE(session) << error;
  ASSERT_EQ(FillDisk(data_dir() + "/filler"), "");
  std::atomic<bool> stop{false};
  const StageContext context = ContextFor(session.get(), &station.sink(), &stop);
  BoundedQueue<CapturedView> q1(kViews);
  CaptureStage capture(context, &station.devices(), {kViews, 90, 0ms});
  const StageOutcome captured = capture.Run(q1);
  EXPECT_EQ(captured.code, ErrorCode::kDiskFull) << captured.message;
  EXPECT_TRUE(captured.storage);
  EXPECT_TRUE(captured.resumable);
  EXPECT_TRUE(Contains(captured.message, "view 0")) << captured.message;
  EXPECT_TRUE(session->DurableViews().empty());
  EXPECT_FALSE(StageOutcome::Error(ErrorCode::kIoError, "camera", true).storage);
}

TEST_F(JobStages, DeviceErrorsKeepTheirCodes) {
  EXPECT_EQ(ToErrorCode(drivers::StatusCode::kAborted), ErrorCode::kCancelled);
  EXPECT_EQ(ToErrorCode(drivers::StatusCode::kDeviceLost), ErrorCode::kDeviceLost);
  EXPECT_EQ(ToErrorCode(drivers::StatusCode::kTimeout), ErrorCode::kTimeout);
  EXPECT_EQ(ToErrorCode(drivers::StatusCode::kFault), ErrorCode::kFailedPrecondition);
  EXPECT_EQ(ToErrorCode(drivers::StatusCode::kIoError), ErrorCode::kIoError);
}

}  // namespace
}  // namespace craftscan::daemon
