#include "craftscan/daemon/commands.h"

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <exception>
#include <filesystem>
#include <optional>
#include <set>
#include <utility>
#include <vector>

#include "craftscan/daemon/devices.h"
#include "craftscan/daemon/jobs.h"
#include "craftscan/daemon/scan_turns.h"
#include "craftscan/daemon/session_store.h"
#include "craftscan/pipeline/common/sha256.h"

namespace craftscan::daemon {
namespace {

// Reads and parses <sessions>/<id>/manifest.json (id already checked with
// IsValidSessionId). False with *error.
bool ReadManifest(const SessionStore& store, const std::string& id, std::string* text,
                  Manifest* manifest, std::string* error) {
  const std::string path = store.sessions_dir() + "/" + id + "/manifest.json";
  FILE* f = std::fopen(path.c_str(), "rb");
  if (!f) {
    *error = "session " + id + ": cannot read its manifest: " + std::strerror(errno);
    return false;
  }
  text->clear();
  char buffer[65536];
  std::size_t n;
  while ((n = std::fread(buffer, 1, sizeof buffer, f)) > 0) text->append(buffer, n);
  std::fclose(f);
  if (!ManifestFromJson(*text, manifest, error)) {
    *error = "session " + id + ": " + *error;
    return false;
  }
  return true;
}

std::string Hex64(std::uint64_t value) {
  char text[17];
  std::snprintf(text, sizeof text, "%016llx", static_cast<unsigned long long>(value));
  return text;
}

// Whether session `id` (already checked with IsValidSessionId) has a folder
// in the store: what tells an unknown session from one that is there but
// cannot be opened, resumed or read.
bool SessionFolderExists(const SessionStore& store, const std::string& id) {
  std::error_code ec;
  return std::filesystem::is_directory(store.sessions_dir() + "/" + id, ec);
}

// A session's turns for `sessions`: turn, views, first_view, state (a turn
// still capturing shows the session's state), and a refused or joined
// turn's join summary.
nlohmann::json TurnsSummaryJson(const nlohmann::json& turns, const std::string& session_state) {
  nlohmann::json out = nlohmann::json::array();
  for (const nlohmann::json& t : turns) {
    if (!t.is_object()) continue;
    std::string state = t.value("state", std::string());
    if (state == "capturing" && session_state != "done") state = session_state;
    nlohmann::json entry = {{"turn", t.value("turn", 0)},
                            {"views", t.value("views", 0)},
                            {"first_view", t.value("first_view", 0)},
                            {"state", state}};
    if (t.contains("join")) entry["join"] = TurnJoinSummary(t["join"]);
    out.push_back(std::move(entry));
  }
  return out;
}

// A session file that is not an output, by name: calibration.yaml or
// views/NNN/<file> (what a worker fetches to reconstruct); nullopt for
// anything else or a file the manifest does not hold.
std::optional<FileRecord> SessionInput(const Manifest& manifest, const std::string& name) {
  if (name == kCalibrationYaml) return manifest.calibration;
  int index = -1;
  char file[64] = {};
  if (name.size() > 10 + sizeof file - 1 ||
      std::sscanf(name.c_str(), "views/%3d/%63s", &index, file) != 2)
    return std::nullopt;
  const auto view = manifest.views.find(index);
  if (view == manifest.views.end()) return std::nullopt;
  const auto record = view->second.files.find(file);
  if (record == view->second.files.end()) return std::nullopt;
  return record->second;
}

}  // namespace

nlohmann::json JobJson(const JobInfo& job) {
  nlohmann::json out = {
      {"id", job.id},           {"verb", job.verb},    {"state", ToString(job.state)},
      {"session", job.session}, {"stage", job.stage},  {"progress", job.progress},
      {"message", job.message}, {"result", job.result}};
  if (job.turn > 1) out["turn"] = job.turn;
  return out;
}

nlohmann::json DevicesJson(const std::vector<DeviceReport>& devices) {
  nlohmann::json list = nlohmann::json::array();
  for (const DeviceReport& d : devices) {
    list.push_back({{"name", d.name},
                    {"kind", d.kind},
                    {"driver", d.driver},
                    {"state", d.state},
                    {"message", d.message}});
  }
  return list;
}

CommandHandler::CommandHandler(CommandLimits limits, const TokenAuthority* tokens, JobEngine* jobs,
                               DeviceManager* devices, SessionStore* store,
                               std::function<nlohmann::json()> status)
    : limits_(limits),
      tokens_(tokens),
      jobs_(jobs),
      devices_(devices),
      store_(store),
      store_unavailable_("the session store is not open"),
      status_(std::move(status)) {}

void CommandHandler::SetStore(SessionStore* store, std::string why_unavailable) {
  store_ = store;
  store_unavailable_ = std::move(why_unavailable);
}

CommandReply CommandHandler::Refuse(const CommandRequest& request, ReplyCode code,
                                    std::string message) const {
  CommandReply reply;
  reply.request_id = request.request_id.substr(0, limits_.max_field_bytes);
  reply.client = request.client.substr(0, limits_.max_field_bytes);
  reply.code = code;
  reply.message = std::move(message);
  return reply;
}

CommandReply CommandHandler::Handle(const CommandRequest& request) {
  CommandCheck check = CheckCommand(request, limits_, tokens_);
  if (!check.ok()) return Refuse(request, check.code, std::move(check.message));
  try {
    return Dispatch(request.verb, check.arguments, *check.identity,
                    Refuse(request, ReplyCode::kInternal, ""));
  } catch (const std::exception& e) {
    return Refuse(request, ReplyCode::kInternal, std::string("internal error: ") + e.what());
  }
}

CommandReply CommandHandler::Dispatch(const std::string& verb, const nlohmann::json& args,
                                      const Identity& who, CommandReply reply) {
  auto done = [&](ReplyCode code, std::string message,
                  nlohmann::json result = nlohmann::json::object()) {
    reply.code = code;
    reply.message = std::move(message);
    reply.result = std::move(result);
    return reply;
  };
  std::string error;
  JobInfo job;
  auto started = [&](bool ok) {
    if (ok) return done(ReplyCode::kOk, job.verb + " started as " + job.id, JobJson(job));
    // Refused because a job runs (none did when Dispatch began, but the
    // engine is the one to say), or tried and failed.
    return done(jobs_->Busy() ? ReplyCode::kBusy : ReplyCode::kFailed, error);
  };
  const bool job_verb = verb == "capture" || verb == "scan" || verb == "resume" ||
                        verb == "calibrate" || verb == "calibrate-turntable" ||
                        verb == "turntable" || verb == "camera";
  // A live preview gives way to any job; a camera change restarts it after.
  std::optional<PreviewRequest> restart_preview;
  if ((job_verb || verb == "preview") && jobs_->Busy() && jobs_->Current().verb == "preview" &&
      !(verb == "preview" && args.value("action", "") == "start")) {
    if (verb == "camera") restart_preview = jobs_->LastPreviewRequest();
    if (!jobs_->StopPreview(std::chrono::seconds(10))) {
      return done(ReplyCode::kBusy, "busy: the preview did not stop within 10 s");
    }
    if (verb == "preview") return done(ReplyCode::kOk, "preview stopped");
  }
  if (job_verb && jobs_->Busy()) {
    const JobInfo current = jobs_->Current();
    return done(ReplyCode::kBusy, "busy: " + current.id + " (" + current.verb + ") is running",
                JobJson(current));
  }
  const bool needs_store = verb == "sessions" || verb == "get" || verb == "delete" ||
                           verb == "capture" || verb == "scan" || verb == "resume" ||
                           verb == "calibrate" || verb == "calibrate-turntable";
  if (needs_store && !store_) return done(ReplyCode::kUnavailable, store_unavailable_);
  if (job_verb && !devices_->IsOpen()) {
    return done(ReplyCode::kUnavailable, "the devices are not open; see the status topic");
  }

  if (verb == "status") {
    // With the caller's identity: a console signing a user in learns the
    // token's role from it (what to show; the daemon still checks each verb).
    nlohmann::json status = status_ ? status_() : nlohmann::json::object();
    if (!status.is_object()) status = nlohmann::json::object();
    status["you"] = {{"name", who.name}, {"role", std::string(ToString(who.role))}};
    return done(ReplyCode::kOk, "status", std::move(status));
  }
  if (verb == "devices") {
    nlohmann::json list = DevicesJson(devices_->Reports());
    return done(ReplyCode::kOk, std::to_string(list.size()) + " devices", {{"devices", list}});
  }
  if (verb == "sessions") {
    nlohmann::json list = nlohmann::json::array();
    for (const SessionSummary& s : store_->List()) {
      nlohmann::json entry = {{"id", s.id},
                              {"object", s.object_name},
                              {"job", s.job},
                              {"state", s.state},
                              {"problem", s.problem},
                              {"views_captured", s.views_captured},
                              {"created", s.created_utc},
                              {"updated", s.updated_utc}};
      if (s.turns.is_array()) entry["turns"] = TurnsSummaryJson(s.turns, s.state);
      list.push_back(std::move(entry));
    }
    return done(ReplyCode::kOk, std::to_string(list.size()) + " sessions", {{"sessions", list}});
  }
  if (verb == "get") {
    const std::string id = args["session"];  // IsValidSessionId (CheckCommand)
    if (args.contains("files")) return GetFiles(id, args, reply);
    const VerifyResult verify = store_->Verify(id);
    if (!verify.manifest_ok) {
      return done(ReplyCode::kNotFound,
                  verify.problems.empty() ? "unknown session" : verify.problems[0]);
    }
    std::string text;
    Manifest parsed;
    nlohmann::json manifest;
    if (ReadManifest(*store_, id, &text, &parsed, &error)) {
      manifest = nlohmann::json::parse(text, nullptr, false);
    }
    return done(
        ReplyCode::kOk, verify.IsIntact() ? "intact" : "damaged",
        {{"manifest", manifest}, {"intact", verify.IsIntact()}, {"problems", verify.problems}});
  }
  if (verb == "delete") {
    const std::string id = args["session"];
    Status moved;
    const std::string trash = store_->MoveToTrash(id, &moved);
    if (trash.empty()) {
      const ReplyCode code = moved.code() == ErrorCode::kNotFound             ? ReplyCode::kNotFound
                             : moved.code() == ErrorCode::kFailedPrecondition ? ReplyCode::kBusy
                             : moved.code() == ErrorCode::kInvalidArgument ? ReplyCode::kBadArgument
                                                                           : ReplyCode::kFailed;
      return done(code, moved.message());
    }
    return done(
        ReplyCode::kOk, "session " + id + " moved to the trash",
        {{"session", id}, {"trash", trash}, {"warning", moved.ok() ? "" : moved.message()}});
  }
  if (verb == "cancel") {
    if (!jobs_->Cancel(&error)) return done(ReplyCode::kFailed, error);
    return done(ReplyCode::kOk, "cancelling " + jobs_->Current().id);
  }
  if (verb == "capture") {
    return started(jobs_->StartCapture(args.value("object", std::string("object")), &job, &error));
  }
  if (verb == "scan") {
    ScanRequest request;
    request.object = args.value("object", std::string("object"));
    request.views = args.value("views", 0);
    request.step_deg = args.value("step_deg", 0.0);
    if (args.contains("exposure_bracket"))  // a list of numbers (CheckCommand)
      request.exposure_bracket = args["exposure_bracket"].get<std::vector<double>>();
    request.client = who.name;
    request.add_to = args.value("add_to", std::string());
    const bool ok = jobs_->StartScan(request, &job, &error);
    if (!ok && !request.add_to.empty() && !SessionFolderExists(*store_, request.add_to))
      return done(ReplyCode::kNotFound, error);
    return started(ok);
  }
  if (verb == "resume") {
    const std::string id = args["session"];  // IsValidSessionId (CheckCommand)
    const bool ok = jobs_->StartResume(id, &job, &error);
    if (!ok && !SessionFolderExists(*store_, id)) return done(ReplyCode::kNotFound, error);
    return started(ok);
  }
  if (verb == "calibrate") return started(jobs_->StartCalibrate(&job, &error));
  if (verb == "calibrate-turntable") return started(jobs_->StartCalibrateTurntable(&job, &error));
  if (verb == "turntable") {
    const std::string action = args["action"];
    if (action == "home") {
      if (!devices_->Home(&error)) return done(ReplyCode::kFailed, error);
      return done(ReplyCode::kOk, "homed");
    }
    if (action == "move") {  // with angle_deg (CheckCommand)
      const double angle = args["angle_deg"];
      if (!devices_->MoveTo(angle, &error)) return done(ReplyCode::kFailed, error);
      return done(ReplyCode::kOk, "at " + std::to_string(angle) + " deg",
                  {{"angle_deg", devices_->TurntableStatusNow().angle_deg}});
    }
    return done(ReplyCode::kBadArgument, "action: must be 'home' or 'move'");
  }
  if (verb == "camera") {
    drivers::CameraSettings settings = devices_->camera_settings();
    settings.exposure_us = args.value("exposure_us", settings.exposure_us);
    settings.gain_db = args.value("gain_db", settings.gain_db);
    const bool applied = devices_->ApplyCameraSettings(settings, &error);
    if (restart_preview) jobs_->StartPreview(*restart_preview, &job, nullptr);
    if (!applied) return done(ReplyCode::kFailed, error);
    return done(ReplyCode::kOk, "camera settings applied",
                {{"exposure_us", settings.exposure_us}, {"gain_db", settings.gain_db}});
  }
  if (verb == "preview") {
    const std::string action = args["action"];
    if (action == "stop") return done(ReplyCode::kOk, "no preview was running");
    if (action != "start")
      return done(ReplyCode::kBadArgument, "action: must be 'start' or 'stop'");
    if (jobs_->Busy() && jobs_->Current().verb != "preview") {
      const JobInfo current = jobs_->Current();
      return done(ReplyCode::kBusy,
                  "busy: " + current.id + " (" + current.verb + ") is running; no preview now",
                  JobJson(current));
    }
    if (!devices_->IsOpen()) {
      return done(ReplyCode::kUnavailable, "the devices are not open; see the status topic");
    }
    PreviewRequest request;
    request.fps = args.value("fps", request.fps);
    request.width = args.value("width", request.width);
    request.seconds = args.value("seconds", request.seconds);
    return started(jobs_->StartPreview(request, &job, &error));
  }
  return done(ReplyCode::kUnknownVerb, "unknown verb '" + verb + "'");
}

CommandReply CommandHandler::GetFiles(const std::string& id, const nlohmann::json& args,
                                      CommandReply reply) {
  auto refuse = [&](ReplyCode code, std::string message) {
    reply.code = code;
    reply.message = std::move(message);
    return reply;
  };
  std::string text, error;
  Manifest manifest;
  if (!SessionFolderExists(*store_, id))
    return refuse(ReplyCode::kNotFound, "unknown session " + id);
  if (!ReadManifest(*store_, id, &text, &manifest, &error))
    return refuse(ReplyCode::kNotFound, error);
  // The files to send, by name: the outputs ("all"), the named outputs, or
  // the whole session ("session": the manifest, the calibration copy, every
  // view's durable files and the outputs, e.g. for an archive's BagIt bag).
  std::vector<std::pair<std::string, FileRecord>> named;
  const nlohmann::json& files = args["files"];  // "all", "session" or valid names (CheckCommand)
  if (files.is_string() && files.get_ref<const std::string&>() == "session") {
    named.emplace_back(kManifestJson, FileRecord{text.size(), Fnv1a64(text), Sha256Hex(text)});
    if (manifest.calibration) named.emplace_back(kCalibrationYaml, *manifest.calibration);
    for (const auto& [index, view] : manifest.views) {
      char folder[16];
      std::snprintf(folder, sizeof folder, "views/%03d/", index);
      for (const auto& [name, record] : view.files) named.emplace_back(folder + name, record);
    }
    for (const auto& [name, record] : manifest.outputs) named.emplace_back(name, record);
  } else if (files.is_string()) {
    for (const auto& [name, record] : manifest.outputs) named.emplace_back(name, record);
    if (named.empty()) {
      return refuse(ReplyCode::kNotFound,
                    "session " + id + " has no outputs (it is " + ToString(manifest.state) + ")");
    }
  } else {
    std::set<std::string> seen;
    for (const nlohmann::json& item : files) {
      const std::string& name = item.get_ref<const std::string&>();
      if (const std::optional<FileRecord> input = SessionInput(manifest, name)) {
        if (seen.insert(name).second) named.emplace_back(name, *input);
        continue;
      }
      if (!manifest.outputs.count(name)) {
        std::string available;
        for (const auto& [output, unused] : manifest.outputs) {
          available += (available.empty() ? "" : ", ") + output;
        }
        return refuse(ReplyCode::kNotFound,
                      "session " + id + " has no durable output '" + name +
                          "' (it has: " + (available.empty() ? "none" : available) + ")");
      }
      if (seen.insert(name).second) named.emplace_back(name, manifest.outputs.at(name));
    }
  }
  FileTransfer transfer;
  transfer.session = id;
  transfer.chunk_bytes = args.value("chunk_bytes", kDefaultTransferChunkBytes);
  nlohmann::json list = nlohmann::json::array();
  std::uint64_t total = 0;
  for (const auto& [name, record] : named) {
    transfer.files.push_back(
        {name, store_->sessions_dir() + "/" + id + "/" + name, record.size_bytes, record.fnv1a64});
    nlohmann::json entry = {
        {"name", name}, {"size", record.size_bytes}, {"fnv1a64", Hex64(record.fnv1a64)}};
    if (!record.sha256.empty()) entry["sha256"] = record.sha256;  // absent: an old manifest
    list.push_back(std::move(entry));
    total += record.size_bytes;
  }
  reply.code = ReplyCode::kOk;
  reply.message =
      "sending " + std::to_string(named.size()) + " files, " + std::to_string(total) + " bytes";
  reply.result = {{"session", id},
                  {"state", ToString(manifest.state)},
                  {"chunk_bytes", transfer.chunk_bytes},
                  {"total_bytes", total},
                  {"files", list}};
  reply.transfer = std::move(transfer);
  return reply;
}

}  // namespace craftscan::daemon
