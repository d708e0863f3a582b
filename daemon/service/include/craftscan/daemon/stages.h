// The stages of the station's jobs (DESIGN.md "The second wave"): each a
// class with one Run() that returns a typed outcome. JobEngine (jobs.h)
// composes them on its worker threads; tests call Run() directly.
//
//   scan, capture, resume (one session):
//     CaptureStage      move, settle, trigger, store durably, publish
//       ─Q1─► MatchStage        rectify, AD-Census, reproject, store, publish
//       ─Q2─► ReconstructStage  after the last view: ReconstructScan, outputs,
//                               report (scan and resume of a scan only)
//   calibrate            CalibrateStage
//   calibrate-turntable  CalibrateTurntableStage
//
// Stopping: a stage polls `stop` (set by a cancel, a shutdown or another
// stage's failure) at its safe points and ends with kCancelled; so does a
// stage whose queue was closed under it. Each stage finishes the item in
// hand first, so whatever it acknowledged is durable. Stages do not record
// the session's end (the JobEngine does, in one place) and throw nothing
// the JobEngine does not catch.
#pragma once

#include <atomic>
#include <chrono>
#include <functional>
#include <optional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "craftscan/daemon/bounded_queue.h"
#include "craftscan/daemon/devices.h"
#include "craftscan/daemon/scan_turns.h"
#include "craftscan/daemon/session_store.h"
#include "craftscan/drivers/camera.h"
#include "craftscan/drivers/host.h"
#include "craftscan/pipeline/calib/calibration.h"
#include "craftscan/pipeline/common/point_cloud.h"
#include "craftscan/pipeline/common/status.h"
#include "craftscan/pipeline/stereo/view_processing.h"
#include "craftscan/pipeline/surface/scan_reconstruction.h"

namespace craftscan::daemon {

class JobSink;
struct ScanOutputContext;  // craftscan/daemon/scan_outputs.h
class RemoteJobs;          // craftscan/daemon/remote_jobs.h
class RemoteJobFeed;
struct RemoteJobOutcome;
struct RemoteInput;
struct ReportInputs;  // craftscan/daemon/report.h
struct ReportFiles;

// How a stage ended. Callers switch on `code`, never on `message`.
struct StageOutcome {
  ErrorCode code = ErrorCode::kOk;
  // "" when ok; otherwise what failed, naming the view and the cause
  // ("view 2: camera lost and not recovered: ...", "cancelled").
  std::string message;
  // The session can be continued by resume without redoing what is durable
  // (a device, a storage error, a cancel): it is marked interrupted. False
  // for an outcome the same data would give again (the pipeline, unreadable
  // stored data): the session is marked failed.
  bool resumable = true;
  // The data disk refused a write (the session store's Status, its code from
  // the errno): the job's message then says what the operator fixes
  // (JobEngine's storage advice). False for device and pipeline errors,
  // whose kIoError is not the disk's.
  bool storage = false;

  bool ok() const { return code == ErrorCode::kOk; }
  bool cancelled() const { return code == ErrorCode::kCancelled; }
  static StageOutcome Ok() { return {}; }
  static StageOutcome Cancelled() { return {ErrorCode::kCancelled, "cancelled", true}; }
  static StageOutcome Error(ErrorCode code, std::string message, bool resumable) {
    return {code, std::move(message), resumable, false};
  }
  // A failed store: the Status's code, `prefix` before its message;
  // resumable once the operator fixes the disk.
  static StageOutcome Storage(const Status& status, const std::string& prefix) {
    return {status.code(), prefix + status.message(), true, true};
  }
};

// The ErrorCode of a device error: kAborted → kCancelled, kDeviceLost →
// kDeviceLost, kTimeout → kTimeout, kInvalidArgument → kInvalidArgument,
// kWrongState/kFault/kUnsupported → kFailedPrecondition, kIoError → kIoError.
ErrorCode ToErrorCode(drivers::StatusCode code);

// Progress of a job: stage name ("capture", "match", "register", ...),
// current of total, a line for the operator.
using ProgressFn = std::function<void(const std::string& stage, int current, int total,
                                      const std::string& message)>;
using LogFn = std::function<void(drivers::LogLevel, std::string_view)>;

// Renders report.html and its pictures for a finished scan (MakeReportFiles
// in craftscan/daemon/report.h); false with *error when it cannot.
using ReportWriter =
    std::function<bool(const ReportInputs& inputs, ReportFiles* files, std::string* error)>;

// What every stage is given. Pointers are not owned and outlive the stage.
struct StageContext {
  Session* session = nullptr;               // the job's session (scan stages)
  JobSink* sink = nullptr;                  // may be null: nothing published
  ProgressFn progress;                      // may be empty
  LogFn log;                                // may be empty
  const std::atomic<bool>* stop = nullptr;  // may be null: never stopped

  bool Stopping() const { return stop && stop->load(); }
  // The flag to poll (DeviceManager::Capture): `stop`, or one never set.
  const std::atomic<bool>& StopFlag() const {
    static const std::atomic<bool> never{false};
    return stop ? *stop : never;
  }
  void Progress(const std::string& stage, int current, int total,
                const std::string& message) const {
    if (progress) progress(stage, current, total, message);
  }
  void Log(drivers::LogLevel level, std::string_view message) const {
    if (log) log(level, message);
  }
};

// Q1: a view captured (or loaded from the session); empty images: its cloud
// is already durable and the match stage loads it.
struct CapturedView {
  int view = 0;
  double angle_deg = 0;
  cv::Mat left, right;
  cv::Mat texture;  // the texture frame, when the station has a projector
  // The pair's encoding (ViewProcessor::Process): 1 as captured, the
  // merge's gamma for an exposure bracket.
  double gamma = 1.0;
};
// Q2: a view's cloud in the rig frame (mm).
struct MatchedView {
  int view = 0;
  double angle_deg = 0;
  PointCloud cloud;
};

// The pose of a view cloud for display: the view taken at commanded angle
// θ, brought back to the turntable frame at angle 0 (identity without a
// turntable axis).
cv::Matx44d WorldFromView(const StereoCalibration& calibration, double angle_deg);

// Views first_view … first_view+views−1 in order (the k-th at k·step_deg): a view whose cloud is
// durable is handed on as it is, a durable capture is loaded, the others
// are captured (turntable prepared once, moved unless it is a one-view
// capture with step 0, settle, trigger), stored durably, then published
// (JobSink::Capture: the acknowledgement) and handed on. Thread: the job's.
class CaptureStage {
 public:
  struct Options {
    int views = 1;
    double step_deg = 0;
    std::chrono::milliseconds settle{0};
    // Exposure bracketing (DeviceManager::CaptureBracketed): multiples of
    // the exposure captured besides it and merged; empty = one exposure.
    std::vector<double> exposure_bracket;
    // A scan's turn (scan_turns.h): its views are stored from first_view
    // on, meta.json records the turn, and progress messages start with
    // `label` ("turn 2: "; "" for a one-turn scan); current/total count the
    // turn's views.
    int first_view = 0;
    int turn = 1;
    std::string label;
    // Automatic bracketing, when exposure_bracket is empty: a view whose
    // left image is dark and without texture on enough of the platter
    // (DarkUntexturedSharePct over auto_bracket_region, PlatterRegionMask;
    // AutoBracketOptions' threshold) is also captured at its multiple. Off
    // when the region is empty. meta.json records the share and the choice.
    bool auto_bracket = false;
    cv::Mat auto_bracket_region;
  };
  // `moving` (may be null) is true while a move is in progress, so a cancel
  // can abort it (DeviceManager::AbortMove).
  CaptureStage(StageContext context, DeviceManager* devices, Options options,
               std::atomic<bool>* moving = nullptr)
      : context_(std::move(context)), devices_(devices), options_(options), moving_(moving) {}

  // Ends ok once every view is handed on (Q1 is left open: the caller closes
  // it); kCancelled on stop or a closed Q1; a device error with its code
  // (resumable); a storage error (resumable); a stored capture that cannot
  // be read back (not resumable).
  StageOutcome Run(BoundedQueue<CapturedView>& out);
  double capture_ms() const { return capture_ms_; }  // moves, captures and stores

 private:
  StageOutcome CaptureView(int view, double angle_deg, CapturedView* item);

  StageContext context_;
  DeviceManager* devices_;
  Options options_;
  std::atomic<bool>* moving_;
  bool turntable_prepared_ = false;
  double capture_ms_ = 0;
};

// Each view from Q1: rectify, match, reproject, crop (ViewProcessor), store
// the disparity map and the cloud, publish both (a durable cloud is loaded
// and published again), hand the cloud on. Thread: its own.
class MatchStage {
 public:
  // `processor` is initialised; `views` is the job's view count (progress).
  // A turn's views (CaptureStage::Options): progress counts from first_view,
  // messages start with `label`.
  MatchStage(StageContext context, ViewProcessor* processor, const StereoCalibration* calibration,
             int views, int first_view = 0, std::string label = {})
      : context_(std::move(context)),
        processor_(processor),
        calibration_(calibration),
        views_(views),
        first_view_(first_view),
        label_(std::move(label)) {}

  // Ends ok when Q1 is closed and drained (Q2 is left open); kCancelled on
  // stop or a closed Q2; a pipeline error or an unreadable cloud (not
  // resumable); a storage error (resumable).
  StageOutcome Run(BoundedQueue<CapturedView>& in, BoundedQueue<MatchedView>& out);
  double match_ms() const { return match_ms_; }

 private:
  StageOutcome MatchView(CapturedView& item, MatchedView* out);

  StageContext context_;
  ViewProcessor* processor_;
  const StereoCalibration* calibration_;
  int views_;
  int first_view_;
  std::string label_;
  double match_ms_ = 0;
};

// Collects the views from Q2 until it closes: index k holds view k (nullopt
// for a view that never came). `views` ≥ 0.
std::vector<std::optional<MatchedView>> CollectViews(BoundedQueue<MatchedView>& in, int views);

struct ReconstructOutcome {
  StageOutcome status;
  // fused_points, mesh_vertices, stage times, box, measurement; a turn
  // joined or refused: turn_join (TurnJoinJson), also when status failed
  nlohmann::json result;
  // A later turn (Options::turn > 1) that reached the join: its verdict.
  std::optional<TurnJoinResult::Status> join_status;
  std::string summary;      // "6 views, 123456 fused points" when ok
  std::string done_detail;  // the journal entry for done: "fused 123456 points"
};

// As the views come (IncrementalScan): each view conditioned and registered
// onto the one before while the turntable turns. After the last view:
// session reconstructing, the rest of the reconstruction (closing edge, loop
// closure, fusion, mesh, measurements), fused.ply, mesh.ply, mesh.obj,
// mesh.glb (glb.h; one that cannot be encoded is logged, not a failure)
// and report.json stored, then the report pages (a report that cannot be made
// is logged, not a failure), then the fused cloud published. Thread: its own.
class ReconstructStage {
 public:
  struct Options {
    int views = 0;
    double step_deg = 0;
    ScanOptions scan;
    int min_disparity = 0;  // the band searched (for the report's colour scale), px
    int num_disparities = 0;
    // Provenance written into mesh.glb (craftscan/daemon/glb.h) besides the
    // session's own (object, client, capture time, calibration).
    std::string station;   // the station id
    std::string software;  // "craftscan <version>"
    std::string rights;    // the config's deliverables.rights; "" = none
    // A turn after the first (scan_turns.h): its views from first_view on;
    // after its own reconstruction (without a mesh) turn 1 is rebuilt from
    // its stored view clouds (ReconstructScan), the turn joined onto it
    // (JoinTurnScans with `join`), and the joined model is the output;
    // report.json gets "turns" (every turn of `turns`, this one's state
    // "joined") and "turn_join". A refused join fails with the join's
    // message (not resumable), nothing written.
    int first_view = 0;
    int turn = 1;
    std::string label;              // "turn 2: " for progress messages
    std::vector<TurnRecord> turns;  // all the session's turns, this one last
    TurnJoinOptions join;
    // Not null (a first turn only): the reconstruction is offered to the
    // site's workers (remote_jobs.h) as the scan starts, each view handed on
    // as it is durable, and made here only when none does it. remote_config: the station's config
    // (DumpDaemonConfig) the worker takes the pipeline settings from.
    RemoteJobs* remote = nullptr;
    std::string remote_config;
    std::chrono::milliseconds remote_offer_timeout{3000};
    std::chrono::seconds remote_max{1800};
    // Told the job's worker as it changes (the site view); may be empty.
    std::function<void(const std::string& job, const std::string& worker)> on_remote;
  };
  // `report` may be empty: no report pages.
  ReconstructStage(StageContext context, const StereoCalibration* calibration, Options options,
                   ReportWriter report)
      : context_(std::move(context)),
        calibration_(calibration),
        options_(std::move(options)),
        report_(std::move(report)) {}

  // Takes Q2 until it closes (views out of order wait for their turn).
  // kCancelled on stop, checked once the views are in and again after the
  // reconstruction's last part (it cannot be interrupted),
  // before any output is written; a missing view → kInternal; an unusable
  // reconstruction (not resumable); a storage error (resumable).
  ReconstructOutcome Run(BoundedQueue<MatchedView>& in);

 private:
  // Turn 1 rebuilt from its stored view clouds (no mesh), or the failure.
  StageOutcome RebuildFirstTurn(ScanResult* first);
  std::string WithTurns(const std::string& report, const nlohmann::json& result);
  // The views the report shows: (index, commanded angle), every joined turn's.
  std::vector<std::pair<int, double>> ReportViews() const;
  // What the outputs are made from (scan_outputs.h): the session's provenance.
  ScanOutputContext OutputContext() const;
  // The reconstruction offered to the site's workers (options_.remote),
  // its views fed as they come. Thread: its own, while Run takes the views.
  RemoteJobOutcome RunRemote(RemoteJobFeed* feed);
  // A durable view's files as a worker fetches them.
  std::vector<RemoteInput> ViewInputs(int view, double angle_deg) const;
  // A worker's model stored as the station's own.
  void StoreRemote(const RemoteJobOutcome& handed, double reconstruct_ms, ReconstructOutcome* out);

  StageContext context_;
  const StereoCalibration* calibration_;
  Options options_;
  ReportWriter report_;
};

// How a calibration job ended; JobEngine makes `accepted` current.
struct CalibrationOutcome {
  StageOutcome status;  // message: the job's message ("calibrate: ...")
  nlohmann::json result;
  std::optional<StereoCalibration> accepted;  // set when ok
  std::string id;                             // the calibration's folder name
  std::string summary;                        // the job's message when ok
};

// A new folder <data_dir>/calibration/<UTC stamp>[-n]; its name in *id.
// "" with *error.
std::string NewCalibrationDir(const std::string& data_dir, std::string* id, std::string* error);

// Stereo calibration from a board held in front of the cameras: captures
// until `views` have the board in both images (at most `max_attempts`),
// keeps their pictures under a new calibration folder, solves, saves
// calibration.yaml and report.json there; accepted when usable and its RMS
// is at most max_rms_px. Thread: the job's.
class CalibrateStage {
 public:
  struct Options {
    std::string data_dir;
    BoardSpec board;
    int views = 16;
    int max_attempts = 40;
    double max_rms_px = 0.5;
    StereoCalibrationOptions calibration;
    // Guided (calibration_guide.h): watch the stream, take a view when the
    // board is held still, sharp and in a new pose, advise the person, until
    // the guide is done (`views` is then the views needed) or guided_max_s
    // of frame time pass. Preview frames with the guide's overlay are
    // streamed at about guided_preview_fps (JobSink::Preview).
    bool guided = false;
    double guided_max_s = 600;
    double guided_preview_fps = 4;
    int guided_preview_width = 640;
    std::string job_id;  // for the preview frames
  };
  CalibrateStage(StageContext context, DeviceManager* devices, Options options)
      : context_(std::move(context)), devices_(devices), options_(std::move(options)) {}
  CalibrationOutcome Run();

 private:
  CalibrationOutcome Solve(const std::vector<StereoBoardView>& views, cv::Size image_size,
                           const std::string& dir, const std::string& id);
  // The guided capture loop: the views, or a failure (its message).
  CalibrationOutcome RunGuided(const std::string& dir, const std::string& id);

  StageContext context_;
  DeviceManager* devices_;
  Options options_;
};

// The turntable axis from a board lying on the platter, captured at each of
// `angles_deg`, added to `calibration` and saved under a new calibration
// folder. Thread: the job's.
class CalibrateTurntableStage {
 public:
  struct Options {
    std::string data_dir;
    BoardSpec board;
    std::vector<double> angles_deg;
    std::chrono::milliseconds settle{0};
    double board_thickness_mm = 3;
    // Guided (PlatterGuide, calibration_guide.h): wait until the board lies
    // still in view, then at each angle use the first frame with the board
    // lying still; preview frames with the guide's overlay as in
    // CalibrateStage. Gives up after guided_max_s of frame time.
    bool guided = false;
    double guided_max_s = 600;
    double guided_preview_fps = 4;
    int guided_preview_width = 640;
    std::string job_id;
  };
  CalibrateTurntableStage(StageContext context, DeviceManager* devices, Options options,
                          StereoCalibration calibration, std::atomic<bool>* moving = nullptr)
      : context_(std::move(context)),
        devices_(devices),
        options_(std::move(options)),
        calibration_(std::move(calibration)),
        moving_(moving) {}
  CalibrationOutcome Run();

 private:
  // The guided capture: the steps at every angle (found or missed), or false
  // with `error` (or cancelled).
  bool RunGuided(std::vector<TurntableStep>* steps, std::string* error);
  CalibrationOutcome Solve(const std::vector<TurntableStep>& steps);

  StageContext context_;
  DeviceManager* devices_;
  Options options_;
  StereoCalibration calibration_;
  std::atomic<bool>* moving_;
};

}  // namespace craftscan::daemon
