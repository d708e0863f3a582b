#include "craftscan/daemon/daemon.h"

#include <malloc.h>

#include <chrono>
#include <optional>
#include <thread>
#include <utility>

#include <spdlog/spdlog.h>

#include "craftscan/daemon/auth.h"
#include "craftscan/daemon/commands.h"
#include "craftscan/daemon/devices.h"
#include "craftscan/daemon/jobs.h"
#include "craftscan/daemon/notify.h"
#include "craftscan/daemon/remote_jobs.h"
#include "craftscan/daemon/report.h"
#include "craftscan/daemon/session_store.h"
#include "dds_bridge.h"

namespace craftscan::daemon {
namespace {

using Clock = std::chrono::steady_clock;

// How often an unusable data directory is tried again (like the devices).
constexpr std::chrono::seconds kStoreRetryInterval{10};
// How often devices that failed to open are tried again (while no job runs).
constexpr std::chrono::seconds kDeviceRetryInterval{10};
// How long the command loop waits for a command before its periodic work.
constexpr std::chrono::milliseconds kCommandWait{100};
// StationStatus (and SiteStation) is republished at least this often,
// changed or not; SiteStation also at least every SiteWriter::kRenewInterval
// (its liveliness lease).
constexpr std::chrono::seconds kStatusInterval{1};
// A running job silent for longer is taken for a hung driver call: the
// watchdog pings stop, systemd restarts the daemon, the session resumes.
constexpr std::chrono::minutes kJobSilenceLimit{10};

void Log(drivers::LogLevel level, std::string_view message) {
  switch (level) {
    case drivers::LogLevel::kDebug:
      spdlog::debug("{}", message);
      break;
    case drivers::LogLevel::kInfo:
      spdlog::info("{}", message);
      break;
    case drivers::LogLevel::kWarning:
      spdlog::warn("{}", message);
      break;
    case drivers::LogLevel::kError:
      spdlog::error("{}", message);
      break;
  }
}

// Logs refused commands without letting a flood flood the log (commands.h,
// "Floods"): at most kRefusalLogsPerSecond one by one; the rest are counted
// and summed up once a second. Not thread-safe (the command loop's).
class RefusalLog {
 public:
  explicit RefusalLog(Clock::time_point now)
      : bucket_(kRefusalLogsPerSecond, 2 * kRefusalLogsPerSecond, now), last_summary_(now) {}

  // Logs `reply` to a `verb` received at `received` if it is a refusal.
  void Note(const CommandReply& reply, std::string_view verb, Clock::time_point received) {
    if (reply.code == ReplyCode::kOk) return;
    if (bucket_.Take(received)) {
      spdlog::info("command {} '{}' from '{}': {}: {}", reply.request_id, verb.substr(0, 64),
                   reply.client, ToString(reply.code), reply.message);
    } else {
      ++unlogged_;
    }
  }
  // Logs how many refusals went unlogged, once a second at most.
  void Summarize(Clock::time_point now) {
    if (unlogged_ == 0 || now - last_summary_ < std::chrono::seconds(1)) return;
    spdlog::warn(
        "{} more commands refused in the last second(s), not logged one by one "
        "(is a client flooding?)",
        unlogged_);
    unlogged_ = 0;
    last_summary_ = now;
  }

 private:
  static constexpr double kRefusalLogsPerSecond = 10;
  TokenBucket bucket_;
  std::size_t unlogged_ = 0;
  Clock::time_point last_summary_;
};

}  // namespace

std::string_view ToString(StationState state) {
  switch (state) {
    case StationState::kStarting:
      return "starting";
    case StationState::kIdle:
      return "idle";
    case StationState::kBusy:
      return "busy";
    case StationState::kDegraded:
      return "degraded";
    case StationState::kError:
      return "error";
    case StationState::kStopping:
      return "stopping";
  }
  return "error";
}

StationState StationStateFrom(const StationFacts& facts) {
  if (facts.stopping) return StationState::kStopping;
  if (!facts.devices_tried) return StationState::kStarting;
  if (facts.job_running) return StationState::kBusy;
  if (!facts.devices_open) return StationState::kError;
  if (!facts.store_open) return StationState::kDegraded;
  return StationState::kIdle;
}

struct Daemon::Impl {
  DaemonConfig config;
  SystemdNotifier notifier;
  std::unique_ptr<SessionStore> store;
  std::optional<TokenAuthority> tokens;
  std::shared_ptr<dds::Participant> participant;
  // Reconstruction on the site's workers (reconstruction.mode remote/auto).
  std::unique_ptr<RemoteJobs> remote;
  StatusWriter status_writer;
  SiteWriter site;  // this station on the site's topic; the job protocol sets its remote job
  CommandChannel commands;
  DdsPublisher publisher;
  FileSender files;
  std::unique_ptr<DeviceManager> devices;
  std::unique_ptr<JobEngine> jobs;
  std::unique_ptr<CommandHandler> handler;
  std::atomic<bool> status_dirty{true};
  std::string last_error;
  // Why the session store is not open ("" when it is): the station serves
  // degraded (status, devices) and OpenStore() is retried.
  std::string storage_error;
  // Set only by UpdateState(), from devices_tried, stopping and what the
  // devices, jobs and store say.
  StationState state = StationState::kStarting;
  bool devices_tried = false;
  bool stopping = false;

  // What the command loop remembers between turns (Run's thread only).
  struct LoopClocks {
    std::chrono::microseconds ping_interval{0};  // 0: no watchdog
    Clock::time_point last_ping{}, last_status, last_store_try, last_open_try;
    Clock::time_point trim_at = Clock::time_point::max();  // see TrimAfterJob
    std::string last_job_state, last_summary;
  } loop;
  CommandRateLimiter rate_limiter;
  ReplyMemory replies;                // the last replies, for commands sent again
  RefusalLog refusals{Clock::now()};  // restarted by StartServing

  // What StationStatus and the status verb show.
  StationStatusFields Snapshot() const;
  nlohmann::json StatusJson() const;
  // StationStatus and SiteStation.
  void PublishStatus() {
    const StationStatusFields snapshot = Snapshot();
    status_writer.Publish(snapshot);
    site.Publish(snapshot);
  }
  // last_error and storage_error, as the status shows them.
  std::string Problems() const;
  // Tries to open the session store; on success marks unfinished sessions
  // interrupted and hands the store to the jobs and commands, else records
  // why in storage_error and has the commands refuse what needs it.
  bool OpenStore();
  // The one place `state` changes; marks the status dirty when it does.
  void UpdateState();

  // The participant on config.dds and the bridge's topics (dds_bridge.h).
  // False with *error.
  bool OpenDds(std::string* error);

  // The steps of Run().
  // Start-up: camera_info of the current calibration, the devices opened
  // (once; a failure is retried by RetryDevices), READY=1.
  void StartServing();
  void OpenDevices();
  // The command loop, one turn: ServeCommand waits up to kCommandWait for a
  // command and answers it; Tick does the periodic work, in this order:
  // device and store retries, the job followed, the state, the malloc trim,
  // STATUS=, StationStatus, WATCHDOG=1.
  void ServeCommand();
  void Answer(const CommandRequest& request, Clock::time_point received);
  void Tick(Clock::time_point now);
  void RetryDevices(Clock::time_point now);
  void RetryStore(Clock::time_point now);
  void FollowJob(const JobInfo& job);
  void TrimAfterJob(Clock::time_point now);
  void NotifySummary(const JobInfo& job);
  void PublishStatusIfDue(Clock::time_point now);
  void PingWatchdog(Clock::time_point now);
  // SIGTERM: STOPPING=1, the transfers dropped, the job checkpointed, the
  // devices closed.
  void ShutDown();
};

std::string Daemon::Impl::Problems() const {
  if (storage_error.empty()) return last_error;
  if (last_error.empty()) return storage_error;
  return last_error + "; " + storage_error;
}

bool Daemon::Impl::OpenStore() {
  Status opened;
  store = SessionStore::Open(config.data_dir, &opened);
  if (!store) {
    const std::string& why = opened.message();
    storage_error = "data_dir: " + why;
    handler->SetStore(nullptr, "storage unavailable: " + why + " (craftscand retries every " +
                                   std::to_string(kStoreRetryInterval.count()) + " s)");
    jobs->SetStore(nullptr);
    return false;
  }
  std::vector<std::string> problems;
  for (const std::string& id : store->MarkInterrupted(&problems)) {
    spdlog::warn("session {} was unfinished: marked interrupted", id);
  }
  for (const std::string& p : problems) spdlog::error("sessions: {}", p);
  storage_error.clear();
  jobs->SetStore(store.get());
  handler->SetStore(store.get(), "");
  return true;
}

void Daemon::Impl::UpdateState() {
  StationFacts facts;
  facts.stopping = stopping;
  facts.devices_tried = devices_tried;
  facts.devices_open = devices->IsOpen();
  facts.job_running = jobs->Busy();
  facts.store_open = store != nullptr;
  const StationState next = StationStateFrom(facts);
  if (next == state) return;
  state = next;
  status_dirty = true;
}

StationStatusFields Daemon::Impl::Snapshot() const {
  StationStatusFields s;
  s.station = config.station;
  s.state = state;
  s.devices = devices->Reports();
  s.job = jobs->Current();
  s.last_error = Problems();
  s.calibration_id = jobs->calibration_id();
  return s;
}

nlohmann::json Daemon::Impl::StatusJson() const {
  const StationStatusFields s = Snapshot();
  return {{"station", s.station},
          {"state", ToString(s.state)},
          {"devices", DevicesJson(s.devices)},
          {"job", JobJson(s.job)},
          {"last_error", s.last_error},
          {"storage",
           {{"data_dir", config.data_dir}, {"ok", store != nullptr}, {"error", storage_error}}},
          {"calibration_id", s.calibration_id}};
}

bool Daemon::Impl::OpenDds(std::string* error) {
  dds::ParticipantOptions options;
  options.domain_id = static_cast<std::uint32_t>(config.dds.domain);
  if (!config.dds.config_file.empty()) options.config = dds::ConfigFileUri(config.dds.config_file);
  participant = dds::Participant::Create(options, error);
  const std::string& station = config.station;
  return participant && status_writer.Create(participant, station, error) &&
         site.Create(participant, config.site, station, ToString(config.reconstruction.mode),
                     error) &&
         commands.Create(participant, station, error) &&
         publisher.Create(participant, station, error) && files.Create(participant, station, error);
}

Daemon::Daemon(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
Daemon::~Daemon() = default;

std::unique_ptr<Daemon> Daemon::Create(const DaemonConfig& config, std::string* error) {
  auto impl = std::make_unique<Impl>();
  impl->config = config;
  std::string why;
  if (!config.IsValid(&why)) {
    *error = "config: " + why;
    return nullptr;
  }
  impl->tokens = TokenAuthority::Load(config.auth.tokens_file, &why);
  if (!impl->tokens) {
    *error = "auth.tokens_file: " + why;
    return nullptr;
  }
  if (!impl->OpenDds(&why)) {
    *error = "dds: " + why;
    return nullptr;
  }

  DeviceSetup setup;
  setup.plugin_path = config.plugins.SearchPath();
  setup.camera = {config.devices.camera.driver, config.devices.camera.config};
  setup.turntable = {config.devices.turntable.driver, config.devices.turntable.config};
  setup.camera_settings.exposure_us = config.scan.exposure_us;
  setup.camera_settings.gain_db = config.scan.gain_db;
  Impl* raw = impl.get();
  impl->devices = std::make_unique<DeviceManager>(setup, Log, [raw] { raw->status_dirty = true; });

  JobEngineOptions jobs;
  jobs.data_dir = config.data_dir;
  jobs.station = config.station;
  jobs.software = std::string("craftscan ") + CRAFTSCAN_VERSION;
  jobs.rights = config.deliverables.rights;
  jobs.default_views = config.scan.views;
  jobs.default_step_deg = config.scan.step_deg;
  jobs.settle = std::chrono::milliseconds(config.scan.settle_ms);
  jobs.exposure_bracket = config.scan.exposure_bracket;
  jobs.auto_bracket = config.scan.auto_bracket;
  jobs.queue_capacity = config.limits.queue_capacity;
  jobs.threads = config.pipeline.threads;
  jobs.view = ViewOptions(config.pipeline);
  jobs.scan = ReconstructionOptions(config.pipeline);
  jobs.board = config.calibration.board;
  jobs.turntable_board = config.calibration.turntable_board;
  jobs.turntable_board_thickness_mm = config.calibration.turntable_board_thickness_mm;
  jobs.calibration_views = config.calibration.views;
  jobs.calibration_guided = config.calibration.guided;
  jobs.calibration_guided_max_s = config.calibration.guided_max_s;
  jobs.max_rms_px = config.calibration.max_rms_px;
  if (config.reconstruction.mode != ReconstructionMode::kLocal) {
    impl->remote = RemoteJobs::Create(impl->participant, config.site, config.station,
                                      &*impl->tokens, Log, &why);
    if (!impl->remote) {
      *error = "reconstruction: " + why;
      return nullptr;
    }
    jobs.remote = impl->remote.get();
    jobs.reconstruction = config.reconstruction.mode;
    jobs.remote_config = DumpDaemonConfig(config);
    jobs.remote_offer_timeout = std::chrono::milliseconds(config.reconstruction.offer_timeout_ms);
    jobs.remote_max = std::chrono::seconds(config.reconstruction.max_remote_s);
    SiteWriter* site = &impl->site;
    jobs.on_remote = [site](const std::string& job, const std::string& worker) {
      site->SetRemoteJob(job, worker);
    };
  }
  jobs.calibration.rectification.zero_disparity = false;
  impl->jobs = std::make_unique<JobEngine>(jobs, impl->devices.get(), impl->store.get(),
                                           &impl->publisher, Log, MakeReportFiles);
  if (!impl->jobs->LoadCurrentCalibration(&why)) {
    spdlog::error("calibration: {} (starting without one; run calibrate)", why);
    impl->last_error = "calibration: " + why;
  }
  CommandLimits limits;
  limits.max_argument_bytes = static_cast<std::size_t>(config.limits.max_command_bytes);
  impl->handler = std::make_unique<CommandHandler>(limits, &*impl->tokens, impl->jobs.get(),
                                                   impl->devices.get(), impl->store.get(),
                                                   [raw] { return raw->StatusJson(); });
  // An unusable data directory (read-only, missing, a disk not mounted yet)
  // is not fatal: the station serves degraded and Run() retries.
  if (!impl->OpenStore()) {
    spdlog::error("{} (serving without sessions; retrying every {} s)", impl->storage_error,
                  kStoreRetryInterval.count());
  }
  return std::unique_ptr<Daemon>(new Daemon(std::move(impl)));
}

int Daemon::Run() {
  Impl& d = *impl_;
  d.StartServing();
  while (!stop_.load()) {
    d.ServeCommand();
    d.Tick(Clock::now());
  }
  d.ShutDown();
  return 0;
}

void Daemon::Impl::StartServing() {
  if (const auto c = jobs->calibration()) publisher.CalibrationChanged(*c);
  notifier.Status("opening devices");
  PublishStatus();
  OpenDevices();
  // Ready once the devices were tried: a station without its hardware or
  // its data directory still serves what it can, and says why in STATUS=
  // and StationStatus.
  notifier.Ready(state == StationState::kIdle ? "ready: devices up" : "degraded: " + Problems());
  spdlog::info("craftscand serving station '{}' on DDS domain {}", config.station,
               config.dds.domain);
  loop.ping_interval =
      config.watchdog.enabled ? notifier.WatchdogPingInterval() : std::chrono::microseconds(0);
  loop.last_status = loop.last_store_try = Clock::now();
  refusals = RefusalLog(loop.last_status);
}

void Daemon::Impl::OpenDevices() {
  loop.last_open_try = Clock::now();
  std::string error;
  if (!devices->Open(&error)) {
    last_error = "devices: " + error;
    spdlog::error("devices: {} (retrying every {} s)", error, kDeviceRetryInterval.count());
  }
  devices_tried = true;
  UpdateState();
}

void Daemon::Impl::ServeCommand() {
  std::string error;
  CommandRequest request;
  const dds::TakeStatus taken = commands.Take(kCommandWait, handler->limits(), &request, &error);
  if (taken == dds::TakeStatus::kOk) {
    Answer(request, Clock::now());
  } else if (taken == dds::TakeStatus::kError) {
    spdlog::warn("command topic: {}", error);
    std::this_thread::sleep_for(kCommandWait);
  }
  refusals.Summarize(Clock::now());
}

void Daemon::Impl::Answer(const CommandRequest& request, Clock::time_point received) {
  // A command sent again (its first reply did not reach the client) gets
  // the reply it had; it is not run twice (ReplyMemory).
  bool known = false;
  if (const CommandReply* again = replies.Find(request, &known)) {
    spdlog::debug("command {} from '{}' sent again: its reply repeated", again->request_id,
                  again->client);
    commands.Reply(*again);
    return;
  }
  if (known) return;  // repeated more than kMaxReplyRepeats times: dropped
  CommandReply reply = rate_limiter.Admit(request.client, received)
                           ? handler->Handle(request)
                           : handler->Refuse(request, ReplyCode::kBusy,
                                             CommandRateLimiter::RefusalMessage(request.client));
  if (reply.transfer && !files.HasRoom()) {
    reply.code = ReplyCode::kBusy;
    reply.message = "busy: " + std::to_string(kMaxQueuedTransfers) +
                    " file transfers are waiting; try again shortly";
    reply.result = nlohmann::json::object();
    reply.transfer.reset();
  }
  spdlog::debug("command {} '{}' from '{}': {}", reply.request_id, request.verb.substr(0, 64),
                reply.client, ToString(reply.code));
  refusals.Note(reply, request.verb, received);
  replies.Remember(request, reply);
  commands.Reply(reply);
  // The chunks follow the Reply that lists them.
  if (reply.transfer) files.Enqueue(reply.request_id, reply.client, std::move(*reply.transfer));
  // A refusal or a query changes nothing the status shows (a started job
  // is seen by Tick); republishing for each would echo a flood.
  if (reply.code == ReplyCode::kOk && !IsQueryVerb(request.verb)) status_dirty = true;
}

void Daemon::Impl::Tick(Clock::time_point now) {
  RetryDevices(now);
  RetryStore(now);
  const JobInfo job = jobs->Current();
  FollowJob(job);
  UpdateState();
  TrimAfterJob(now);
  NotifySummary(job);
  PublishStatusIfDue(now);
  PingWatchdog(now);
}

void Daemon::Impl::RetryDevices(Clock::time_point now) {
  if (devices->IsOpen() || jobs->Busy() || now - loop.last_open_try <= kDeviceRetryInterval) {
    return;
  }
  loop.last_open_try = now;
  std::string error;
  if (devices->Open(&error)) {
    last_error.clear();
    notifier.Status("ready: devices up");
  } else {
    last_error = "devices: " + error;
  }
  status_dirty = true;
}

void Daemon::Impl::RetryStore(Clock::time_point now) {
  if (store || now - loop.last_store_try < kStoreRetryInterval) return;
  loop.last_store_try = now;
  std::string error;
  if (OpenStore()) {
    spdlog::info("data directory '{}' is usable: serving sessions", config.data_dir);
    if (!jobs->calibration()) {  // it may have been unreadable until now
      if (!jobs->LoadCurrentCalibration(&error)) {
        last_error = "calibration: " + error;
      } else if (const auto c = jobs->calibration()) {
        publisher.CalibrationChanged(*c);
      }
    }
  } else {
    spdlog::debug("{}", storage_error);
  }
  status_dirty = true;
}

void Daemon::Impl::FollowJob(const JobInfo& job) {
  const std::string job_state = job.id + std::string(ToString(job.state)) + job.stage;
  if (job_state == loop.last_job_state) return;
  loop.last_job_state = job_state;
  status_dirty = true;
  if (job.state == JobState::kFailed) last_error = job.message;
}

void Daemon::Impl::TrimAfterJob(Clock::time_point now) {
  // A job's images and clouds are freed on its threads' malloc arenas,
  // which glibc keeps for reuse; hand the free pages back once it has
  // ended (and its thread has let go of them), so that the daemon's RSS
  // between jobs is what it holds (measured by test_daemon_soak), not the
  // sum of what its threads once held.
  if (jobs->Busy()) {
    loop.trim_at = now + std::chrono::milliseconds(250);
  } else if (now >= loop.trim_at) {
    ::malloc_trim(0);
    loop.trim_at = Clock::time_point::max();
  }
}

void Daemon::Impl::NotifySummary(const JobInfo& job) {
  // STATUS= when a job starts or ends (not per stage: each is a datagram
  // the service manager must read).
  // Degraded (devices or storage) stays in STATUS= until it is over, so
  // `systemctl status` shows a missing camera, not "idle".
  const std::string summary =
      !store || !devices->IsOpen() ? "degraded: " + Problems()
      : jobs->Busy()               ? "busy: " + job.id + " " + job.verb
                     : "idle; last job " + job.id + " " + std::string(ToString(job.state));
  if (summary == loop.last_summary) return;
  loop.last_summary = summary;
  notifier.Status(summary);
}

void Daemon::Impl::PublishStatusIfDue(Clock::time_point now) {
  if (status_dirty.exchange(false) || now - loop.last_status > kStatusInterval ||
      site.RenewalDue(now)) {
    PublishStatus();
    loop.last_status = now;
  }
}

void Daemon::Impl::PingWatchdog(Clock::time_point now) {
  // Healthy: this loop runs, and a running job has reported within
  // kJobSilenceLimit (a driver call hung forever stops the pings; systemd
  // restarts us and the session resumes).
  const bool healthy = !jobs->Busy() || now - publisher.last_activity() < kJobSilenceLimit;
  if (loop.ping_interval.count() > 0 && healthy && now - loop.last_ping >= loop.ping_interval) {
    notifier.Watchdog();
    loop.last_ping = now;
  }
}

void Daemon::Impl::ShutDown() {
  spdlog::info("stopping");
  notifier.Stopping("stopping: checkpointing the running job");
  stopping = true;
  UpdateState();
  PublishStatus();
  files.Stop();
  jobs->Shutdown();
  devices->Close();
  PublishStatus();
  site.Dispose();  // the site view drops this station now, not after its lease
  spdlog::info("stopped cleanly");
}

}  // namespace craftscan::daemon
