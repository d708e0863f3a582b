#include "craftscan/daemon/jobs.h"

#include "craftscan/daemon/remote_jobs.h"

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
#include <thread>
#include <type_traits>
#include <utility>

#include "craftscan/daemon/bounded_queue.h"
#include "craftscan/daemon/scan_turns.h"
#include "craftscan/pipeline/common/atomic_file.h"
#include "craftscan/pipeline/stereo/exposure_merge.h"

namespace craftscan::daemon {
namespace {

bool Fail(std::string* error, std::string message) {
  if (error) *error = std::move(message);
  return false;
}

// The operator's next step after the session store (or the data disk under
// it) refused a write with `code` (from the errno of the failing call), as
// " (disk full: free space in ..., <then>)"; "" for the codes that are not
// the disk's (a busy session, a forbidden transition, a corrupt manifest).
// Only called with codes that come from the store: a device error's
// kIoError is not the disk's (StageOutcome::storage says which).
std::string StorageAdvice(ErrorCode code, const std::string& data_dir, const std::string& then) {
  std::string what;
  switch (code) {
    case ErrorCode::kDiskFull:
      what = "disk full: free space in the data directory '" + data_dir + "'";
      break;
    case ErrorCode::kReadOnly:
      what = "the data directory '" + data_dir + "' is read-only: make it writable";
      break;
    case ErrorCode::kPermissionDenied:
      what =
          "craftscand may not write in the data directory '" + data_dir + "': fix its permissions";
      break;
    case ErrorCode::kIoError:
      what = "I/O error on the data disk '" + data_dir + "': check the disk";
      break;
    default:
      return {};
  }
  return " (" + what + ", then " + then + ")";
}

// The same for a failed Status of the store.
std::string StorageAdvice(const Status& status, const std::string& data_dir,
                          const std::string& then) {
  return StorageAdvice(status.code(), data_dir, then);
}

// See JobEngine::kReserveBytes.
std::string ReservePath(const std::string& data_dir) { return data_dir + "/.craftscand-reserve"; }

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

namespace {

// The multiples as a JSON array, built element by element (GCC 12's
// -Warray-bounds misfires on the vector conversion of an empty vector).
nlohmann::json BracketJson(const std::vector<double>& multiples) {
  nlohmann::json out = nlohmann::json::array();
  for (const double m : multiples) out.push_back(m);
  return out;
}

}  // namespace

struct JobEngine::ScanPlan {
  std::unique_ptr<Session> session;
  StereoCalibration calibration;
  int views = 0;
  double step_deg = 0;
  std::vector<double> exposure_bracket;  // CaptureStage::Options::exposure_bracket
  bool auto_bracket = false;             // CaptureStage::Options::auto_bracket
  bool reconstruct = true;               // false for a one-view capture
  // The turn captured (scan_turns.h): 1, or a later one joined onto turn 1;
  // its views from first_view on. `turns`: all of the session's, this one
  // last (empty for a one-turn scan).
  int turn = 1;
  int first_view = 0;
  std::vector<TurnRecord> turns;
};

namespace {

// A scan's views, step and bracket from `request` (StartScan's rules), the
// defaults where it gives none; false with *error.
bool ScanShape(const ScanRequest& request, int default_views, double default_step_deg,
               const std::vector<double>& default_bracket, int* views, double* step,
               std::vector<double>* bracket, std::string* error) {
  *views = request.views > 0 ? request.views : default_views;
  if (*views < 2 || *views > 360) return Fail(error, "views must be in 2..360");
  // A step given wins; views without a step make one full turn; neither:
  // the defaults.
  *step = request.step_deg != 0 ? request.step_deg
          : request.views > 0   ? 360.0 / *views
                                : default_step_deg;
  if (!std::isfinite(*step) || std::abs(*step) < 0.1 || std::abs(*step) * (*views - 1) > 720) {
    return Fail(error, "step_deg must be finite, |step| >= 0.1 and span at most 720 degrees");
  }
  *bracket = request.exposure_bracket.value_or(default_bracket);
  if (std::string why; !IsValidExposureBracket(*bracket, &why)) {
    return Fail(error, "exposure_bracket: " + why);
  }
  return true;
}

// "turn 2: " for a later turn's messages; "" for turn 1.
std::string TurnLabel(int turn) { return turn > 1 ? "turn " + std::to_string(turn) + ": " : ""; }

}  // namespace

JobEngine::JobEngine(JobEngineOptions options, DeviceManager* devices, SessionStore* store,
                     JobSink* sink, std::function<void(drivers::LogLevel, std::string_view)> log,
                     ReportWriter report)
    : options_(std::move(options)),
      devices_(devices),
      store_(store),
      sink_(sink),
      log_(std::move(log)),
      report_(std::move(report)) {
  // Job ids carry the engine's start time (UTC HHMMSS): a client that
  // followed job-101500-1 of a daemon that then restarted does not take
  // the new daemon's first job for it.
  const std::time_t now = std::time(nullptr);
  std::tm tm{};
  gmtime_r(&now, &tm);
  char stamp[16];
  std::strftime(stamp, sizeof stamp, "%H%M%S", &tm);
  job_prefix_ = std::string("job-") + stamp + "-";
}

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

Status JobEngine::RecordState(Session& session, SessionState state, const std::string& detail) {
  Status set = session.SetState(state, detail);
  if (set.ok()) return set;
  if (set.code() == ErrorCode::kDiskFull && ::unlink(ReservePath(options_.data_dir).c_str()) == 0) {
    if (log_) {
      log_(drivers::LogLevel::kWarning,
           "disk full: freed the reserve to mark session " + session.id() + " " + ToString(state));
    }
    set = session.SetState(state, detail);
  }
  return set;
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
                       std::function<JobOutcome()> body, JobInfo* info, std::string* error) {
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
  current_.id = job_prefix_ + std::to_string(next_job_++);
  current_.verb = verb;
  current_.state = JobState::kRunning;
  current_.session = session;
  current_.stage = "starting";
  running_ = true;
  stop_ = false;
  if (info) *info = current_;
  worker_ = std::thread([this, body = std::move(body)] {
    JobOutcome outcome;
    try {
      outcome = body();
    } catch (const std::exception& e) {
      outcome = {JobState::kFailed, std::string("internal error: ") + e.what(), {}};
    } catch (...) {
      outcome = {JobState::kFailed, "internal error: unknown exception", {}};
    }
    Finish(std::move(outcome));
  });
  return true;
}

StageContext JobEngine::Context(Session* session) {
  StageContext context;
  context.session = session;
  context.sink = sink_;
  context.progress = [this](const std::string& stage, int current, int total,
                            const std::string& message) {
    SetStage(stage, current, total, message);
  };
  context.log = log_;
  context.stop = &stop_;
  return context;
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

void JobEngine::Finish(JobOutcome outcome) {
  if (outcome.state == JobState::kIdle || outcome.state == JobState::kRunning) {
    outcome = {JobState::kFailed, "job ended without a result", {}};  // a bug in a Run*
  }
  std::string job;
  {
    std::lock_guard lock(mutex_);
    current_.state = outcome.state;
    current_.message = outcome.message;
    current_.result = std::move(outcome.result);
    if (outcome.state == JobState::kDone) current_.progress = 1;
    running_ = false;
    job = current_.id;
    idle_.notify_all();
  }
  if (log_) {
    log_(outcome.state == JobState::kDone ? drivers::LogLevel::kInfo : drivers::LogLevel::kWarning,
         job + " " + std::string(ToString(outcome.state)) + ": " + outcome.message);
  }
  if (sink_) sink_->Progress(job, std::string(ToString(outcome.state)), 1, 1, outcome.message);
}

bool JobEngine::Cancel(std::string* error) {
  {
    std::lock_guard lock(mutex_);
    if (!running_) return Fail(error, "no job is running");
    stop_ = true;
  }
  // A move can take many seconds: stop the table (the driver's feed hold)
  // instead of waiting for it. The job then ends "cancelled" at that view.
  if (moving_) devices_->AbortMove();
  return true;
}

void JobEngine::Shutdown() {
  stop_ = true;
  if (moving_) devices_->AbortMove();
  if (worker_.joinable()) worker_.join();
}

// --- scan, capture, resume -------------------------------------------------

bool JobEngine::StartScan(const ScanRequest& request, JobInfo* info, std::string* error) {
  if (!request.add_to.empty()) return StartAddTurn(request, info, error);
  // Neither views nor step: the configured scan.views and scan.step_deg.
  int views = 0;
  double step = 0;
  std::vector<double> bracket;
  if (!ScanShape(request, options_.default_views, options_.default_step_deg,
                 options_.exposure_bracket, &views, &step, &bracket, error))
    return false;
  const std::optional<StereoCalibration> calibration = this->calibration();
  if (!calibration)
    return Fail(error, "no calibration: run calibrate and calibrate-turntable first");
  if (!calibration->turntable.valid) {
    return Fail(error, "the calibration has no turntable axis: run calibrate-turntable first");
  }
  auto plan = std::make_shared<ScanPlan>();
  plan->calibration = *calibration;
  plan->views = views;
  plan->step_deg = step;
  plan->exposure_bracket = bracket;
  plan->auto_bracket = AutoBracket(request, bracket);
  const nlohmann::json params = {{"views", views},
                                 {"step_deg", step},
                                 {"exposure_bracket", BracketJson(bracket)},
                                 {"auto_bracket", plan->auto_bracket},
                                 {"client", request.client},
                                 {"calibration_id", calibration_id()}};
  return StartSessionJob("scan", request.object, params, std::move(plan), info, error);
}

bool JobEngine::StartCapture(const std::string& object, JobInfo* info, std::string* error) {
  const std::optional<StereoCalibration> calibration = this->calibration();
  if (!calibration) return Fail(error, "no calibration: run calibrate first");
  auto plan = std::make_shared<ScanPlan>();
  plan->calibration = *calibration;
  plan->views = 1;
  plan->step_deg = 0;
  plan->exposure_bracket = options_.exposure_bracket;
  plan->auto_bracket = AutoBracket(ScanRequest{}, plan->exposure_bracket);
  plan->reconstruct = false;
  const nlohmann::json params = {{"views", 1},
                                 {"step_deg", 0},
                                 {"exposure_bracket", BracketJson(plan->exposure_bracket)},
                                 {"auto_bracket", plan->auto_bracket}};
  return StartSessionJob("capture", object, params, std::move(plan), info, error);
}

bool JobEngine::StartSessionJob(const std::string& verb, const std::string& object,
                                nlohmann::json params, std::shared_ptr<ScanPlan> plan,
                                JobInfo* info, std::string* error) {
  if (Busy()) return Fail(error, "busy: " + Current().id + " (" + Current().verb + ") is running");
  SessionStore* store = Store(error);
  if (!store) return false;
  EnsureReserve();
  Status created;
  plan->session = store->Create(object, verb, params, std::chrono::system_clock::now(), &created);
  if (!plan->session) {
    return Fail(error, created.message() + StorageAdvice(created, options_.data_dir, "try again"));
  }
  const Status copied = plan->session->CopyCalibration(
      options_.data_dir + "/calibration/current.yaml", calibration_id());
  if (!copied.ok()) {
    RecordState(*plan->session, SessionState::kFailed, copied.message());
    return Fail(error, copied.message() + StorageAdvice(copied, options_.data_dir, "try again"));
  }
  const std::string session = plan->session->id();
  return Launch(
      verb, session, [this, plan] { return RunScan(plan); }, info, error);
}

bool JobEngine::StartAddTurn(const ScanRequest& request, JobInfo* info, std::string* error) {
  if (Busy()) return Fail(error, "busy: " + Current().id + " (" + Current().verb + ") is running");
  SessionStore* store = Store(error);
  if (!store) return false;
  JoinFinishedWorker();  // the last job's session lock goes with its thread
  const std::string& id = request.add_to;
  auto plan = std::make_shared<ScanPlan>();
  Status opened;
  plan->session = store->OpenSession(id, &opened);
  if (!plan->session) return Fail(error, "add_to: " + opened.message());
  const Manifest manifest = plan->session->manifest();
  if (manifest.job != "scan") {
    return Fail(error, "add_to: session " + id + " is a " + manifest.job +
                           " session; only a scan's session takes another turn");
  }
  std::string why;
  if (!SessionTurns(manifest, &plan->turns, &why)) return Fail(error, "add_to: " + why);
  if (manifest.state != SessionState::kDone) {
    const bool first = plan->turns.size() == 1;
    return Fail(error, "add_to: session " + id + " is " + ToString(manifest.state) + ": its " +
                           (first ? std::string("first turn")
                                  : "turn " + std::to_string(plan->turns.size())) +
                           " is not finished (resume it first)");
  }
  for (const TurnRecord& t : plan->turns) {
    if (t.state == "joined") {
      return Fail(error, "add_to: session " + id + " already has turn " + std::to_string(t.turn) +
                             " joined onto turn 1 (a session joins two turns); scan the object "
                             "anew for another");
    }
  }
  // Neither views nor step: the first turn's.
  int views = 0;
  double step = 0;
  std::vector<double> bracket;
  if (!ScanShape(request, plan->turns.front().views, plan->turns.front().step_deg,
                 options_.exposure_bracket, &views, &step, &bracket, error))
    return false;
  const TurnRecord& last = plan->turns.back();
  TurnRecord turn;
  turn.turn = last.turn + 1;
  turn.first_view = last.first_view + last.views;
  turn.views = views;
  turn.step_deg = step;
  turn.state = "capturing";
  turn.extra = {{"exposure_bracket", BracketJson(bracket)},
                {"auto_bracket", AutoBracket(request, bracket)},
                {"client", request.client}};
  if (turn.first_view + views - 1 > kMaxViewIndex) {
    return Fail(error, "add_to: session " + id + " has no room for " + std::to_string(views) +
                           " more views (view numbers end at " + std::to_string(kMaxViewIndex) +
                           ")");
  }
  if (!LoadCalibration(plan->session->dir() + "/calibration.yaml", &plan->calibration, error))
    return false;
  if (!plan->calibration.turntable.valid)
    return Fail(error, "add_to: session " + id + "'s calibration has no turntable axis");
  plan->turns.push_back(turn);
  nlohmann::json params = manifest.params;
  params["turns"] = TurnsJson(plan->turns);
  EnsureReserve();
  const Status reopened = plan->session->ReopenForTurn(
      params, "turn " + std::to_string(turn.turn) + ": " + std::to_string(views) +
                  " views from view " + std::to_string(turn.first_view) +
                  ", the object laid in another pose");
  if (!reopened.ok()) {
    return Fail(error,
                reopened.message() + StorageAdvice(reopened, options_.data_dir, "try again"));
  }
  plan->views = views;
  plan->step_deg = step;
  plan->exposure_bracket = bracket;
  plan->auto_bracket = AutoBracket(request, bracket);
  plan->turn = turn.turn;
  plan->first_view = turn.first_view;
  if (!Launch(
          "scan", id, [this, plan] { return RunScan(plan); }, info, error))
    return false;
  NoteTurn(plan->turn, info);
  return true;
}

void JobEngine::NoteTurn(int turn, JobInfo* info) {
  std::lock_guard lock(mutex_);
  current_.turn = turn > 1 ? turn : 0;
  if (info) info->turn = current_.turn;
}

bool JobEngine::StartResume(const std::string& session_id, JobInfo* info, std::string* error) {
  if (Busy()) return Fail(error, "busy: " + Current().id + " (" + Current().verb + ") is running");
  SessionStore* store = Store(error);
  if (!store) return false;
  JoinFinishedWorker();  // the last job's session lock goes with its thread
  EnsureReserve();
  auto plan = std::make_shared<ScanPlan>();
  Status opened;
  plan->session = store->OpenSession(session_id, &opened);
  if (!plan->session) return Fail(error, opened.message());
  const SessionState state = plan->session->state();
  if (state == SessionState::kDone)
    return Fail(error, "session " + session_id + " is already done");
  if (IsActive(state)) {
    // Its lock is ours, so no job runs it: the one that did could not
    // record its end (e.g. the disk was full).
    const Status marked =
        RecordState(*plan->session, SessionState::kInterrupted,
                    std::string("found ") + ToString(state) + " with no job running it");
    if (!marked.ok()) {
      return Fail(error, marked.message() + StorageAdvice(marked, options_.data_dir, "resume it"));
    }
  }
  const nlohmann::json params = plan->session->params();
  plan->views = params.value("views", 0);
  plan->step_deg = params.value("step_deg", 0.0);
  // Sessions from before bracketing have none: one exposure, as they began.
  const nlohmann::json bracket = params.value("exposure_bracket", nlohmann::json::array());
  std::string why;
  bool bracket_ok = bracket.is_array();
  for (const nlohmann::json& m : bracket_ok ? bracket : nlohmann::json::array()) {
    bracket_ok = bracket_ok && m.is_number();
    if (bracket_ok) plan->exposure_bracket.push_back(m.get<double>());
  }
  if (!bracket_ok || !IsValidExposureBracket(plan->exposure_bracket, &why)) {
    return Fail(error, "session " + session_id + ": manifest's exposure_bracket is invalid" +
                           (why.empty() ? "" : ": " + why));
  }
  // Sessions from before automatic bracketing: none.
  const auto auto_bracket_of = [](const nlohmann::json& j) {
    const auto it = j.find("auto_bracket");
    return it != j.end() && it->is_boolean() && it->get<bool>();
  };
  plan->auto_bracket = auto_bracket_of(params);
  plan->reconstruct = plan->session->manifest().job == "scan";
  if (plan->session->manifest().params.contains("turns")) {
    // A later turn: the last one, where it stopped (turn 1 was done before it began).
    if (!SessionTurns(plan->session->manifest(), &plan->turns, &why)) return Fail(error, why);
    TurnRecord& last = plan->turns.back();
    last.state = "capturing";
    plan->turn = last.turn;
    plan->first_view = last.first_view;
    plan->views = last.views;
    plan->step_deg = last.step_deg;
    plan->exposure_bracket.clear();
    for (const nlohmann::json& m : last.extra.value("exposure_bracket", nlohmann::json::array()))
      if (m.is_number()) plan->exposure_bracket.push_back(m.get<double>());
    plan->auto_bracket = auto_bracket_of(last.extra);
  }
  if (plan->views < 1) return Fail(error, "session " + session_id + ": manifest has no view count");
  if (!LoadCalibration(plan->session->dir() + "/calibration.yaml", &plan->calibration, error)) {
    return false;
  }
  if (!Launch(
          "resume", session_id, [this, plan] { return RunScan(plan); }, info, error))
    return false;
  NoteTurn(plan->turn, info);
  return true;
}

JobEngine::JobOutcome JobEngine::RunScan(const std::shared_ptr<ScanPlan>& plan) {
  const std::string sid = plan->session->id();
  JobOutcome outcome;
  try {
    outcome = RunScanStages(*plan);
  } catch (const std::exception& e) {
    outcome = {
        JobState::kFailed, "session " + sid + ": internal error: " + e.what(), {{"session", sid}}};
  } catch (...) {
    outcome = {JobState::kFailed,
               "session " + sid + ": internal error: unknown exception",
               {{"session", sid}}};
  }
  // The session is closed -- its lock released -- before the job is
  // announced as ended (Finish, by the caller), so a client told "done" or
  // "failed" can open it at once (resume, craftscan-record, another process).
  plan->session.reset();
  return outcome;
}

namespace {

// Turns an exception escaping a stage's thread into its outcome.
template <class Run>
auto Guarded(const char* stage, bool resumable, Run run) -> decltype(run()) {
  const auto failed = [&](const std::string& what) {
    decltype(run()) out{};
    if constexpr (std::is_same_v<decltype(out), StageOutcome>) {
      out = StageOutcome::Error(ErrorCode::kInternal, stage + (": " + what), resumable);
    } else {
      out.status = StageOutcome::Error(ErrorCode::kInternal, stage + (": " + what), resumable);
    }
    return out;
  };
  try {
    return run();
  } catch (const std::exception& e) {
    return failed(e.what());
  } catch (...) {
    return failed("unknown exception");
  }
}

// The outcome of stages running together: the first failure, else a
// cancel, else ok. Thread-safe.
class CombinedOutcome {
 public:
  void Add(const StageOutcome& outcome) {
    std::lock_guard lock(mutex_);
    if (outcome.cancelled()) {
      cancelled_ = true;
    } else if (!outcome.ok() && !failure_) {
      failure_ = outcome;
    }
  }
  StageOutcome Result() const {
    std::lock_guard lock(mutex_);
    if (failure_) return *failure_;
    return cancelled_ ? StageOutcome::Cancelled() : StageOutcome::Ok();
  }

 private:
  mutable std::mutex mutex_;
  std::optional<StageOutcome> failure_;
  bool cancelled_ = false;
};

}  // namespace

JobEngine::JobOutcome JobEngine::RunScanStages(ScanPlan& plan) {
  Session& session = *plan.session;
  const std::string sid = session.id();
  std::string error;
  ViewProcessor processor;
  ViewProcessorOptions view_options = options_.view;
  view_options.num_threads = options_.threads;
  if (!processor.Init(plan.calibration, view_options, &error)) {
    return EndSession(session, StageOutcome::Error(ErrorCode::kInvalidArgument, error, false));
  }
  if (session.state() != SessionState::kCapturing) {  // a turn added is capturing already
    if (Status set = session.SetState(SessionState::kCapturing, "job " + Current().id); !set.ok()) {
      return {JobState::kFailed,
              set.message() + StorageAdvice(set, options_.data_dir, "resume " + sid),
              {{"session", sid}}};
    }
  }
  const std::string label = TurnLabel(plan.turn);
  if (plan.turn > 1) {
    if (StageOutcome kept = KeepFirstTurnOutputs(session); !kept.ok())
      return EndSession(session, kept);
  }
  // The sim lays the object as the operator did for this turn.
  if (plan.turn > 1) SetStage("capture", 0, plan.views, label + "the object in its new pose");
  if (const drivers::DriverStatus shown = devices_->ShowTurn(plan.turn); !shown.ok()) {
    return EndSession(session,
                      StageOutcome::Error(ToErrorCode(shown.code), label + shown.message, true));
  }

  BoundedQueue<CapturedView> q1(static_cast<std::size_t>(options_.queue_capacity));
  BoundedQueue<MatchedView> q2(static_cast<std::size_t>(options_.queue_capacity));
  CombinedOutcome combined;
  // A stage that failed stops the others; one that ended closes its output.
  const auto ended = [&](const StageOutcome& outcome, auto& output) {
    combined.Add(outcome);
    if (!outcome.ok()) {
      stop_ = true;
      q1.Close();
      q2.Close();
    }
    output.Close();
  };
  const StageContext context = Context(&session);
  CaptureStage::Options capture_options{
      plan.views, plan.step_deg, options_.settle, plan.exposure_bracket, plan.first_view,
      plan.turn,  label};
  if (plan.auto_bracket) {
    capture_options.auto_bracket = true;
    capture_options.auto_bracket_region =
        PlatterRegionMask(plan.calibration, options_.view.platter_radius_mm);
  }
  CaptureStage capture(context, devices_, std::move(capture_options), &moving_);
  MatchStage match(context, &processor, &plan.calibration, plan.views, plan.first_view, label);
  ReconstructStage::Options build;
  build.views = plan.views;
  build.step_deg = plan.step_deg;
  build.scan = options_.scan;
  build.scan.num_threads = options_.threads;
  build.min_disparity = processor.min_disparity();
  build.num_disparities = processor.num_disparities();
  build.station = options_.station;
  build.software = options_.software;
  build.rights = options_.rights;
  build.first_view = plan.first_view;
  build.turn = plan.turn;
  build.label = label;
  build.turns = plan.turns;
  build.join.num_threads = std::max(1, options_.threads);
  const bool offered = options_.remote != nullptr && plan.turn == 1 && plan.reconstruct &&
                       (options_.reconstruction == ReconstructionMode::kRemote ||
                        (options_.reconstruction == ReconstructionMode::kAuto &&
                         options_.remote->WorkersIdle() > 0));
  if (offered) {
    build.remote = options_.remote;
    build.remote_config = options_.remote_config;
    build.remote_offer_timeout = options_.remote_offer_timeout;
    build.remote_max = options_.remote_max;
    build.on_remote = options_.on_remote;
  }
  ReconstructStage reconstruct(context, &plan.calibration, std::move(build), report_);

  std::thread matcher(
      [&] { ended(Guarded("matching", false, [&] { return match.Run(q1, q2); }), q2); });
  ReconstructOutcome built;
  std::thread builder([&] {
    if (plan.reconstruct) {
      built = Guarded("reconstruction", false, [&] { return reconstruct.Run(q2); });
    } else {
      CollectViews(q2, plan.views);
      if (stop_) built.status = StageOutcome::Cancelled();
    }
    combined.Add(built.status);
  });
  ended(Guarded("capture", true, [&] { return capture.Run(q1); }), q1);
  matcher.join();
  builder.join();

  const StageOutcome outcome = combined.Result();
  if (!outcome.ok() && plan.turn > 1 && !outcome.resumable)
    return EndTurnNotJoined(plan, outcome, built.join_status,
                            built.result.value("turn_join", nlohmann::json()));
  if (!outcome.ok()) return EndSession(session, outcome);
  nlohmann::json result = {{"session", sid},
                           {"views", plan.views},
                           {"capture_ms", capture.capture_ms()},
                           {"match_ms", match.match_ms()}};
  if (plan.turn > 1) {
    plan.turns.back().state = "joined";
    plan.turns.back().extra["join"] = built.result.value("turn_join", nlohmann::json());
    plan.turns.back().extra.erase("message");
    nlohmann::json params = session.params();
    params["turns"] = TurnsJson(plan.turns);
    if (Status set = session.SetParams(params, label + "joined onto turn 1"); !set.ok())
      return EndSession(session, StageOutcome::Storage(set, label));
    result["turns"] = params["turns"];
  }
  if (!plan.reconstruct) {
    return EndSessionDone(session, "capture stored", "the view is stored",
                          {JobState::kDone, "session " + sid + ": 1 view captured", result});
  }
  result.update(built.result);
  return EndSessionDone(session, built.done_detail, "the outputs are stored",
                        {JobState::kDone, "session " + sid + ": " + built.summary, result});
}

StageOutcome JobEngine::KeepFirstTurnOutputs(Session& session) {
  const Manifest manifest = session.manifest();
  for (const auto& [name, record] : manifest.outputs) {
    if (name.rfind("turn", 0) == 0 && name.find('/') != std::string::npos) continue;  // a turn's
    const std::string kept = "turn1/" + name;
    if (manifest.outputs.count(kept)) continue;
    std::string bytes, why;
    if (!session.LoadOutput(name, &bytes, &why)) {
      return StageOutcome::Error(ErrorCode::kCorrupt, "turn 1's " + name + ": " + why, false);
    }
    if (Status stored = session.StoreOutput(kept, bytes); !stored.ok())
      return StageOutcome::Storage(stored, "keeping turn 1's outputs: ");
  }
  return StageOutcome::Ok();
}

JobEngine::JobOutcome JobEngine::EndTurnNotJoined(ScanPlan& plan, const StageOutcome& outcome,
                                                  std::optional<TurnJoinResult::Status> join_status,
                                                  const nlohmann::json& join) {
  Session& session = *plan.session;
  const std::string sid = session.id();
  TurnRecord& turn = plan.turns.back();
  const bool refused = join_status == TurnJoinResult::Status::kRefusedOverlap ||
                       join_status == TurnJoinResult::Status::kRefusedAmbiguous;
  turn.state = refused ? "refused" : "failed";
  turn.extra["message"] = outcome.message;
  if (join.is_object()) turn.extra["join"] = join;
  nlohmann::json params = session.params();
  params["turns"] = TurnsJson(plan.turns);
  const std::string label = TurnLabel(turn.turn);
  Status recorded = session.SetParams(params, label + turn.state + ": " + outcome.message);
  if (recorded.ok()) {
    recorded = RecordState(session, SessionState::kDone,
                           label + turn.state + "; the model is turn 1's (turn1/ and the outputs)");
  }
  std::string message =
      "session " + sid + ": " + outcome.message + "; the session keeps turn 1's model";
  if (refused) {
    message +=
        ": lay the object differently (so that more of what turn 1 saw is seen again, "
        "and a distinctive part) and add another turn: craftscanctl scan --add-to " +
        sid;
  }
  if (!recorded.ok()) message += "; it could not be recorded: " + recorded.message();
  nlohmann::json result = {{"session", sid}, {"turn", turn.turn}, {"turn_state", turn.state}};
  if (join.is_object()) result["turn_join"] = join;
  return {JobState::kFailed, message, result};
}

JobEngine::JobOutcome JobEngine::EndSession(Session& session, const StageOutcome& outcome) {
  const std::string sid = session.id();
  const SessionState state = outcome.resumable ? SessionState::kInterrupted : SessionState::kFailed;
  std::string message = outcome.message;
  if (outcome.storage) message += StorageAdvice(outcome.code, options_.data_dir, "resume " + sid);
  const Status marked = RecordState(session, state, outcome.message);
  const bool recorded = marked.ok();
  if (!recorded) {
    message += "; it could not be marked " + std::string(ToString(state)) + " (" +
               marked.message() + "): resume marks it";
  }
  return {outcome.cancelled() ? JobState::kCancelled : JobState::kFailed,
          "session " + sid + " " + (recorded ? ToString(state) : "stopped") + ": " + message,
          {{"session", sid}}};
}

JobEngine::JobOutcome JobEngine::EndSessionDone(Session& session, const std::string& detail,
                                                const std::string& stored, JobOutcome done) {
  const Status marked = RecordState(session, SessionState::kDone, detail);
  if (marked.ok()) return done;
  return {JobState::kFailed,
          "session " + session.id() + ": " + stored +
              " but the session could not be marked done: " + marked.message() +
              StorageAdvice(marked, options_.data_dir, "resume " + session.id()),
          {{"session", session.id()}}};
}

// --- calibration -------------------------------------------------------------

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

bool PreviewRequest::IsValid(std::string* why) const {
  if (!(fps > 0 && fps <= 15)) return Fail(why, "fps: must be in (0, 15]");
  if (width < 64 || width > 4096) return Fail(why, "width: must be 64..4096");
  if (!(seconds > 0 && seconds <= 600)) return Fail(why, "seconds: must be in (0, 600]");
  return true;
}

namespace {
std::int64_t SteadyNs() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(
             std::chrono::steady_clock::now().time_since_epoch())
      .count();
}
}  // namespace

std::int64_t WallNow() { return WallStamp(SteadyNs()); }

std::int64_t WallStamp(std::int64_t steady_ns) {
  const std::int64_t wall = std::chrono::duration_cast<std::chrono::nanoseconds>(
                                std::chrono::system_clock::now().time_since_epoch())
                                .count();
  const std::int64_t age = SteadyNs() - steady_ns;
  // A frame stamped on the steady clock a moment ago: its wall time. Any
  // other stamp (a simulated clock): now.
  return age >= 0 && age < std::int64_t{10'000'000'000} ? wall - age : wall;
}

bool JobEngine::StartPreview(const PreviewRequest& request, JobInfo* info, std::string* error) {
  if (!request.IsValid(error)) return false;
  const auto until = SteadyNs() + static_cast<std::int64_t>(request.seconds * 1e9);
  {
    std::lock_guard lock(mutex_);
    if (running_ && current_.verb == "preview") {
      preview_until_ns_ = until;
      if (info) *info = current_;
      return true;
    }
  }
  preview_until_ns_ = until;
  {
    std::lock_guard lock(mutex_);
    last_preview_ = request;
  }
  return Launch(
      "preview", "", [this, request] { return RunPreview(request); }, info, error);
}

PreviewRequest JobEngine::LastPreviewRequest() const {
  std::lock_guard lock(mutex_);
  return last_preview_;
}

bool JobEngine::StopPreview(std::chrono::milliseconds timeout) {
  {
    std::lock_guard lock(mutex_);
    if (!running_ || current_.verb != "preview") return true;
    stop_ = true;
  }
  return WaitIdle(timeout);
}

JobEngine::JobOutcome JobEngine::RunPreview(const PreviewRequest& request) {
  const std::string job_id = Current().id;
  const auto period = std::chrono::nanoseconds(static_cast<std::int64_t>(1e9 / request.fps));
  SetStage("preview", 0, 0,
           "streaming both cameras at " + std::to_string(static_cast<int>(request.fps + 0.5)) +
               " frames/s until stopped");
  std::uint32_t sequence = 0;
  while (!stop_ && SteadyNs() < preview_until_ns_) {
    const auto next = std::chrono::steady_clock::now() + period;
    drivers::StereoFrame frame;
    const drivers::DriverStatus s = devices_->Capture(&frame, stop_);
    if (stop_) break;
    if (!s.ok()) return {JobState::kFailed, "preview: " + s.message, {{"frames", sequence}}};
    const std::int64_t ready_ns = WallNow();
    PreviewFrame p = MakePreviewFrame(frame.left.image, frame.right.image, request.width);
    p.job_id = job_id;
    p.sequence = sequence++;
    p.stamp_ns = WallStamp(frame.left.timestamp_ns);
    p.ready_ns = ready_ns;
    p.exposure_us = frame.settings.exposure_us;
    p.gain_db = frame.settings.gain_db;
    if (sink_) sink_->Preview(p);
    while (!stop_ && std::chrono::steady_clock::now() < next) {
      std::this_thread::sleep_for(std::min<std::chrono::nanoseconds>(
          std::chrono::milliseconds(20), next - std::chrono::steady_clock::now()));
    }
  }
  const std::string summary = "preview: " + std::to_string(sequence) + " frames";
  if (stop_) return {JobState::kCancelled, summary + ", stopped", {{"frames", sequence}}};
  return {JobState::kDone,
          summary + ", no request for " + std::to_string(static_cast<int>(request.seconds)) + " s",
          {{"frames", sequence}}};
}

bool JobEngine::StartCalibrate(JobInfo* info, std::string* error) {
  return Launch(
      "calibrate", "", [this] { return RunCalibrate(); }, info, error);
}

bool JobEngine::StartCalibrateTurntable(JobInfo* info, std::string* error) {
  if (!calibration()) return Fail(error, "no calibration: run calibrate first");
  return Launch(
      "calibrate-turntable", "", [this] { return RunCalibrateTurntable(); }, info, error);
}

JobEngine::JobOutcome JobEngine::RunCalibrate() {
  CalibrateStage::Options o{options_.data_dir,          options_.board,
                            options_.calibration_views, options_.calibration_max_attempts,
                            options_.max_rms_px,        options_.calibration};
  o.guided = options_.calibration_guided;
  o.guided_max_s = options_.calibration_guided_max_s;
  o.job_id = Current().id;
  CalibrateStage stage(Context(nullptr), devices_, o);
  return EndCalibration("calibrate", stage.Run());
}

CalibrateTurntableStage::Options JobEngine::TurntableOptions() {
  CalibrateTurntableStage::Options o{options_.data_dir, options_.turntable_board,
                                     options_.turntable_angles_deg, options_.settle,
                                     options_.turntable_board_thickness_mm};
  o.guided = options_.calibration_guided;
  o.guided_max_s = options_.calibration_guided_max_s;
  o.job_id = Current().id;
  return o;
}

JobEngine::JobOutcome JobEngine::RunCalibrateTurntable() {
  CalibrateTurntableStage stage(Context(nullptr), devices_, TurntableOptions(), *calibration(),
                                &moving_);
  return EndCalibration("calibrate-turntable", stage.Run());
}

JobEngine::JobOutcome JobEngine::EndCalibration(const std::string& verb,
                                                CalibrationOutcome outcome) {
  if (outcome.status.cancelled()) return {JobState::kCancelled, outcome.status.message, {}};
  if (!outcome.status.ok()) {
    return {JobState::kFailed, outcome.status.message, std::move(outcome.result)};
  }
  std::string error;
  if (!outcome.accepted || !SetCurrentCalibration(*outcome.accepted, outcome.id, &error)) {
    return {JobState::kFailed, verb + ": " + error, std::move(outcome.result)};
  }
  return {JobState::kDone, outcome.summary, std::move(outcome.result)};
}

}  // namespace craftscan::daemon
