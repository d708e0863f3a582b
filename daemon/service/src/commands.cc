#include "craftscan/daemon/commands.h"

#include <cmath>
#include <exception>
#include <map>
#include <set>
#include <utility>
#include <vector>

#include "craftscan/daemon/devices.h"
#include "craftscan/daemon/jobs.h"
#include "craftscan/daemon/session_store.h"

namespace craftscan::daemon {
namespace {

enum class ArgType { kString, kInt, kNumber };

struct ArgSpec {
  ArgType type;
  bool required;
  double min, max;  // numbers: range; strings: length range
};

// The argument schema of every verb (see the table in commands.h).
const std::map<std::string, std::map<std::string, ArgSpec>>& VerbArguments() {
  static const std::map<std::string, std::map<std::string, ArgSpec>> table = {
      {"status", {}},
      {"devices", {}},
      {"sessions", {}},
      {"get", {{"session", {ArgType::kString, true, 1, 128}}}},
      {"capture", {{"object", {ArgType::kString, false, 1, 128}}}},
      {"scan",
       {{"object", {ArgType::kString, false, 1, 128}},
        {"views", {ArgType::kInt, false, 2, 360}},
        {"step_deg", {ArgType::kNumber, false, -360, 360}}}},
      {"cancel", {}},
      {"resume", {{"session", {ArgType::kString, true, 1, 128}}}},
      {"turntable",
       {{"action", {ArgType::kString, true, 1, 16}},
        {"angle_deg", {ArgType::kNumber, false, -3600, 3600}}}},
      {"camera",
       {{"exposure_us", {ArgType::kNumber, false, 1, 10e6}},
        {"gain_db", {ArgType::kNumber, false, 0, 48}}}},
      {"calibrate", {}},
      {"calibrate-turntable", {}},
  };
  return table;
}

bool CheckArguments(const std::map<std::string, ArgSpec>& spec, const nlohmann::json& args,
                    std::string* why) {
  for (const auto& [key, value] : args.items()) {
    const auto it = spec.find(key);
    if (it == spec.end()) {
      std::string known;
      for (const auto& [name, unused] : spec) known += (known.empty() ? "" : ", ") + name;
      *why = "unknown argument '" + key + "'" +
             (known.empty() ? " (this verb takes none)" : " (known: " + known + ")");
      return false;
    }
    const ArgSpec& s = it->second;
    switch (s.type) {
      case ArgType::kString: {
        if (!value.is_string()) {
          *why = key + ": must be a string";
          return false;
        }
        const std::size_t n = value.get_ref<const std::string&>().size();
        if (n < s.min || n > s.max) {
          *why = key + ": length must be " + std::to_string(static_cast<int>(s.min)) + ".." +
                 std::to_string(static_cast<int>(s.max));
          return false;
        }
        break;
      }
      case ArgType::kInt:
        if (!value.is_number_integer() || value.get<double>() < s.min ||
            value.get<double>() > s.max) {
          *why = key + ": must be an integer in " + std::to_string(static_cast<int>(s.min)) +
                 ".." + std::to_string(static_cast<int>(s.max));
          return false;
        }
        break;
      case ArgType::kNumber: {
        const double v = value.is_number() ? value.get<double>() : NAN;
        if (!std::isfinite(v) || v < s.min || v > s.max) {
          *why = key + ": must be a number in [" + std::to_string(s.min) + ", " +
                 std::to_string(s.max) + "]";
          return false;
        }
        break;
      }
    }
  }
  for (const auto& [key, s] : spec) {
    if (s.required && !args.contains(key)) {
      *why = "missing argument '" + key + "'";
      return false;
    }
  }
  return true;
}

nlohmann::json JobJson(const JobInfo& job) {
  return {{"id", job.id},           {"verb", job.verb},         {"state", ToString(job.state)},
          {"session", job.session}, {"stage", job.stage},       {"progress", job.progress},
          {"message", job.message}, {"result", job.result}};
}

}  // namespace

std::string_view ToString(ReplyCode code) {
  switch (code) {
    case ReplyCode::kOk: return "ok";
    case ReplyCode::kBadRequest: return "bad_request";
    case ReplyCode::kUnauthenticated: return "unauthenticated";
    case ReplyCode::kUnknownVerb: return "unknown_verb";
    case ReplyCode::kForbidden: return "forbidden";
    case ReplyCode::kBadArgument: return "bad_argument";
    case ReplyCode::kBusy: return "busy";
    case ReplyCode::kNotFound: return "not_found";
    case ReplyCode::kUnavailable: return "unavailable";
    case ReplyCode::kFailed: return "failed";
    case ReplyCode::kTooLarge: return "too_large";
    case ReplyCode::kInternal: return "internal";
  }
  return "internal";
}

CommandHandler::CommandHandler(CommandLimits limits, const TokenAuthority* tokens, JobEngine* jobs,
                               DeviceManager* devices, SessionStore* store,
                               std::function<nlohmann::json()> status)
    : limits_(limits), tokens_(tokens), jobs_(jobs), devices_(devices), store_(store),
      status_(std::move(status)) {}

CommandReply CommandHandler::Handle(const CommandRequest& request) {
  CommandReply reply;
  auto clip = [&](const std::string& s) { return s.substr(0, limits_.max_field_bytes); };
  reply.request_id = clip(request.request_id);
  reply.client = clip(request.client);
  auto refuse = [&](ReplyCode code, std::string message) {
    reply.code = code;
    reply.message = std::move(message);
    return reply;
  };
  if (request.arguments.size() > limits_.max_argument_bytes) {
    return refuse(ReplyCode::kTooLarge, "arguments are " + std::to_string(request.arguments.size()) +
                                            " bytes; the limit is " +
                                            std::to_string(limits_.max_argument_bytes));
  }
  for (const auto* field : {&request.request_id, &request.client, &request.verb, &request.token}) {
    if (field->size() > limits_.max_field_bytes) {
      return refuse(ReplyCode::kTooLarge, "request_id, client, verb and token are limited to " +
                                              std::to_string(limits_.max_field_bytes) + " bytes");
    }
  }
  if (request.request_id.empty()) return refuse(ReplyCode::kBadRequest, "request_id is empty");
  nlohmann::json args = nlohmann::json::object();
  if (!request.arguments.empty()) {
    args = nlohmann::json::parse(request.arguments, nullptr, /*allow_exceptions=*/false);
    if (args.is_discarded()) {
      return refuse(ReplyCode::kBadRequest, "arguments are not valid JSON");
    }
    if (!args.is_object()) return refuse(ReplyCode::kBadRequest, "arguments must be a JSON object");
  }
  const std::optional<Identity> who = tokens_ ? tokens_->Authenticate(request.token) : std::nullopt;
  if (!who) return refuse(ReplyCode::kUnauthenticated, "unknown token");
  const auto verb = VerbArguments().find(request.verb);
  const std::optional<Role> needed = RequiredRole(request.verb);
  if (verb == VerbArguments().end() || !needed) {
    std::string known;
    for (const auto& [name, unused] : VerbArguments()) known += (known.empty() ? "" : ", ") + name;
    return refuse(ReplyCode::kUnknownVerb,
                  "unknown verb '" + clip(request.verb) + "' (known: " + known + ")");
  }
  if (!Satisfies(who->role, *needed)) {
    return refuse(ReplyCode::kForbidden, "'" + request.verb + "' needs role " +
                                             std::string(ToString(*needed)) + "; " + who->name +
                                             " is " + std::string(ToString(who->role)));
  }
  std::string why;
  if (!CheckArguments(verb->second, args, &why)) return refuse(ReplyCode::kBadArgument, why);
  try {
    return Dispatch(request.verb, args, *who, reply);
  } catch (const std::exception& e) {
    return refuse(ReplyCode::kInternal, std::string("internal error: ") + e.what());
  }
}

CommandReply CommandHandler::Dispatch(const std::string& verb, const nlohmann::json& args,
                                      const Identity& who, CommandReply reply) {
  auto done = [&](ReplyCode code, std::string message, nlohmann::json result = nlohmann::json::object()) {
    reply.code = code;
    reply.message = std::move(message);
    reply.result = std::move(result);
    return reply;
  };
  std::string error;
  JobInfo job;
  auto started = [&](bool ok) {
    if (ok) return done(ReplyCode::kOk, job.verb + " started as " + job.id, JobJson(job));
    const ReplyCode code = error.rfind("busy", 0) == 0 ? ReplyCode::kBusy : ReplyCode::kFailed;
    return done(code, error);
  };
  const bool job_verb = verb == "capture" || verb == "scan" || verb == "resume" ||
                        verb == "calibrate" || verb == "calibrate-turntable" ||
                        verb == "turntable" || verb == "camera";
  if (job_verb && jobs_->Busy()) {
    const JobInfo current = jobs_->Current();
    return done(ReplyCode::kBusy, "busy: " + current.id + " (" + current.verb + ") is running",
                JobJson(current));
  }
  if (job_verb && !devices_->IsOpen()) {
    return done(ReplyCode::kUnavailable, "the devices are not open; see the status topic");
  }

  if (verb == "status") return done(ReplyCode::kOk, "status", status_ ? status_() : nlohmann::json{});
  if (verb == "devices") {
    nlohmann::json list = nlohmann::json::array();
    for (const DeviceReport& d : devices_->Reports()) {
      list.push_back({{"name", d.name}, {"kind", d.kind}, {"driver", d.driver},
                      {"state", d.state}, {"message", d.message}});
    }
    return done(ReplyCode::kOk, std::to_string(list.size()) + " devices", {{"devices", list}});
  }
  if (verb == "sessions") {
    nlohmann::json list = nlohmann::json::array();
    for (const SessionSummary& s : store_->List()) {
      list.push_back({{"id", s.id}, {"object", s.object_name}, {"job", s.job},
                      {"state", s.state}, {"problem", s.problem},
                      {"views_captured", s.views_captured}, {"created", s.created_utc},
                      {"updated", s.updated_utc}});
    }
    return done(ReplyCode::kOk, std::to_string(list.size()) + " sessions", {{"sessions", list}});
  }
  if (verb == "get") {
    const std::string id = args["session"];
    if (!IsValidSessionId(id)) return done(ReplyCode::kBadArgument, "session: not a session id");
    const VerifyResult verify = store_->Verify(id);
    if (!verify.manifest_ok) {
      return done(ReplyCode::kNotFound, verify.problems.empty() ? "unknown session" : verify.problems[0]);
    }
    std::string text;
    std::string path = store_->sessions_dir() + "/" + id + "/manifest.json";
    nlohmann::json manifest;
    if (FILE* f = std::fopen(path.c_str(), "rb")) {
      char buffer[65536];
      std::size_t n;
      while ((n = std::fread(buffer, 1, sizeof buffer, f)) > 0) text.append(buffer, n);
      std::fclose(f);
      manifest = nlohmann::json::parse(text, nullptr, false);
    }
    return done(ReplyCode::kOk, verify.IsIntact() ? "intact" : "damaged",
                {{"manifest", manifest}, {"intact", verify.IsIntact()},
                 {"problems", verify.problems}});
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
    request.client = who.name;
    return started(jobs_->StartScan(request, &job, &error));
  }
  if (verb == "resume") {
    const std::string id = args["session"];
    if (!IsValidSessionId(id)) return done(ReplyCode::kBadArgument, "session: not a session id");
    const bool ok = jobs_->StartResume(id, &job, &error);
    if (!ok && error.find("unknown") != std::string::npos) return done(ReplyCode::kNotFound, error);
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
    if (action == "move") {
      if (!args.contains("angle_deg")) return done(ReplyCode::kBadArgument, "missing argument 'angle_deg'");
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
    if (!devices_->ApplyCameraSettings(settings, &error)) return done(ReplyCode::kFailed, error);
    return done(ReplyCode::kOk, "camera settings applied",
                {{"exposure_us", settings.exposure_us}, {"gain_db", settings.gain_db}});
  }
  return done(ReplyCode::kUnknownVerb, "unknown verb '" + verb + "'");
}

}  // namespace craftscan::daemon
