// The scan's stages: capture, match, reconstruct (stages.h).
#include <cmath>
#include <cstdio>
#include <exception>
#include <thread>
#include <utility>

#include "craftscan/daemon/glb.h"
#include "craftscan/daemon/jobs.h"
#include "craftscan/daemon/remote_jobs.h"
#include "craftscan/daemon/report.h"
#include "craftscan/daemon/scan_outputs.h"
#include "craftscan/daemon/stages.h"
#include "craftscan/pipeline/common/atomic_file.h"
#include "craftscan/pipeline/common/ply.h"
#include "craftscan/pipeline/stereo/exposure_merge.h"
#include "craftscan/pipeline/surface/mesh.h"

namespace craftscan::daemon {
namespace {

constexpr double kDegToRad = CV_PI / 180;

double MsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
      .count();
}

std::string ViewPrefix(int view) { return "view " + std::to_string(view) + ": "; }

nlohmann::json FrameMeta(const drivers::StereoFrame& frame, double angle_deg) {
  return {
      {"angle_deg", angle_deg},
      {"exposure_us", frame.settings.exposure_us},
      {"gain_db", frame.settings.gain_db},
      {"pixel_format", std::string(drivers::ToString(frame.settings.pixel_format))},
      {"left", {{"timestamp_ns", frame.left.timestamp_ns}, {"frame_id", frame.left.frame_id}}},
      {"right", {{"timestamp_ns", frame.right.timestamp_ns}, {"frame_id", frame.right.frame_id}}}};
}

// A storage error of the session store, with the code of the failing
// system call: resumable once the operator fixes the disk.
StageOutcome StorageError(int view, const Status& status) {
  return StageOutcome::Storage(status, ViewPrefix(view));
}

}  // namespace

ErrorCode ToErrorCode(drivers::StatusCode code) {
  switch (code) {
    case drivers::StatusCode::kOk:
      return ErrorCode::kOk;
    case drivers::StatusCode::kAborted:
      return ErrorCode::kCancelled;
    case drivers::StatusCode::kDeviceLost:
      return ErrorCode::kDeviceLost;
    case drivers::StatusCode::kTimeout:
      return ErrorCode::kTimeout;
    case drivers::StatusCode::kInvalidArgument:
      return ErrorCode::kInvalidArgument;
    case drivers::StatusCode::kIoError:
      return ErrorCode::kIoError;
    case drivers::StatusCode::kWrongState:
    case drivers::StatusCode::kFault:
    case drivers::StatusCode::kUnsupported:
      return ErrorCode::kFailedPrecondition;
  }
  return ErrorCode::kInternal;
}

cv::Matx44d WorldFromView(const StereoCalibration& c, double angle_deg) {
  if (!c.turntable.valid) return cv::Matx44d::eye();
  const double a = -angle_deg * kDegToRad;
  const cv::Matx44d rz(std::cos(a), -std::sin(a), 0, 0, std::sin(a), std::cos(a), 0, 0, 0, 0, 1, 0,
                       0, 0, 0, 1);
  return rz * TurntableFromRig(c.turntable);
}

// --- capture -------------------------------------------------------------------

StageOutcome CaptureStage::Run(BoundedQueue<CapturedView>& out) {
  Session& session = *context_.session;
  for (int k = 0; k < options_.views; ++k) {
    if (context_.Stopping()) return StageOutcome::Cancelled();
    const double angle = k * options_.step_deg;
    const int index = options_.first_view + k;
    const Manifest manifest = session.manifest();
    const auto record = manifest.views.find(index);
    const bool has_capture = record != manifest.views.end() && record->second.HasCapture();
    CapturedView item{index, angle, {}, {}, {}};
    if (has_capture && record->second.HasCloud()) {
      // Durable up to its cloud: the match stage loads it.
    } else if (has_capture) {
      std::string why;
      nlohmann::json meta;
      if (!session.LoadCapture(index, &item.left, &item.right, &meta, &why, &item.texture)) {
        return StageOutcome::Error(ErrorCode::kCorrupt,
                                   ViewPrefix(index) + "stored capture unreadable: " + why, false);
      }
      // A stored merge (its meta lists the bracket) is gamma-encoded.
      const auto bracket = meta.find("exposure_bracket");
      if (bracket != meta.end() && bracket->is_array() && !bracket->empty())
        item.gamma = ExposureMergeOptions{}.gamma;
    } else if (StageOutcome captured = CaptureView(index, angle, &item); !captured.ok()) {
      return captured;
    }
    if (!out.Push(std::move(item))) return StageOutcome::Cancelled();
  }
  return StageOutcome::Ok();
}

StageOutcome CaptureStage::CaptureView(int index, double angle, CapturedView* item) {
  const int n = options_.views;
  const int k = index - options_.first_view;  // within the turn
  const std::string& label = options_.label;
  // A device error while stopping is the stop (an aborted move, a capture
  // given up), not a fault of the device.
  const auto device_error = [&](const drivers::DriverStatus& s) {
    if (context_.Stopping() || s.code == drivers::StatusCode::kAborted) {
      return StageOutcome::Cancelled();
    }
    return StageOutcome::Error(ToErrorCode(s.code), label + ViewPrefix(index) + s.message, true);
  };
  const auto start = std::chrono::steady_clock::now();
  context_.Progress("capture", k, n, label + "moving to " + std::to_string(angle) + " deg");
  if (n > 1 || options_.step_deg != 0) {
    if (!turntable_prepared_) {
      // Homed first if an earlier job left it faulted.
      const drivers::DriverStatus prepared = devices_->PrepareTurntable();
      if (!prepared.ok()) return device_error(prepared);
      turntable_prepared_ = true;
    }
    if (moving_) *moving_ = true;
    const drivers::DriverStatus moved = devices_->MoveTo(angle);
    if (moving_) *moving_ = false;
    if (!moved.ok()) return device_error(moved);
    std::this_thread::sleep_for(options_.settle);
  }
  drivers::StereoFrame frame;
  std::vector<double> bracket = options_.exposure_bracket;
  double dark_pct = std::nan("");  // automatic bracketing's measure, when it ran
  drivers::DriverStatus captured;
  if (options_.auto_bracket && bracket.empty() && !options_.auto_bracket_region.empty()) {
    captured = devices_->Capture(&frame, context_.StopFlag());
    const AutoBracketOptions automatic;
    if (captured.ok())
      dark_pct = DarkUntexturedSharePct(frame.left.image, options_.auto_bracket_region, automatic);
    if (captured.ok() && dark_pct >= automatic.min_share_pct) {
      bracket = {automatic.multiple};
      char why[96];
      std::snprintf(why, sizeof why, ": %.1f %% of the platter dark without texture: also x%g",
                    dark_pct, automatic.multiple);
      context_.Progress("capture", k, n, label + "view " + std::to_string(index) + why);
      captured = devices_->AddExposures(bracket, &frame, context_.StopFlag());
    }
  } else {
    captured = devices_->CaptureBracketed(bracket, &frame, context_.StopFlag());
  }
  if (!captured.ok()) return device_error(captured);
  nlohmann::json meta = FrameMeta(frame, angle);
  // The stored pair is the merge; the multiples say of what.
  if (!bracket.empty()) meta["exposure_bracket"] = bracket;
  if (std::isfinite(dark_pct)) {
    meta["auto_bracket"] = {{"dark_untextured_pct", dark_pct}, {"bracketed", !bracket.empty()}};
  }
  if (options_.turn > 1) meta["turn"] = options_.turn;
  if (Status stored = context_.session->StoreCapture(index, angle, frame.left.image,
                                                     frame.right.image, meta, frame.texture_left);
      !stored.ok()) {
    return StorageError(index, stored);
  }
  capture_ms_ += MsSince(start);
  if (context_.sink)
    context_.sink->Capture(context_.session->id(), index, angle, frame);  // durable
  context_.Progress("capture", k + 1, n, label + "view " + std::to_string(index) + " stored");
  item->left = frame.left.image;
  item->right = frame.right.image;
  item->texture = frame.texture_left;
  item->gamma = bracket.empty() ? 1.0 : ExposureMergeOptions{}.gamma;
  return StageOutcome::Ok();
}

// --- match ---------------------------------------------------------------------

StageOutcome MatchStage::Run(BoundedQueue<CapturedView>& in, BoundedQueue<MatchedView>& out) {
  while (std::optional<CapturedView> item = in.Pop()) {
    if (context_.Stopping()) return StageOutcome::Cancelled();
    MatchedView matched{item->view, item->angle_deg, {}};
    if (StageOutcome o = MatchView(*item, &matched); !o.ok()) return o;
    const std::string sid = context_.session->id();
    if (context_.sink) {
      context_.sink->Cloud(sid, matched.view, matched.cloud,
                           WorldFromView(*calibration_, matched.angle_deg));
    }
    context_.Progress("match", matched.view - first_view_ + 1, views_,
                      label_ + "view " + std::to_string(matched.view) + ": " +
                          std::to_string(matched.cloud.size()) + " points");
    if (!out.Push(std::move(matched))) return StageOutcome::Cancelled();
  }
  return context_.Stopping() ? StageOutcome::Cancelled() : StageOutcome::Ok();
}

StageOutcome MatchStage::MatchView(CapturedView& item, MatchedView* out) {
  Session& session = *context_.session;
  std::string why;
  if (item.left.empty()) {
    if (!session.LoadCloud(item.view, &out->cloud, &why)) {
      return StageOutcome::Error(ErrorCode::kCorrupt, ViewPrefix(item.view) + why, false);
    }
    return StageOutcome::Ok();
  }
  const auto start = std::chrono::steady_clock::now();
  ProcessedView v = processor_->Process(item.left, item.right, item.texture, item.gamma);
  if (!v.ok) {
    return StageOutcome::Error(ErrorCode::kInvalidArgument, ViewPrefix(item.view) + v.message,
                               false);
  }
  Status stored = session.StoreDisparity(item.view, v.disparity);
  if (stored.ok()) stored = session.StoreCloud(item.view, v.cloud_in_rig);
  if (!stored.ok()) return StorageError(item.view, stored);
  match_ms_ += MsSince(start);
  if (context_.sink) {
    context_.sink->Disparity(session.id(), item.view, v.disparity, processor_->focal_px(),
                             processor_->baseline_mm(), v.min_disparity, v.num_disparities);
  }
  out->cloud = std::move(v.cloud_in_rig);
  return StageOutcome::Ok();
}

// --- reconstruct ---------------------------------------------------------------

std::vector<std::optional<MatchedView>> CollectViews(BoundedQueue<MatchedView>& in, int views) {
  std::vector<std::optional<MatchedView>> out(static_cast<std::size_t>(views));
  while (std::optional<MatchedView> item = in.Pop()) {
    if (item->view >= 0 && item->view < views) {
      out[static_cast<std::size_t>(item->view)] = std::move(*item);
    }
  }
  return out;
}

ReconstructOutcome ReconstructStage::Run(BoundedQueue<MatchedView>& in) {
  ReconstructOutcome out;
  const int n = options_.views;
  const int first = options_.first_view;
  const bool joining = options_.turn > 1;
  const std::string& label = options_.label;
  ScanOptions scan = options_.scan;
  scan.camera = RectifiedLeftCamera(*calibration_);  // the view clouds are in its frame
  ScanOptions turn_scan = scan;
  if (joining) turn_scan.mesh = false;  // the joined model is meshed once
  // Each view is conditioned and registered onto the one before as soon as
  // both are here, while the turntable turns to the next; views that come
  // early wait for their turn.
  IncrementalScan incremental(calibration_->turntable, turn_scan);
  // Handed to a worker (one turn; a join is made here): offered as the scan
  // starts, each view handed on as it is durable so the worker registers
  // while the turntable turns; the views are kept here too, for a local
  // reconstruction should no worker finish it (then fed to `incremental`).
  bool remote = options_.remote != nullptr && !joining;
  std::vector<ScanView> kept;
  RemoteJobFeed feed;
  RemoteJobOutcome handed;
  std::thread offering;
  if (remote) offering = std::thread([&] { handed = RunRemote(&feed); });
  struct JoinOnExit {  // whatever way Run leaves (the job ends: stop, timeouts)
    std::thread& thread;
    ~JoinOnExit() {
      if (thread.joinable()) thread.join();
    }
  } join_offering{offering};
  // The job ended without a result while views still come: on here.
  const auto take_back = [&] {
    if (offering.joinable()) offering.join();
    for (ScanView& v : kept) incremental.Add(std::move(v));
    kept.clear();
  };
  std::vector<std::optional<MatchedView>> waiting(static_cast<std::size_t>(std::max(n, 0)));
  int next = 0;
  while (std::optional<MatchedView> item = in.Pop()) {
    const int k = item->view - first;
    if (k < 0 || k >= n) continue;
    waiting[static_cast<std::size_t>(k)] = std::move(*item);
    for (; next < n && waiting[static_cast<std::size_t>(next)]; ++next) {
      MatchedView& view = *waiting[static_cast<std::size_t>(next)];
      if (!context_.Stopping()) {
        ScanView v;
        v.commanded_angle_rad = view.angle_deg * kDegToRad;
        v.cloud_in_rig = std::move(view.cloud);
        if (remote && feed.ended() && offering.joinable()) take_back();
        if (remote && offering.joinable()) {
          kept.push_back(std::move(v));
          feed.Add(ViewInputs(view.view, view.angle_deg), next + 1);
        } else {
          incremental.Add(std::move(v));
        }
      }
      waiting[static_cast<std::size_t>(next)].reset();
    }
  }
  // From the last view on: for a remote job that includes the wait for the
  // worker's part after its last view.
  const auto start = std::chrono::steady_clock::now();
  feed.Close();
  if (offering.joinable()) offering.join();
  if (context_.Stopping()) {
    out.status = StageOutcome::Cancelled();
    return out;
  }
  if (next < n) {
    out.status = StageOutcome::Error(
        ErrorCode::kInternal, "view " + std::to_string(first + next) + " was never matched", true);
    return out;
  }
  Session& session = *context_.session;
  if (Status set =
          session.SetState(SessionState::kReconstructing, label + "registration, fusion, mesh");
      !set.ok()) {
    out.status = StageOutcome::Storage(set, "");
    return out;
  }
  ScanResult r;
  if (remote) {
    if (handed.status == RemoteJobOutcome::Status::kCancelled) {
      out.status = StageOutcome::Cancelled();
      return out;
    }
    if (handed.status == RemoteJobOutcome::Status::kDone) {
      StoreRemote(handed, MsSince(start), &out);
      return out;
    }
    context_.Log(drivers::LogLevel::kWarning,
                 "session " + session.id() + ": reconstructing here: " + handed.message);
    context_.Progress("register", 0, 1, "reconstructing here: " + handed.message);
    take_back();
    r = incremental.Finish();
    out.result["remote"] = {{"job", handed.job_id}, {"outcome", "local"}, {"why", handed.message}};
  } else {
    context_.Progress("register", 0, 1,
                      label + "closing the loop over " + std::to_string(n) + " registered views");
    r = incremental.Finish();
  }
  if (joining && r.IsUsable()) {
    const std::string turn = "turn " + std::to_string(options_.turn);
    ScanResult first_turn;
    context_.Progress("join", 0, 2,
                      "turn 1: rebuilding from its " +
                          std::to_string(options_.turns.front().views) + " stored views");
    if (StageOutcome rebuilt = RebuildFirstTurn(&first_turn); !rebuilt.ok()) {
      out.status = rebuilt;
      return out;
    }
    if (context_.Stopping()) {
      out.status = StageOutcome::Cancelled();
      return out;
    }
    context_.Progress("join", 1, 2, "joining " + turn + " onto turn 1");
    r = JoinTurnScans(first_turn, r, scan, options_.join);
    out.result["turn_join"] = TurnJoinJson(r);
    if (r.turn_join) out.join_status = r.turn_join->status;
    context_.Progress("join", 2, 2, turn + ": " + TurnJoinSummary(out.result["turn_join"]));
    if (!r.IsUsable() && r.turn_join && r.turn_join->status != TurnJoinResult::Status::kFailed) {
      out.status = StageOutcome::Error(
          ErrorCode::kFailedPrecondition,
          turn + " not joined (" + ToString(r.turn_join->status) + "): " + r.turn_join->message,
          false);
      return out;
    }
  }
  const double reconstruct_ms = MsSince(start);
  if (!r.IsUsable()) {
    out.status = StageOutcome::Error(ErrorCode::kInvalidArgument,
                                     label + "reconstruction: " + r.message, false);
    return out;
  }
  if (context_.Stopping()) {  // the last safe point: nothing is written yet
    out.status = StageOutcome::Cancelled();
    return out;
  }
  context_.Progress("write", 0, 1, "writing fused cloud, mesh and report");
  ScanOutputs outputs =
      MakeScanOutputs(r, WithTurns(ScanReportJson(r), out.result), OutputContext());
  if (StageOutcome stored = StoreScanOutputs(session, outputs, context_.log); !stored.ok()) {
    out.status = stored;
    return out;
  }
  if (context_.sink) context_.sink->Cloud(session.id(), -1, r.fused, cv::Matx44d::eye());
  out.result.update(outputs.result);
  out.result["reconstruct_ms"] = reconstruct_ms;
  out.summary = std::to_string(n) + " views, " + std::to_string(r.fused.size()) + " fused points";
  out.done_detail = "fused " + std::to_string(r.fused.size()) + " points";
  if (joining) {
    out.result["turn"] = options_.turn;
    out.summary = "turn " + std::to_string(options_.turn) + " " +
                  TurnJoinSummary(out.result["turn_join"]) +
                  " onto turn 1: " + std::to_string(options_.turns.front().views) + " + " +
                  std::to_string(n) + " views, " + std::to_string(r.fused.size()) + " fused points";
    out.done_detail = "turn " + std::to_string(options_.turn) + " joined, fused " +
                      std::to_string(r.fused.size()) + " points";
  }
  return out;
}

StageOutcome ReconstructStage::RebuildFirstTurn(ScanResult* first) {
  const TurnRecord& t = options_.turns.front();
  Session& session = *context_.session;
  const Manifest manifest = session.manifest();
  std::vector<ScanView> views;
  for (int v = t.first_view; v < t.first_view + t.views; ++v) {
    const auto record = manifest.views.find(v);
    ScanView view;
    std::string why = "view " + std::to_string(v) + " is not in the manifest";
    if (record == manifest.views.end() || !session.LoadCloud(v, &view.cloud_in_rig, &why))
      return StageOutcome::Error(ErrorCode::kCorrupt, "turn 1: " + why, false);
    view.commanded_angle_rad = record->second.angle_deg * kDegToRad;
    views.push_back(std::move(view));
  }
  ScanOptions scan = options_.scan;
  scan.camera = RectifiedLeftCamera(*calibration_);
  scan.mesh = false;
  *first = ReconstructScan(views, calibration_->turntable, scan);
  if (!first->IsUsable()) {
    return StageOutcome::Error(ErrorCode::kInvalidArgument,
                               "turn 1: reconstruction: " + first->message, false);
  }
  return StageOutcome::Ok();
}

// report.json of a joined turn: ScanReportJson's, with "turns" (each turn:
// its views, state, platter-contact points dropped) and "turn_join".
std::string ReconstructStage::WithTurns(const std::string& report, const nlohmann::json& result) {
  if (options_.turn <= 1) return report;
  nlohmann::json json = nlohmann::json::parse(report, nullptr, false);
  if (!json.is_object()) return report;
  const nlohmann::json join = result.value("turn_join", nlohmann::json());
  std::vector<TurnRecord> turns = options_.turns;
  nlohmann::json list = nlohmann::json::array();
  for (TurnRecord& t : turns) {
    if (t.turn == options_.turn) t.state = "joined";
    nlohmann::json entry = {{"turn", t.turn},
                            {"first_view", t.first_view},
                            {"views", t.views},
                            {"step_deg", t.step_deg},
                            {"state", t.state}};
    if (join.is_object() && t.turn == 1) entry["contact_dropped"] = join["contact_dropped_a"];
    if (join.is_object() && t.turn == options_.turn)
      entry["contact_dropped"] = join["contact_dropped_b"];
    list.push_back(std::move(entry));
  }
  json["turns"] = std::move(list);
  json["turn_join"] = join;
  json["joined_turns"] = {1, options_.turn};
  return json.dump(2);
}

std::vector<std::pair<int, double>> ReconstructStage::ReportViews() const {
  std::vector<std::pair<int, double>> views;
  const auto add = [&](int first_view, int n, double step) {
    for (int k = 0; k < n; ++k) views.emplace_back(first_view + k, k * step);
  };
  if (options_.turn > 1 && !options_.turns.empty())
    add(options_.turns.front().first_view, options_.turns.front().views,
        options_.turns.front().step_deg);
  add(options_.first_view, options_.views, options_.step_deg);
  return views;
}

std::vector<RemoteInput> ReconstructStage::ViewInputs(int view, double angle_deg) const {
  std::vector<RemoteInput> inputs;
  const Manifest manifest = context_.session->manifest();
  const auto record = manifest.views.find(view);
  if (record == manifest.views.end()) return inputs;
  char folder[16];
  std::snprintf(folder, sizeof folder, "views/%03d/", view);
  for (const char* file : {"cloud.ply", "disparity.pfm"}) {
    const auto f = record->second.files.find(file);
    if (f == record->second.files.end()) continue;
    RemoteInput input{folder + std::string(file), f->second.size_bytes, f->second.sha256};
    if (std::string(file) == "cloud.ply") {
      input.view = view;
      input.angle_deg = angle_deg;
      input.captured_utc = record->second.captured_utc;
    }
    inputs.push_back(std::move(input));
  }
  return inputs;
}

RemoteJobOutcome ReconstructStage::RunRemote(RemoteJobFeed* feed) {
  Session& session = *context_.session;
  const Manifest manifest = session.manifest();
  const ScanOutputContext c = OutputContext();
  RemoteJobRequest request;
  request.session = session.id();
  request.offer_timeout = options_.remote_offer_timeout;
  request.max_remote = options_.remote_max;
  request.views_total = options_.views;
  request.feed = feed;
  if (manifest.calibration) {
    request.inputs.push_back(
        {kCalibrationYaml, manifest.calibration->size_bytes, manifest.calibration->sha256});
  }
  nlohmann::json report_views = nlohmann::json::array();
  for (const auto& [index, angle] : c.report_views) report_views.push_back({index, angle});
  request.parameters = {{"config", options_.remote_config},
                        {"report_views", report_views},
                        {"report", static_cast<bool>(report_)},
                        {"min_disparity", c.min_disparity},
                        {"num_disparities", c.num_disparities},
                        {"session", c.session_id},
                        {"object_name", c.object_name},
                        {"created_utc", c.created_utc},
                        {"captured_utc", c.captured_utc},
                        {"client", c.client},
                        {"calibration_id", c.calibration_id},
                        {"station", c.station},
                        {"software", c.software},
                        {"rights", c.rights}};
  static const std::atomic<bool> never{false};
  return options_.remote->Run(request, context_.stop ? *context_.stop : never, context_.progress,
                              options_.on_remote);
}

void ReconstructStage::StoreRemote(const RemoteJobOutcome& handed, double reconstruct_ms,
                                   ReconstructOutcome* out) {
  Session& session = *context_.session;
  context_.Progress("write", 0, 1, "writing the model worker " + handed.worker + " made");
  if (StageOutcome stored = StoreScanOutputs(session, handed.outputs, context_.log); !stored.ok()) {
    out->status = stored;
    return;
  }
  // A worker leaves mesh.obj out (ScanOutputContext::mesh_obj).
  if (StageOutcome stored = StoreMeshObjFromPly(session); !stored.ok()) {
    out->status = stored;
    return;
  }
  PointCloud fused;
  std::string why;
  if (context_.sink && ReadPly(session.dir() + "/fused.ply", &fused, &why))
    context_.sink->Cloud(session.id(), -1, fused, cv::Matx44d::eye());
  out->result.update(handed.outputs.result);
  out->result["reconstruct_ms"] = reconstruct_ms;
  out->result["remote"] = {{"job", handed.job_id},      {"outcome", "done"},
                           {"worker", handed.worker},   {"grants", handed.grants},
                           {"seconds", handed.seconds}, {"bytes_back", handed.bytes_back}};
  const auto points = handed.outputs.result.value("fused_points", std::size_t{0});
  out->summary = std::to_string(options_.views) + " views, " + std::to_string(points) +
                 " fused points (reconstructed by worker " + handed.worker + ")";
  out->done_detail = "fused " + std::to_string(points) + " points on worker " + handed.worker;
}

ScanOutputContext ReconstructStage::OutputContext() const {
  ScanOutputContext c = SessionOutputContext(*context_.session, calibration_);
  c.station = options_.station;
  c.software = options_.software;
  c.rights = options_.rights;
  c.report_views = ReportViews();
  c.min_disparity = options_.min_disparity;
  c.num_disparities = options_.num_disparities;
  c.report = report_;
  c.progress = context_.progress;
  c.log = context_.log;
  return c;
}

}  // namespace craftscan::daemon
