#include "craftscan/daemon/jobs.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <cstring>
#include <ctime>
#include <exception>
#include <fstream>
#include <sstream>
#include <utility>

#include <opencv2/imgcodecs.hpp>

#include "craftscan/daemon/bounded_queue.h"
#include "craftscan/daemon/report.h"
#include "craftscan/pipeline/common/atomic_file.h"

namespace craftscan::daemon {
namespace {

constexpr double kDegToRad = CV_PI / 180;

bool Fail(std::string* error, std::string message) {
  if (error) *error = std::move(message);
  return false;
}

std::string UtcStamp() {
  const std::time_t t = std::time(nullptr);
  std::tm tm{};
  gmtime_r(&t, &tm);
  char buffer[32];
  std::strftime(buffer, sizeof buffer, "%Y%m%d-%H%M%S", &tm);
  return buffer;
}

// The prior pose of a view cloud for display: the view taken at commanded
// angle θ, brought back to the turntable frame at angle 0.
cv::Matx44d WorldFromView(const StereoCalibration& c, double angle_deg) {
  if (!c.turntable.valid) return cv::Matx44d::eye();
  const double a = -angle_deg * kDegToRad;
  const cv::Matx44d rz(std::cos(a), -std::sin(a), 0, 0, std::sin(a), std::cos(a), 0, 0, 0, 0, 1, 0,
                       0, 0, 0, 1);
  return rz * TurntableFromRig(c.turntable);
}

// The operator's next step after a storage error about a path below `dir`
// (recognised by that path and the strerror text the store's messages end
// with), as " (disk full: free space in ..., <then>)"; "" for other errors
// (a device error may say "Permission denied" too).
std::string StorageAdvice(const std::string& error, const std::string& dir,
                          const std::string& data_dir, const std::string& then) {
  if (dir.empty() || error.find(dir) == std::string::npos) return {};
  const auto says = [&](int code) { return error.find(std::strerror(code)) != std::string::npos; };
  std::string what;
  if (says(ENOSPC) || says(EDQUOT)) {
    what = "disk full: free space in the data directory '" + data_dir + "'";
  } else if (says(EROFS)) {
    what = "the data directory '" + data_dir + "' is read-only: make it writable";
  } else if (says(EACCES) || says(EPERM)) {
    what = "craftscand may not write in the data directory '" + data_dir + "': fix its permissions";
  } else if (says(EIO)) {
    what = "I/O error on the data disk '" + data_dir + "': check the disk";
  } else {
    return {};
  }
  return " (" + what + ", then " + then + ")";
}

// See JobEngine::kReserveBytes.
std::string ReservePath(const std::string& data_dir) { return data_dir + "/.craftscand-reserve"; }

nlohmann::json FrameMeta(const drivers::StereoFrame& frame, double angle_deg) {
  return {
      {"angle_deg", angle_deg},
      {"exposure_us", frame.settings.exposure_us},
      {"gain_db", frame.settings.gain_db},
      {"pixel_format", std::string(drivers::ToString(frame.settings.pixel_format))},
      {"left", {{"timestamp_ns", frame.left.timestamp_ns}, {"frame_id", frame.left.frame_id}}},
      {"right", {{"timestamp_ns", frame.right.timestamp_ns}, {"frame_id", frame.right.frame_id}}}};
}

}  // namespace

std::string_view ToString(JobState state) {
  switch (state) {
    case JobState::kIdle:
      return "idle";
    case JobState::kRunning:
      return "running";
    case JobState::kDone:
      return "done";
    case JobState::kFailed:
      return "failed";
    case JobState::kCancelled:
      return "cancelled";
  }
  return "unknown";
}

struct JobEngine::ScanPlan {
  std::unique_ptr<Session> session;
  StereoCalibration calibration;
  int views = 0;
  double step_deg = 0;
  bool reconstruct = true;  // false for a one-view capture
};

JobEngine::JobEngine(JobEngineOptions options, DeviceManager* devices, SessionStore* store,
                     JobSink* sink, std::function<void(drivers::LogLevel, std::string_view)> log)
    : options_(std::move(options)),
      devices_(devices),
      store_(store),
      sink_(sink),
      log_(std::move(log)) {}

JobEngine::~JobEngine() { Shutdown(); }

SessionStore* JobEngine::Store(std::string* error) const {
  SessionStore* store = store_.load();
  if (!store) {
    Fail(error, "the session store is not open: the data directory '" + options_.data_dir +
                    "' is not usable (see the status)");
  }
  return store;
}

void JobEngine::EnsureReserve() {
  const std::string path = ReservePath(options_.data_dir);
  struct stat st {};
  if (::stat(path.c_str(), &st) == 0 &&
      static_cast<std::size_t>(st.st_blocks) * 512 >= kReserveBytes) {
    return;
  }
  const int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_CLOEXEC | O_NOFOLLOW, 0600);
  if (fd < 0) return;  // read-only or gone: the job's first write says so
  const int rc = ::posix_fallocate(fd, 0, static_cast<off_t>(kReserveBytes));
  ::close(fd);
  if (rc != 0) {
    ::unlink(path.c_str());
    if (log_) {
      log_(drivers::LogLevel::kWarning, "cannot reserve " + std::to_string(kReserveBytes) +
                                            " bytes in '" + path + "': " + std::strerror(rc));
    }
  }
}

bool JobEngine::RecordState(Session& session, SessionState state, const std::string& detail,
                            std::string* error) {
  std::string why;
  if (session.SetState(state, detail, &why)) return true;
  const bool full = why.find(std::strerror(ENOSPC)) != std::string::npos ||
                    why.find(std::strerror(EDQUOT)) != std::string::npos;
  if (full && ::unlink(ReservePath(options_.data_dir).c_str()) == 0) {
    if (log_) {
      log_(drivers::LogLevel::kWarning,
           "disk full: freed the reserve to mark session " + session.id() + " " + ToString(state));
    }
    if (session.SetState(state, detail, &why)) return true;
  }
  return Fail(error, why);
}

void JobEngine::JoinFinishedWorker() {
  {
    std::lock_guard lock(mutex_);
    if (running_) return;
  }
  if (worker_.joinable()) worker_.join();
}

bool JobEngine::LoadCurrentCalibration(std::string* error) {
  const std::string path = options_.data_dir + "/calibration/current.yaml";
  struct stat st {};
  if (::stat(path.c_str(), &st) != 0) return true;  // none yet
  StereoCalibration calibration;
  if (!LoadCalibration(path, &calibration, error)) return false;
  std::string id;
  std::ifstream id_file(options_.data_dir + "/calibration/current.id");
  std::getline(id_file, id);
  std::lock_guard lock(mutex_);
  calibration_ = calibration;
  calibration_id_ = id.empty() ? "current" : id;
  return true;
}

std::optional<StereoCalibration> JobEngine::calibration() const {
  std::lock_guard lock(mutex_);
  return calibration_;
}

std::string JobEngine::calibration_id() const {
  std::lock_guard lock(mutex_);
  return calibration_id_;
}

bool JobEngine::Busy() const {
  std::lock_guard lock(mutex_);
  return running_;
}

JobInfo JobEngine::Current() const {
  std::lock_guard lock(mutex_);
  return current_;
}

bool JobEngine::WaitIdle(std::chrono::milliseconds timeout) const {
  std::unique_lock lock(mutex_);
  return idle_.wait_for(lock, timeout, [&] { return !running_; });
}

bool JobEngine::Launch(const std::string& verb, const std::string& session,
                       std::function<void()> body, JobInfo* info, std::string* error) {
  std::unique_lock lock(mutex_);
  if (running_) {
    return Fail(error, "busy: " + current_.id + " (" + current_.verb + ") is running");
  }
  if (worker_.joinable()) {
    lock.unlock();
    worker_.join();
    lock.lock();
  }
  current_ = JobInfo{};
  current_.id = "job-" + std::to_string(next_job_++);
  current_.verb = verb;
  current_.state = JobState::kRunning;
  current_.session = session;
  current_.stage = "starting";
  running_ = true;
  cancel_ = false;
  if (info) *info = current_;
  worker_ = std::thread([this, body = std::move(body)] {
    try {
      body();
    } catch (const std::exception& e) {
      Finish(JobState::kFailed, std::string("internal error: ") + e.what());
    } catch (...) {
      Finish(JobState::kFailed, "internal error: unknown exception");
    }
    std::lock_guard lock(mutex_);
    if (running_) {  // a body that forgot to finish
      running_ = false;
      current_.state = JobState::kFailed;
      current_.message = "job ended without a result";
    }
    idle_.notify_all();
  });
  return true;
}

void JobEngine::SetStage(const std::string& stage, int current, int total,
                         const std::string& message) {
  std::string job;
  {
    std::lock_guard lock(mutex_);
    current_.stage = stage;
    if (total > 0) current_.progress = static_cast<double>(current) / total;
    job = current_.id;
  }
  if (sink_) sink_->Progress(job, stage, current, total, message);
}

void JobEngine::Finish(JobState state, const std::string& message, nlohmann::json result) {
  if (defer_finish_) {  // RunScan finishes once the session is closed
    deferred_finish_ = DeferredFinish{state, message, std::move(result)};
    return;
  }
  std::string job, stage;
  {
    std::lock_guard lock(mutex_);
    current_.state = state;
    current_.message = message;
    current_.result = std::move(result);
    if (state == JobState::kDone) current_.progress = 1;
    running_ = false;
    job = current_.id;
    idle_.notify_all();
  }
  if (log_) {
    log_(state == JobState::kDone ? drivers::LogLevel::kInfo : drivers::LogLevel::kWarning,
         job + " " + std::string(ToString(state)) + ": " + message);
  }
  if (sink_) sink_->Progress(job, std::string(ToString(state)), 1, 1, message);
}

bool JobEngine::Cancel(std::string* error) {
  {
    std::lock_guard lock(mutex_);
    if (!running_) return Fail(error, "no job is running");
    cancel_ = true;
  }
  // A move can take many seconds: stop the table (the driver's feed hold)
  // instead of waiting for it. The job then ends "cancelled" at that view.
  if (moving_) devices_->AbortMove();
  return true;
}

void JobEngine::Shutdown() {
  cancel_ = true;
  if (moving_) devices_->AbortMove();
  if (worker_.joinable()) worker_.join();
}

// --- scan, capture, resume -------------------------------------------------

bool JobEngine::StartScan(const ScanRequest& request, JobInfo* info, std::string* error) {
  const int views = request.views > 0 ? request.views : options_.default_views;
  if (views < 2 || views > 360) return Fail(error, "views must be in 2..360");
  // A step given wins; views without a step make one full turn; neither:
  // the configured scan.views and scan.step_deg.
  const double step = request.step_deg != 0 ? request.step_deg
                      : request.views > 0   ? 360.0 / views
                                            : options_.default_step_deg;
  if (!std::isfinite(step) || std::abs(step) < 0.1 || std::abs(step) * (views - 1) > 720) {
    return Fail(error, "step_deg must be finite, |step| >= 0.1 and span at most 720 degrees");
  }
  const std::optional<StereoCalibration> calibration = this->calibration();
  if (!calibration)
    return Fail(error, "no calibration: run calibrate and calibrate-turntable first");
  if (!calibration->turntable.valid) {
    return Fail(error, "the calibration has no turntable axis: run calibrate-turntable first");
  }
  if (Busy()) return Fail(error, "busy: " + Current().id + " (" + Current().verb + ") is running");
  SessionStore* store = Store(error);
  if (!store) return false;
  EnsureReserve();
  auto plan = std::make_shared<ScanPlan>();
  plan->calibration = *calibration;
  plan->views = views;
  plan->step_deg = step;
  const nlohmann::json params = {{"views", views},
                                 {"step_deg", step},
                                 {"client", request.client},
                                 {"calibration_id", calibration_id()}};
  plan->session =
      store->Create(request.object, "scan", params, std::chrono::system_clock::now(), error);
  if (!plan->session) {
    *error += StorageAdvice(*error, store->sessions_dir(), options_.data_dir, "try again");
    return false;
  }
  const std::string current = options_.data_dir + "/calibration/current.yaml";
  if (!plan->session->CopyCalibration(current, calibration_id(), error)) {
    RecordState(*plan->session, SessionState::kFailed, *error, nullptr);
    *error += StorageAdvice(*error, store->sessions_dir(), options_.data_dir, "try again");
    return false;
  }
  return Launch(
      "scan", plan->session->id(), [this, plan] { RunScan(plan); }, info, error);
}

bool JobEngine::StartCapture(const std::string& object, JobInfo* info, std::string* error) {
  const std::optional<StereoCalibration> calibration = this->calibration();
  if (!calibration) return Fail(error, "no calibration: run calibrate first");
  if (Busy()) return Fail(error, "busy: " + Current().id + " (" + Current().verb + ") is running");
  SessionStore* store = Store(error);
  if (!store) return false;
  EnsureReserve();
  auto plan = std::make_shared<ScanPlan>();
  plan->calibration = *calibration;
  plan->views = 1;
  plan->step_deg = 0;
  plan->reconstruct = false;
  plan->session = store->Create(object, "capture", {{"views", 1}, {"step_deg", 0}},
                                std::chrono::system_clock::now(), error);
  if (!plan->session) {
    *error += StorageAdvice(*error, store->sessions_dir(), options_.data_dir, "try again");
    return false;
  }
  if (!plan->session->CopyCalibration(options_.data_dir + "/calibration/current.yaml",
                                      calibration_id(), error)) {
    RecordState(*plan->session, SessionState::kFailed, *error, nullptr);
    *error += StorageAdvice(*error, store->sessions_dir(), options_.data_dir, "try again");
    return false;
  }
  return Launch(
      "capture", plan->session->id(), [this, plan] { RunScan(plan); }, info, error);
}

bool JobEngine::StartResume(const std::string& session_id, JobInfo* info, std::string* error) {
  if (Busy()) return Fail(error, "busy: " + Current().id + " (" + Current().verb + ") is running");
  SessionStore* store = Store(error);
  if (!store) return false;
  JoinFinishedWorker();  // the last job's session lock goes with its thread
  EnsureReserve();
  auto plan = std::make_shared<ScanPlan>();
  plan->session = store->OpenSession(session_id, error);
  if (!plan->session) return false;
  const SessionState state = plan->session->state();
  if (state == SessionState::kDone)
    return Fail(error, "session " + session_id + " is already done");
  if (IsActive(state)) {
    // Its lock is ours, so no job runs it: the one that did could not
    // record its end (e.g. the disk was full).
    if (!RecordState(*plan->session, SessionState::kInterrupted,
                     std::string("found ") + ToString(state) + " with no job running it", error)) {
      *error += StorageAdvice(*error, plan->session->dir(), options_.data_dir, "resume it");
      return false;
    }
  }
  const nlohmann::json params = plan->session->params();
  plan->views = params.value("views", 0);
  plan->step_deg = params.value("step_deg", 0.0);
  plan->reconstruct = plan->session->manifest().job == "scan";
  if (plan->views < 1) return Fail(error, "session " + session_id + ": manifest has no view count");
  if (!LoadCalibration(plan->session->dir() + "/calibration.yaml", &plan->calibration, error)) {
    return false;
  }
  return Launch(
      "resume", session_id, [this, plan] { RunScan(plan); }, info, error);
}

void JobEngine::RunScan(const std::shared_ptr<ScanPlan>& plan) {
  // The session is closed -- its lock released -- before the job is
  // announced as ended, so a client told "done" or "failed" can open it at
  // once (resume, craftscan-record, another process). ScanBody's Finish is
  // held back until then.
  defer_finish_ = true;
  try {
    ScanBody(plan);
  } catch (...) {
    defer_finish_ = false;
    deferred_finish_.reset();
    plan->session.reset();
    throw;  // Launch reports it
  }
  defer_finish_ = false;
  plan->session.reset();
  if (deferred_finish_) {
    DeferredFinish f = std::move(*deferred_finish_);
    deferred_finish_.reset();
    Finish(f.state, f.message, std::move(f.result));
  }
}

void JobEngine::ScanBody(const std::shared_ptr<ScanPlan>& plan) {
  Session& session = *plan->session;
  const std::string sid = session.id();
  const int n = plan->views;
  std::string error;

  ViewProcessor processor;
  ViewProcessorOptions view_options = options_.view;
  view_options.num_threads = options_.threads;
  const auto advice = [&](const std::string& e) {
    return StorageAdvice(e, session.dir(), options_.data_dir, "resume " + sid);
  };
  if (!processor.Init(plan->calibration, view_options, &error)) {
    RecordState(session, SessionState::kFailed, error, nullptr);
    Finish(JobState::kFailed, error);
    return;
  }
  if (!session.SetState(SessionState::kCapturing, "job " + Current().id, &error)) {
    Finish(JobState::kFailed, error + advice(error), {{"session", sid}});
    return;
  }

  struct Captured {
    int view;
    double angle_deg;
    cv::Mat left, right;  // empty: the cloud is already durable
  };
  struct Matched {
    int view;
    double angle_deg;
    PointCloud cloud;
  };
  BoundedQueue<Captured> q1(static_cast<std::size_t>(options_.queue_capacity));
  BoundedQueue<Matched> q2(static_cast<std::size_t>(options_.queue_capacity));
  std::mutex error_mutex;
  std::string first_error;
  bool resumable = true;  // interrupted (device, cancel) vs failed (pipeline)
  auto fail = [&](const std::string& message, bool can_resume) {
    {
      std::lock_guard lock(error_mutex);
      if (first_error.empty()) {
        first_error = message;
        resumable = can_resume;
      }
    }
    cancel_ = true;
    q1.Close();
    q2.Close();
  };

  std::vector<std::optional<Matched>> clouds(static_cast<std::size_t>(n));
  double match_ms = 0, capture_ms = 0;
  std::thread matcher([&] {
    try {
      while (std::optional<Captured> item = q1.Pop()) {
        if (cancel_) break;
        Matched out{item->view, item->angle_deg, {}};
        std::string why;
        if (item->left.empty()) {
          if (!session.LoadCloud(item->view, &out.cloud, &why)) {
            fail("view " + std::to_string(item->view) + ": " + why, false);
            break;
          }
        } else {
          const auto start = std::chrono::steady_clock::now();
          ProcessedView v = processor.Process(item->left, item->right);
          if (!v.ok) {
            fail("view " + std::to_string(item->view) + ": " + v.message, false);
            break;
          }
          if (!session.StoreDisparity(item->view, v.disparity, &why) ||
              !session.StoreCloud(item->view, v.cloud_in_rig, &why)) {
            fail("view " + std::to_string(item->view) + ": " + why, true);
            break;
          }
          match_ms +=
              std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
                  .count();
          if (sink_) {
            sink_->Disparity(sid, item->view, v.disparity, processor.focal_px(),
                             processor.baseline_mm(), v.min_disparity, v.num_disparities);
          }
          out.cloud = std::move(v.cloud_in_rig);
        }
        if (sink_) {
          sink_->Cloud(sid, item->view, out.cloud,
                       WorldFromView(plan->calibration, item->angle_deg));
        }
        SetStage("match", item->view + 1, n,
                 "view " + std::to_string(item->view) + ": " + std::to_string(out.cloud.size()) +
                     " points");
        if (!q2.Push(std::move(out))) break;
      }
    } catch (const std::exception& e) {
      fail(std::string("matching: ") + e.what(), false);
    }
    q2.Close();
  });
  std::thread collector([&] {
    while (std::optional<Matched> item = q2.Pop()) {
      clouds[static_cast<std::size_t>(item->view)] = std::move(*item);
    }
  });

  // Stage 1 on this thread: capture what is not durable yet, hand on the rest.
  bool turntable_prepared = false;  // homed first if an earlier job left it faulted
  try {
    for (int k = 0; k < n && !cancel_; ++k) {
      const double angle = k * plan->step_deg;
      const Manifest manifest = session.manifest();
      const auto record = manifest.views.find(k);
      const bool has_capture = record != manifest.views.end() && record->second.HasCapture();
      const bool has_cloud = has_capture && record->second.HasCloud();
      if (has_cloud) {
        if (!q1.Push({k, angle, {}, {}})) break;
        continue;
      }
      Captured item{k, angle, {}, {}};
      if (has_capture) {
        nlohmann::json meta;
        if (!session.LoadCapture(k, &item.left, &item.right, &meta, &error)) {
          fail("view " + std::to_string(k) + ": stored capture unreadable: " + error, false);
          break;
        }
      } else {
        const auto start = std::chrono::steady_clock::now();
        SetStage("capture", k, n, "moving to " + std::to_string(angle) + " deg");
        if (n > 1 || plan->step_deg != 0) {
          if (!turntable_prepared && !(turntable_prepared = devices_->PrepareTurntable(&error))) {
            fail("view " + std::to_string(k) + ": " + error, true);
            break;
          }
          moving_ = true;
          const bool moved = devices_->MoveTo(angle, &error);
          moving_ = false;
          if (!moved) {
            fail(cancel_ ? "cancelled" : "view " + std::to_string(k) + ": " + error, true);
            break;
          }
          std::this_thread::sleep_for(options_.settle);
        }
        drivers::StereoFrame frame;
        if (!devices_->Capture(&frame, cancel_, &error)) {
          fail(cancel_ && error == "cancelled" ? "cancelled"
                                               : "view " + std::to_string(k) + ": " + error,
               true);
          break;
        }
        if (!session.StoreCapture(k, angle, frame.left.image, frame.right.image,
                                  FrameMeta(frame, angle), &error)) {
          fail("view " + std::to_string(k) + ": " + error, true);
          break;
        }
        capture_ms +=
            std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
                .count();
        if (sink_) sink_->Capture(sid, k, angle, frame);  // durable: acknowledged
        SetStage("capture", k + 1, n, "view " + std::to_string(k) + " stored");
        item.left = frame.left.image;
        item.right = frame.right.image;
      }
      if (!q1.Push(std::move(item))) break;
    }
  } catch (const std::exception& e) {
    fail(std::string("capture: ") + e.what(), true);
  }
  q1.Close();
  matcher.join();
  collector.join();

  if (first_error.empty() && cancel_) fail("cancelled", true);
  if (!first_error.empty()) {
    const SessionState state = resumable ? SessionState::kInterrupted : SessionState::kFailed;
    std::string message = first_error + advice(first_error);
    std::string why;
    const bool recorded = RecordState(session, state, first_error, &why);
    if (!recorded) {
      message += "; it could not be marked " + std::string(ToString(state)) + " (" + why +
                 "): resume marks it";
    }
    Finish(first_error == "cancelled" ? JobState::kCancelled : JobState::kFailed,
           "session " + sid + " " + (recorded ? ToString(state) : "stopped") + ": " + message,
           {{"session", sid}});
    return;
  }

  nlohmann::json result = {
      {"session", sid}, {"views", n}, {"capture_ms", capture_ms}, {"match_ms", match_ms}};
  if (!plan->reconstruct) {
    if (!RecordState(session, SessionState::kDone, "capture stored", &error)) {
      Finish(JobState::kFailed,
             "session " + sid + ": the view is stored but the session could not be marked done: " +
                 error + advice(error),
             {{"session", sid}});
      return;
    }
    Finish(JobState::kDone, "session " + sid + ": 1 view captured", result);
    return;
  }

  if (!session.SetState(SessionState::kReconstructing, "registration, fusion, mesh", &error)) {
    RecordState(session, SessionState::kInterrupted, error, nullptr);
    Finish(JobState::kFailed, "session " + sid + " interrupted: " + error + advice(error),
           {{"session", sid}});
    return;
  }
  SetStage("register", 0, 1, "registering " + std::to_string(n) + " views");
  std::vector<ScanView> views;
  for (auto& c : clouds) {
    ScanView v;
    v.commanded_angle_rad = c->angle_deg * kDegToRad;
    v.cloud_in_rig = std::move(c->cloud);
    views.push_back(std::move(v));
  }
  ScanOptions scan = options_.scan;
  scan.num_threads = options_.threads;
  const auto start = std::chrono::steady_clock::now();
  const ScanResult r = ReconstructScan(views, plan->calibration.turntable, scan);
  const double reconstruct_ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
  if (!r.IsUsable()) {
    RecordState(session, SessionState::kFailed, "reconstruction: " + r.message, nullptr);
    Finish(JobState::kFailed, "session " + sid + " failed: reconstruction: " + r.message,
           {{"session", sid}});
    return;
  }
  SetStage("write", 0, 1, "writing fused cloud, mesh and report");
  bool written = session.StoreOutputWith(
      "fused.ply",
      [&](const std::string& path, std::string* why) { return WritePly(path, r.fused, true, why); },
      &error);
  if (written && r.mesh.status == MeshResult::Status::kOk) {
    written = session.StoreOutputWith(
                  "mesh.ply",
                  [&](const std::string& path, std::string* why) {
                    return WriteMeshPly(path, r.mesh.mesh, true, why);
                  },
                  &error) &&
              session.StoreOutputWith(
                  "mesh.obj",
                  [&](const std::string& path, std::string* why) {
                    return WriteMeshObj(path, r.mesh.mesh, why);
                  },
                  &error);
  }
  const std::string report = ScanReportJson(r);
  written = written && session.StoreOutput("report.json", report, &error);
  if (!written) {
    // Storage, not the pipeline: resumable like a capture that failed.
    std::string message = error + advice(error);
    std::string why;
    const bool recorded =
        RecordState(session, SessionState::kInterrupted, "outputs: " + error, &why);
    if (!recorded) message += "; it could not be marked interrupted (" + why + "): resume marks it";
    Finish(JobState::kFailed,
           "session " + sid + (recorded ? " interrupted: " : " stopped: ") + message,
           {{"session", sid}});
    return;
  }
  // The page people look at: measurements, calibration, registration and
  // pictures. A report that cannot be made is noted, not a failed scan.
  SetStage("report", 0, 1, "rendering previews and report.html");
  {
    const Manifest manifest = session.manifest();
    ReportInputs inputs;
    inputs.session_id = sid;
    inputs.object_name = manifest.object_name;
    inputs.created_utc = manifest.created_utc;
    inputs.calibration_id = manifest.calibration_id;
    inputs.scan_report_json = report;
    inputs.calibration = &plan->calibration;
    inputs.fused = &r.fused;
    if (r.mesh.status == MeshResult::Status::kOk) inputs.mesh = &r.mesh.mesh;
    for (int k = 0; k < n; ++k) {
      DisparityView view;
      view.index = k;
      view.angle_deg = k * plan->step_deg;
      view.min_disparity_px = processor.min_disparity();
      view.max_disparity_px = processor.min_disparity() + processor.num_disparities() - 1;
      if (session.LoadDisparity(k, &view.disparity_px, nullptr)) {
        inputs.disparities.push_back(std::move(view));
      }
    }
    ReportFiles files;
    std::string why;
    bool ok = MakeReportFiles(inputs, &files, &why);
    for (std::size_t i = 0; ok && i < files.files.size(); ++i) {
      ok = session.StoreOutput(files.files[i].name, files.files[i].bytes, &why);
    }
    if (!ok && log_) log_(drivers::LogLevel::kWarning, "session " + sid + ": report: " + why);
    result["report_ms"] = files.render_ms;
  }
  if (sink_) sink_->Cloud(sid, -1, r.fused, cv::Matx44d::eye());
  if (!RecordState(session, SessionState::kDone,
                   "fused " + std::to_string(r.fused.size()) + " points", &error)) {
    Finish(JobState::kFailed,
           "session " + sid +
               ": the outputs are stored but the session could not be marked done: " + error +
               advice(error),
           {{"session", sid}});
    return;
  }
  result["fused_points"] = r.fused.size();
  result["mesh_vertices"] = r.mesh.mesh.vertices_mm.size();
  result["reconstruct_ms"] = reconstruct_ms;
  result["stage_ms"] = {{"condition", r.condition_ms}, {"register", r.register_ms},
                        {"loop", r.loop_ms},           {"fuse", r.fuse_ms},
                        {"mesh", r.mesh_ms},           {"measure", r.measure_ms}};
  result["box_mm"] = {r.box.extents_mm[0], r.box.extents_mm[1], r.box.extents_mm[2]};
  const nlohmann::json report_json = nlohmann::json::parse(report, nullptr, false);
  if (report_json.is_object() && report_json.contains("measurement")) {
    result["measurement"] = report_json["measurement"];
  }
  Finish(JobState::kDone,
         "session " + sid + ": " + std::to_string(n) + " views, " + std::to_string(r.fused.size()) +
             " fused points",
         result);
}

// --- calibration -------------------------------------------------------------

std::string JobEngine::NewCalibrationDir(std::string* id, std::string* error) {
  const std::string root = options_.data_dir + "/calibration";
  ::mkdir(root.c_str(), 0755);
  std::string candidate = UtcStamp();
  for (int i = 2; i < 1000; ++i) {
    const std::string dir = root + "/" + candidate;
    if (::mkdir(dir.c_str(), 0755) == 0) {
      *id = candidate;
      return dir;
    }
    if (errno != EEXIST) {
      Fail(error, "'" + dir + "': " + std::strerror(errno));
      return {};
    }
    candidate = UtcStamp() + "-" + std::to_string(i);
  }
  Fail(error, "'" + root + "': no free calibration name");
  return {};
}

bool JobEngine::SetCurrentCalibration(const StereoCalibration& calibration, const std::string& id,
                                      std::string* error) {
  const std::string root = options_.data_dir + "/calibration";
  if (!SaveCalibration(root + "/current.yaml", calibration, error)) return false;
  if (!WriteFileAtomically(root + "/current.id", id + "\n", error)) return false;
  {
    std::lock_guard lock(mutex_);
    calibration_ = calibration;
    calibration_id_ = id;
  }
  if (sink_) sink_->CalibrationChanged(calibration);
  return true;
}

bool JobEngine::StartCalibrate(JobInfo* info, std::string* error) {
  return Launch(
      "calibrate", "", [this] { RunCalibrate(); }, info, error);
}

bool JobEngine::StartCalibrateTurntable(JobInfo* info, std::string* error) {
  if (!calibration()) return Fail(error, "no calibration: run calibrate first");
  return Launch(
      "calibrate-turntable", "", [this] { RunCalibrateTurntable(); }, info, error);
}

void JobEngine::RunCalibrate() {
  std::string error;
  if (!devices_->SwitchScene("held_board", &options_.board, &error)) {
    Finish(JobState::kFailed, "calibrate: " + error);
    return;
  }
  std::string id;
  const std::string dir = NewCalibrationDir(&id, &error);
  if (dir.empty()) {
    devices_->SwitchScene("object", nullptr, &error);
    Finish(JobState::kFailed, "calibrate: " + error);
    return;
  }
  std::vector<StereoBoardView> views;
  cv::Size image_size;
  const int wanted = options_.calibration_views;
  for (int attempt = 0; attempt < options_.calibration_max_attempts &&
                        static_cast<int>(views.size()) < wanted && !cancel_;
       ++attempt) {
    drivers::StereoFrame frame;
    if (!devices_->Capture(&frame, cancel_, &error)) break;
    image_size = frame.left.image.size();
    StereoBoardView view = DetectStereoBoard("view" + std::to_string(attempt), frame.left.image,
                                             frame.right.image, options_.board);
    const bool found = view.left.found && view.right.found;
    if (found) {
      char name[32];
      std::snprintf(name, sizeof name, "/%03zu_", views.size());
      std::vector<uchar> png;
      cv::imencode(".png", frame.left.image, png);
      WriteFileAtomically(dir + name + "left.png", std::string(png.begin(), png.end()), nullptr);
      cv::imencode(".png", frame.right.image, png);
      WriteFileAtomically(dir + name + "right.png", std::string(png.begin(), png.end()), nullptr);
      views.push_back(std::move(view));
    }
    SetStage("capture", static_cast<int>(views.size()), wanted,
             found ? "board found" : "board not found in both images; move the board");
  }
  devices_->SwitchScene("object", nullptr, nullptr);
  if (cancel_) {
    Finish(JobState::kCancelled, "calibrate cancelled; nothing changed");
    return;
  }
  if (static_cast<int>(views.size()) < wanted) {
    Finish(JobState::kFailed, "calibrate: the board was found in " + std::to_string(views.size()) +
                                  " of " + std::to_string(wanted) + " views" +
                                  (error.empty() ? "" : " (" + error + ")"));
    return;
  }
  SetStage("calibrate", 0, 1, "solving");
  StereoCalibrationResult r =
      CalibrateStereo(views, image_size, options_.board, options_.calibration);
  if (r.status != StereoCalibrationResult::Status::kOk) {
    Finish(JobState::kFailed, "calibrate: " + r.message);
    return;
  }
  const CalibrationReport& report = r.report();
  nlohmann::json result = {
      {"calibration_id", id},
      {"rms_stereo_px", report.rms_stereo_px},
      {"rms_left_px", report.rms_left_px},
      {"rms_right_px", report.rms_right_px},
      {"epipolar_mean_px", report.epipolar_mean_px},
      {"views_used", report.views_used},
      {"verdict", std::string(ToString(report.verdict))},
      {"verdict_reason", report.verdict_reason},
      {"focal_px", r.calibration.P1(0, 0)},
      {"baseline_mm", std::abs(r.calibration.P2(0, 3) / r.calibration.P2(0, 0))}};
  if (!SaveCalibration(dir + "/calibration.yaml", r.calibration, &error) ||
      !WriteFileAtomically(dir + "/report.json", result.dump(2), &error)) {
    Finish(JobState::kFailed, "calibrate: " + error, result);
    return;
  }
  const bool accepted = r.IsUsable() && report.rms_stereo_px <= options_.max_rms_px;
  result["accepted"] = accepted;
  if (!accepted) {
    Finish(JobState::kFailed,
           "calibrate: rejected (rms " + std::to_string(report.rms_stereo_px) + " px; " +
               report.verdict_reason + "); the current calibration is unchanged",
           result);
    return;
  }
  if (!SetCurrentCalibration(r.calibration, id, &error)) {
    Finish(JobState::kFailed, "calibrate: " + error, result);
    return;
  }
  Finish(JobState::kDone,
         "calibration " + id + " accepted and current (rms " +
             std::to_string(report.rms_stereo_px) + " px); run calibrate-turntable next",
         result);
}

void JobEngine::RunCalibrateTurntable() {
  std::string error;
  StereoCalibration calibration = *this->calibration();
  if (!devices_->SwitchScene("platter_board", &options_.turntable_board, &error)) {
    Finish(JobState::kFailed, "calibrate-turntable: " + error);
    return;
  }
  std::vector<TurntableStep> steps;
  const auto& angles = options_.turntable_angles_deg;
  if (!devices_->PrepareTurntable(&error)) {
    devices_->SwitchScene("object", nullptr, nullptr);
    Finish(JobState::kFailed, "calibrate-turntable: " + error);
    return;
  }
  for (std::size_t i = 0; i < angles.size() && !cancel_; ++i) {
    drivers::StereoFrame frame;
    if (!devices_->MoveTo(angles[i], &error)) break;
    std::this_thread::sleep_for(options_.settle);
    if (!devices_->Capture(&frame, cancel_, &error)) break;
    TurntableStep step;
    step.commanded_angle_rad = angles[i] * kDegToRad;
    step.left = DetectBoard(frame.left.image, options_.turntable_board);
    SetStage("capture", static_cast<int>(i + 1), static_cast<int>(angles.size()),
             step.left.found ? "board found" : "board not found: " + step.left.message);
    steps.push_back(std::move(step));
  }
  devices_->MoveTo(0, nullptr);
  devices_->SwitchScene("object", nullptr, nullptr);
  if (cancel_) {
    Finish(JobState::kCancelled, "calibrate-turntable cancelled; nothing changed");
    return;
  }
  if (steps.size() < angles.size()) {
    Finish(JobState::kFailed, "calibrate-turntable: " + error);
    return;
  }
  TurntableAxisOptions axis_options;
  axis_options.board_thickness_mm = options_.turntable_board_thickness_mm;
  const TurntableAxisResult r = CalibrateTurntableAxis(calibration, steps, axis_options);
  nlohmann::json result = {{"status", std::string(ToString(r.status))},
                           {"steps_used", r.steps_used},
                           {"residual_mm", r.residual_mm},
                           {"max_abs_angle_error_deg", r.max_abs_angle_error_deg},
                           {"verdict", std::string(ToString(r.verdict))},
                           {"verdict_reason", r.verdict_reason}};
  if (!r.IsUsable() || !ApplyTurntableAxis(r, &calibration)) {
    Finish(JobState::kFailed,
           "calibrate-turntable: rejected: " + (r.message.empty() ? r.verdict_reason : r.message),
           result);
    return;
  }
  std::string id;
  const std::string dir = NewCalibrationDir(&id, &error);
  if (dir.empty() || !SaveCalibration(dir + "/calibration.yaml", calibration, &error) ||
      !WriteFileAtomically(dir + "/report.json", result.dump(2), &error) ||
      !SetCurrentCalibration(calibration, id, &error)) {
    Finish(JobState::kFailed, "calibrate-turntable: " + error, result);
    return;
  }
  result["calibration_id"] = id;
  Finish(JobState::kDone,
         "turntable axis accepted (residual " + std::to_string(r.residual_mm) +
             " mm); calibration " + id + " is current",
         result);
}

}  // namespace craftscan::daemon
