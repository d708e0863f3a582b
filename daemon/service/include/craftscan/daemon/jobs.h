// JobEngine: runs the station's jobs, one at a time, on worker threads.
//
//   calibrate            board views → stereo calibration + report; stored
//                        under <data_dir>/calibration/<id>/ and made current
//                        only when accepted
//   calibrate-turntable  the board on the platter at several angles → the
//                        turntable axis, added to the current calibration
//   capture              one view → disparity → cloud (a one-view session)
//   scan                 N views at a step → registration → fusion → mesh →
//                        measurements (a session)
//   resume               an interrupted scan from its last durable step
//
// The jobs are made of the stages in stages.h; the engine composes them,
// records how the session ended and announces the end, in one place
// (JobEngine::Finish), after the session is closed.
//
// A scan runs three stages joined by bounded queues (capacity from the
// options; a stereo pair is ~8 MB, so 2 keeps memory bounded while capture
// of view k+1 overlaps matching of view k):
//
//   capture (move, settle, trigger, store durably, publish)
//     ─Q1─► match (rectify, AD-Census, reproject, store, publish)
//     ─Q2─► reconstruct (after the last view: ReconstructScan, outputs)
//
// Cancel and shutdown close the queues; each stage finishes its item and
// stops; the session is marked interrupted (resumable), never dropped.
// An exception escaping a stage becomes a failed job.
//
// Storage errors (a full disk, a read-only or vanished data directory) fail
// the job with the store's message (path and strerror) and a hint on what
// to do; the session is interrupted and every acknowledged capture stays
// intact. So that the session's end can be recorded even on a full disk,
// the engine keeps kReserveBytes allocated in <data_dir>/.craftscand-reserve
// (made before each job that stores a session, best effort) and frees it
// when that last manifest write fails for lack of space.
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "craftscan/daemon/config.h"
#include "craftscan/daemon/devices.h"
#include "craftscan/daemon/live_preview.h"
#include "craftscan/daemon/session_store.h"
#include "craftscan/daemon/stages.h"
#include "craftscan/drivers/camera.h"
#include "craftscan/pipeline/calib/calibration.h"
#include "craftscan/pipeline/common/point_cloud.h"
#include "craftscan/pipeline/stereo/view_processing.h"
#include "craftscan/pipeline/surface/scan_reconstruction.h"

namespace craftscan::daemon {

// What the jobs publish; implemented by the DDS bridge (and by tests). Called
// from the job threads, possibly concurrently; implementations must be
// thread-safe and must not block for long.
class JobSink {
 public:
  virtual ~JobSink() = default;
  virtual void Progress(const std::string& job, const std::string& stage, int current, int total,
                        const std::string& message) = 0;
  // A capture, called only once it is durable on disk (the acknowledgement).
  virtual void Capture(const std::string& session, int view, double angle_deg,
                       const drivers::StereoFrame& frame) = 0;
  virtual void Disparity(const std::string& session, int view, const cv::Mat& disparity,
                         double focal_px, double baseline_mm, int min_disparity,
                         int num_disparities) = 0;
  // view −1 = the fused cloud. world_from_cloud: the cloud's pose in the
  // turntable frame (mm).
  virtual void Cloud(const std::string& session, int view, const PointCloud& cloud,
                     const cv::Matx44d& world_from_cloud) = 0;
  // The calibration in force changed (after calibrate / calibrate-turntable).
  virtual void CalibrationChanged(const StereoCalibration& calibration) { (void)calibration; }
  // A live preview frame (the preview job, the guided calibration).
  virtual void Preview(const PreviewFrame& frame) { (void)frame; }
};

struct JobEngineOptions {
  std::string data_dir;
  // Provenance in every scan's mesh.glb (ReconstructStage::Options).
  std::string station;
  std::string software;  // "craftscan <version>"
  std::string rights;    // deliverables.rights; "" = none
  // Reconstruction on the site's workers (remote_jobs.h): null = always here.
  // With `remote`: kRemote offers every scan's reconstruction, kAuto only
  // when a worker is idle as the scan starts (a join is always made here).
  RemoteJobs* remote = nullptr;
  ReconstructionMode reconstruction = ReconstructionMode::kLocal;
  std::string remote_config;  // DumpDaemonConfig of the station's config
  std::chrono::milliseconds remote_offer_timeout{3000};
  std::chrono::seconds remote_max{1800};
  std::function<void(const std::string& job, const std::string& worker)> on_remote;
  int default_views = 6;
  double default_step_deg = 60;
  std::chrono::milliseconds settle{200};
  std::vector<double> exposure_bracket;  // CaptureStage::Options::exposure_bracket
  // scan.auto_bracket: where exposure_bracket is empty and a request names
  // none, each view is bracketed when it needs it (CaptureStage::Options).
  bool auto_bracket = false;
  int queue_capacity = 2;
  int threads = 2;  // matcher and reconstruction threads
  ViewProcessorOptions view;
  ScanOptions scan;  // reconstruction options (num_threads overridden by threads)
  // Calibration.
  BoardSpec board;            // held in front of the cameras
  BoardSpec turntable_board;  // lying on the platter
  int calibration_views = 16;
  int calibration_max_attempts = 40;  // captures tried before giving up
  bool calibration_guided = false;    // CalibrateStage::Options::guided
  double calibration_guided_max_s = 600;
  double max_rms_px = 0.5;
  StereoCalibrationOptions calibration;
  std::vector<double> turntable_angles_deg{0, 60, 120, 180, 240, 300};
  double turntable_board_thickness_mm = 3;
};

enum class JobState { kIdle, kRunning, kDone, kFailed, kCancelled };
std::string_view ToString(JobState state);  // "idle", "running", ...

struct JobInfo {
  std::string id;    // "job-<n>", empty when none ran yet
  std::string verb;  // "scan", "capture", ...
  JobState state = JobState::kIdle;
  std::string session;    // the session it writes, if any
  std::string stage;      // current stage
  double progress = 0;    // 0…1
  std::string message;    // result summary or error
  nlohmann::json result;  // verb-specific result (measurements, calibration figures)
  int turn = 0;           // a scan's turn after the first (scan_turns.h); 0 otherwise
};

// The live preview (verb preview): frames at `fps` until `seconds` after
// the last request, each image scaled to `width` px.
struct PreviewRequest {
  double fps = 4;       // (0, 15]
  int width = 640;      // 64..4096
  double seconds = 60;  // (0, 600]
  bool IsValid(std::string* why) const;
};

struct ScanRequest {
  std::string object = "object";
  int views = 0;        // 0 = the default
  double step_deg = 0;  // 0 = 360 / views
  // Exposure bracketing for this scan (IsValidExposureBracket; [] = off);
  // none: the station's scan.exposure_bracket. Recorded in the session's
  // params, so a resume captures its missing views the same way.
  std::optional<std::vector<double>> exposure_bracket;
  std::string client;
  // Non-empty: no new session; another turn of this finished scan's session
  // with the object laid in another pose (scan_turns.h), views and step
  // defaulting to its first turn's, joined onto its first turn.
  std::string add_to;
};

class JobEngine {
 public:
  // `store` may be null while the data directory is unusable (SetStore).
  // `sink`, `log` and `report` may be null/empty (`report` renders a scan's
  // report.html and pictures: MakeReportFiles from craftscan/daemon/report.h).
  JobEngine(JobEngineOptions options, DeviceManager* devices, SessionStore* store, JobSink* sink,
            std::function<void(drivers::LogLevel, std::string_view)> log, ReportWriter report);
  ~JobEngine();

  // Space kept allocated for recording a session's end on a full disk.
  static constexpr std::size_t kReserveBytes = std::size_t{1} << 20;

  // Replaces the session store (null: StartScan, StartCapture and
  // StartResume fail). Thread-safe; call while no job runs.
  void SetStore(SessionStore* store) { store_.store(store); }

  // Loads <data_dir>/calibration/current.yaml if present. False with *error
  // for a present but unreadable one (the daemon starts anyway, without it).
  bool LoadCurrentCalibration(std::string* error);
  std::optional<StereoCalibration> calibration() const;
  std::string calibration_id() const;

  // Each Start* returns false with *error when busy ("busy: job-101500-3 (scan)
  // is running") or when the request is invalid; on success *info holds the
  // new job's id (and session for scan/capture/resume). StartResume takes an
  // interrupted or failed session, or one left in an active state by a job
  // that could not record its end (no job holds it: it is marked
  // interrupted first).
  bool StartScan(const ScanRequest& request, JobInfo* info, std::string* error);
  bool StartCapture(const std::string& object, JobInfo* info, std::string* error);
  bool StartCalibrate(JobInfo* info, std::string* error);
  bool StartCalibrateTurntable(JobInfo* info, std::string* error);
  bool StartResume(const std::string& session_id, JobInfo* info, std::string* error);
  // Starts the live preview, or extends the running one by request.seconds
  // from now (its fps and width stay). Busy while another job runs.
  bool StartPreview(const PreviewRequest& request, JobInfo* info, std::string* error);
  // Stops a running preview (its job ends cancelled) and waits for it to
  // end, up to `timeout`; true when no preview runs afterwards. Every verb
  // that starts a job calls this first: a preview never holds up a scan.
  bool StopPreview(std::chrono::milliseconds timeout);
  // The last preview's request (to start it again after a camera change).
  PreviewRequest LastPreviewRequest() const;
  // Asks the running job to stop at its next safe point. False if none runs.
  bool Cancel(std::string* error);
  // Cancels the running job (its session becomes interrupted) and joins it.
  void Shutdown();

  bool Busy() const;
  JobInfo Current() const;  // the running job, else the last finished one
  // Waits until no job runs (for tests and shutdown); false on timeout.
  bool WaitIdle(std::chrono::milliseconds timeout) const;

 private:
  struct ScanPlan;
  // How a job ended, as Current() and the final Progress tell it.
  struct JobOutcome {
    JobState state = JobState::kFailed;
    std::string message;
    nlohmann::json result;
  };
  bool Launch(const std::string& verb, const std::string& session, std::function<JobOutcome()> body,
              JobInfo* info, std::string* error);
  // Creates the session of a scan or capture with the current calibration
  // copied in and launches it.
  // Whether a scan brackets automatically: the station's scan.auto_bracket,
  // no bracket configured and none in the request (an explicit [] is off).
  bool AutoBracket(const ScanRequest& request, const std::vector<double>& bracket) const {
    return options_.auto_bracket && !request.exposure_bracket && bracket.empty();
  }
  bool StartSessionJob(const std::string& verb, const std::string& object, nlohmann::json params,
                       std::shared_ptr<ScanPlan> plan, JobInfo* info, std::string* error);
  // ScanRequest::add_to: reopens the session for its next turn and launches it.
  bool StartAddTurn(const ScanRequest& request, JobInfo* info, std::string* error);
  // Records the launched job's turn (JobInfo::turn).
  void NoteTurn(int turn, JobInfo* info);
  // Before a later turn's capture: turn 1's outputs copied under turn1/
  // (those not there yet), so they stay whatever the join does.
  StageOutcome KeepFirstTurnOutputs(Session& session);
  // A later turn that cannot be joined or reconstructed: recorded in the
  // turn ("refused" or "failed", with the message and the join's figures),
  // the session done again with turn 1's model; the job fails with `outcome`'s
  // message and what the operator does next.
  // `join_status`: the join's verdict when it was reached; `join` its figures.
  JobOutcome EndTurnNotJoined(ScanPlan& plan, const StageOutcome& outcome,
                              std::optional<TurnJoinResult::Status> join_status,
                              const nlohmann::json& join);
  // Runs the stages, records the session's end, closes the session.
  JobOutcome RunScan(const std::shared_ptr<ScanPlan>& plan);
  JobOutcome RunScanStages(ScanPlan& plan);
  // Records a stopped or failed session job: the session interrupted
  // (resumable) or failed, and the job's message.
  JobOutcome EndSession(Session& session, const StageOutcome& outcome);
  // Records done; a failed job when done cannot be recorded (`stored` says
  // what is safe on disk then).
  JobOutcome EndSessionDone(Session& session, const std::string& detail, const std::string& stored,
                            JobOutcome done);
  JobOutcome RunPreview(const PreviewRequest& request);
  JobOutcome RunCalibrate();
  JobOutcome RunCalibrateTurntable();
  CalibrateTurntableStage::Options TurntableOptions();
  // Makes an accepted calibration current, or the failed job saying why.
  JobOutcome EndCalibration(const std::string& verb, CalibrationOutcome outcome);
  StageContext Context(Session* session);
  void SetStage(const std::string& stage, int current, int total, const std::string& message);
  // The one place a job ends: Current() and the terminal Progress.
  void Finish(JobOutcome outcome);
  bool SetCurrentCalibration(const StereoCalibration& calibration, const std::string& id,
                             std::string* error);
  // The session store, or null with *error saying so.
  SessionStore* Store(std::string* error) const;
  // Makes the reserve file if it is missing (best effort).
  void EnsureReserve();
  // Session::SetState; when that fails, frees the reserve and tries once
  // more when its code is kDiskFull. The end of a job is then recorded even
  // on a full disk. The failed Status of the last try otherwise.
  Status RecordState(Session& session, SessionState state, const std::string& detail);
  // Joins the worker of the last job if it has finished (its session lock
  // is released once its thread ends).
  void JoinFinishedWorker();

  JobEngineOptions options_;
  DeviceManager* devices_;
  std::atomic<SessionStore*> store_;
  JobSink* sink_;
  std::function<void(drivers::LogLevel, std::string_view)> log_;
  ReportWriter report_;

  mutable std::mutex mutex_;  // guards current_, calibration_, calibration_id_
  mutable std::condition_variable idle_;
  JobInfo current_;
  bool running_ = false;
  std::uint64_t next_job_ = 1;
  std::string job_prefix_;  // "job-HHMMSS-": the engine's start time
  std::optional<StereoCalibration> calibration_;
  std::string calibration_id_;
  // The running job's stages stop: set by Cancel, Shutdown and by a stage
  // that failed (so the others stop too); the stages' StageContext::stop.
  // The job's outcome says which (CombinedOutcome in jobs.cc).
  std::atomic<bool> stop_{false};
  std::atomic<bool> moving_{false};  // a scan's turntable move is in progress (Cancel aborts it)
  // The running preview ends at this steady-clock time (ns); StartPreview extends it.
  std::atomic<std::int64_t> preview_until_ns_{0};
  PreviewRequest last_preview_;  // guarded by mutex_
  std::thread worker_;
};

}  // namespace craftscan::daemon
