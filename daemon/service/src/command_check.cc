// The checks of a command before the daemon acts on it (CheckCommand), the
// reply codes' names and the flood protection (CutCommandRequest,
// CommandRateLimiter). Pure: no jobs, devices or files, so the fuzzers and
// tests can run it alone.
#include <algorithm>
#include <cmath>
#include <map>
#include <utility>

#include "craftscan/daemon/commands.h"
#include "craftscan/daemon/session_manifest.h"

namespace craftscan::daemon {
namespace {

// kNames: the string "all" or "session", or a list of 1..256 strings of
// min..max bytes.
// kNumbers: a list of at most `max` numbers (values are the verb's to check).
enum class ArgType { kString, kInt, kNumber, kNames, kNumbers };

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
      {"get",
       {{"session", {ArgType::kString, true, 1, 128}},
        {"files", {ArgType::kNames, false, 1, 200}},
        {"chunk_bytes",
         {ArgType::kInt, false, static_cast<double>(kMinTransferChunkBytes),
          static_cast<double>(kMaxTransferChunkBytes)}}}},
      {"capture", {{"object", {ArgType::kString, false, 1, 128}}}},
      {"scan",
       {{"object", {ArgType::kString, false, 1, 128}},
        {"views", {ArgType::kInt, false, 2, 360}},
        {"step_deg", {ArgType::kNumber, false, -360, 360}},
        {"exposure_bracket", {ArgType::kNumbers, false, 0, 4}},
        {"add_to", {ArgType::kString, false, 1, 128}}}},
      {"cancel", {}},
      {"resume", {{"session", {ArgType::kString, true, 1, 128}}}},
      {"turntable",
       {{"action", {ArgType::kString, true, 1, 16}},
        {"angle_deg", {ArgType::kNumber, false, -3600, 3600}}}},
      {"camera",
       {{"exposure_us", {ArgType::kNumber, false, 1, 10e6}},
        {"gain_db", {ArgType::kNumber, false, 0, 48}}}},
      {"preview",
       {{"action", {ArgType::kString, true, 1, 16}},
        {"fps", {ArgType::kNumber, false, 0.1, 15}},
        {"width", {ArgType::kInt, false, 64, 4096}},
        {"seconds", {ArgType::kNumber, false, 1, 600}}}},
      {"delete", {{"session", {ArgType::kString, true, 1, 128}}}},
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
          *why = key + ": must be an integer in " + std::to_string(static_cast<int>(s.min)) + ".." +
                 std::to_string(static_cast<int>(s.max));
          return false;
        }
        break;
      case ArgType::kNames: {
        if (value.is_string() && (value.get_ref<const std::string&>() == "all" ||
                                  value.get_ref<const std::string&>() == "session")) {
          break;
        }
        bool ok = value.is_array() && !value.empty() && value.size() <= 256;
        for (std::size_t i = 0; ok && i < value.size(); ++i) {
          ok = value[i].is_string() && value[i].get_ref<const std::string&>().size() >= s.min &&
               value[i].get_ref<const std::string&>().size() <= s.max;
        }
        if (!ok) {
          *why = key + ": must be \"all\", \"session\" or a list of 1..256 names of " +
                 std::to_string(static_cast<int>(s.min)) + ".." +
                 std::to_string(static_cast<int>(s.max)) + " bytes";
          return false;
        }
        break;
      }
      case ArgType::kNumbers: {
        bool ok = value.is_array() && value.size() <= s.max;
        for (std::size_t i = 0; ok && i < value.size(); ++i) {
          ok = value[i].is_number() && std::isfinite(value[i].get<double>());
        }
        if (!ok) {
          *why = key + ": must be a list of at most " + std::to_string(static_cast<int>(s.max)) +
                 " numbers";
          return false;
        }
        break;
      }
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

// calibration.yaml or views/NNN/<file>: a session file a worker fetches
// besides the outputs (`get` with a list of names).
bool IsSessionInputName(const std::string& name) {
  if (name == kCalibrationYaml) return true;
  if (name.size() < 11 || name.compare(0, 6, "views/") != 0 || name[9] != '/') return false;
  for (int i = 6; i < 9; ++i)
    if (name[i] < '0' || name[i] > '9') return false;
  const std::string file = name.substr(10);
  std::string why;
  return file.find('/') == std::string::npos && IsValidOutputName(file, &why);
}

// The checks of argument values by shape, after CheckArguments has checked
// their types and ranges.
bool CheckValues(const std::string& verb, const nlohmann::json& args, std::string* why) {
  if ((verb == "get" || verb == "resume") &&
      !IsValidSessionId(args["session"].get_ref<const std::string&>())) {
    *why = "session: not a session id";
    return false;
  }
  if (verb == "scan" && args.contains("add_to")) {
    if (!IsValidSessionId(args["add_to"].get_ref<const std::string&>())) {
      *why = "add_to: not a session id";
      return false;
    }
    if (args.contains("object")) {
      *why = "object: not with add_to (the session names the object)";
      return false;
    }
  }
  if (verb == "get" && args.contains("files") && args["files"].is_array()) {
    for (const nlohmann::json& name : args["files"]) {
      if (!IsValidOutputName(name.get_ref<const std::string&>(), why) &&
          !IsSessionInputName(name.get_ref<const std::string&>())) {
        *why = "files: '" + name.get<std::string>() + "': " + *why;
        return false;
      }
    }
  }
  if (verb == "turntable") {
    const std::string& action = args["action"].get_ref<const std::string&>();
    if (action != "home" && action != "move") {
      *why = "action: must be 'home' or 'move'";
      return false;
    }
    if (action == "move" && !args.contains("angle_deg")) {
      *why = "missing argument 'angle_deg'";
      return false;
    }
  }
  return true;
}

}  // namespace

std::string_view ToString(ReplyCode code) {
  switch (code) {
    case ReplyCode::kOk:
      return "ok";
    case ReplyCode::kBadRequest:
      return "bad_request";
    case ReplyCode::kUnauthenticated:
      return "unauthenticated";
    case ReplyCode::kUnknownVerb:
      return "unknown_verb";
    case ReplyCode::kForbidden:
      return "forbidden";
    case ReplyCode::kBadArgument:
      return "bad_argument";
    case ReplyCode::kBusy:
      return "busy";
    case ReplyCode::kNotFound:
      return "not_found";
    case ReplyCode::kUnavailable:
      return "unavailable";
    case ReplyCode::kFailed:
      return "failed";
    case ReplyCode::kTooLarge:
      return "too_large";
    case ReplyCode::kInternal:
      return "internal";
  }
  return "internal";
}

CommandCheck CheckCommand(const CommandRequest& request, const CommandLimits& limits,
                          const TokenAuthority* tokens) {
  CommandCheck check;
  auto refuse = [&](ReplyCode code, std::string message) {
    check.code = code;
    check.message = std::move(message);
    check.arguments = nlohmann::json::object();
    check.identity.reset();
    return check;
  };
  const std::size_t argument_bytes =
      std::max(request.arguments.size(), request.received_arguments_bytes);
  if (argument_bytes > limits.max_argument_bytes) {
    return refuse(ReplyCode::kTooLarge, "arguments are " + std::to_string(argument_bytes) +
                                            " bytes; the limit is " +
                                            std::to_string(limits.max_argument_bytes));
  }
  for (const auto* field : {&request.request_id, &request.client, &request.verb, &request.token}) {
    if (field->size() > limits.max_field_bytes) {
      return refuse(ReplyCode::kTooLarge, "request_id, client, verb and token are limited to " +
                                              std::to_string(limits.max_field_bytes) + " bytes");
    }
  }
  if (request.request_id.empty()) return refuse(ReplyCode::kBadRequest, "request_id is empty");
  if (!request.arguments.empty()) {
    check.arguments = nlohmann::json::parse(request.arguments, nullptr, /*allow_exceptions=*/false);
    if (check.arguments.is_discarded()) {
      return refuse(ReplyCode::kBadRequest, "arguments are not valid JSON");
    }
    if (!check.arguments.is_object()) {
      return refuse(ReplyCode::kBadRequest, "arguments must be a JSON object");
    }
  }
  check.identity = tokens ? tokens->Authenticate(request.token) : std::nullopt;
  if (!check.identity) return refuse(ReplyCode::kUnauthenticated, "unknown token");
  const auto verb = VerbArguments().find(request.verb);
  const std::optional<Role> needed = RequiredRole(request.verb);
  if (verb == VerbArguments().end() || !needed) {
    std::string known;
    for (const auto& [name, unused] : VerbArguments()) known += (known.empty() ? "" : ", ") + name;
    return refuse(ReplyCode::kUnknownVerb, "unknown verb '" +
                                               request.verb.substr(0, limits.max_field_bytes) +
                                               "' (known: " + known + ")");
  }
  if (!Satisfies(check.identity->role, *needed)) {
    return refuse(ReplyCode::kForbidden,
                  "'" + request.verb + "' needs role " + std::string(ToString(*needed)) + "; " +
                      check.identity->name + " is " + std::string(ToString(check.identity->role)));
  }
  std::string why;
  if (!CheckArguments(verb->second, check.arguments, &why) ||
      !CheckValues(request.verb, check.arguments, &why)) {
    return refuse(ReplyCode::kBadArgument, why);
  }
  check.code = ReplyCode::kOk;
  return check;
}

CommandRequest CutCommandRequest(std::string_view request_id, std::string_view client,
                                 std::string_view token, std::string_view verb,
                                 std::string_view arguments, const CommandLimits& limits) {
  auto cut = [](std::string_view text, std::size_t limit) {
    return std::string(text.size() > limit ? text.substr(0, limit + 1) : text);
  };
  CommandRequest request;
  request.request_id = cut(request_id, limits.max_field_bytes);
  request.client = cut(client, limits.max_field_bytes);
  request.token = cut(token, limits.max_field_bytes);
  request.verb = cut(verb, limits.max_field_bytes);
  request.arguments = cut(arguments, limits.max_argument_bytes);
  if (request.arguments.size() < arguments.size())
    request.received_arguments_bytes = arguments.size();
  return request;
}

bool IsQueryVerb(std::string_view verb) {
  return verb == "status" || verb == "devices" || verb == "sessions" || verb == "get";
}

double TokenBucket::Level(Clock::time_point now) const {
  const double elapsed_s = std::chrono::duration<double>(now - last_).count();
  return std::min(burst_, tokens_ + std::max(0.0, elapsed_s) * rate_per_s_);
}

bool TokenBucket::Take(Clock::time_point now) {
  tokens_ = Level(now);
  last_ = std::max(last_, now);
  if (tokens_ < 1) return false;
  tokens_ -= 1;
  return true;
}

bool TokenBucket::Full(Clock::time_point now) const { return Level(now) >= burst_; }

bool CommandRateLimiter::Admit(std::string_view client, Clock::time_point now) {
  const std::string name(client.substr(0, CommandLimits{}.max_field_bytes));
  auto it = buckets_.find(name);
  if (it == buckets_.end()) {
    if (buckets_.size() >= kMaxRateLimitedClients) {
      std::erase_if(buckets_, [&](const auto& entry) { return entry.second.Full(now); });
    }
    if (buckets_.size() >= kMaxRateLimitedClients) {
      if (!shared_) shared_.emplace(kClientCommandsPerSecond, kClientCommandBurst, now);
      return shared_->Take(now);
    }
    it = buckets_.emplace(name, TokenBucket(kClientCommandsPerSecond, kClientCommandBurst, now))
             .first;
  }
  return it->second.Take(now);
}

std::string CommandRateLimiter::RefusalMessage(std::string_view client) {
  return "busy: too many commands from client '" +
         std::string(client.substr(0, CommandLimits{}.max_field_bytes)) + "' (more than " +
         std::to_string(static_cast<int>(kClientCommandsPerSecond)) + " a second, bursts of " +
         std::to_string(static_cast<int>(kClientCommandBurst)) + "); slow down and retry";
}

}  // namespace craftscan::daemon

namespace craftscan::daemon {

std::string ReplyMemory::Key(const CommandRequest& request) {
  // The token is part of the key (hashed: only its equality matters), so a
  // request id replayed with another token is handled as a new command.
  return request.client + '\n' + request.request_id + '\n' +
         std::to_string(std::hash<std::string>{}(request.token));
}

const CommandReply* ReplyMemory::Find(const CommandRequest& request, bool* known) {
  if (known) *known = false;
  if (request.request_id.empty()) return nullptr;
  const auto it = replies_.find(Key(request));
  if (it == replies_.end()) return nullptr;
  if (known) *known = true;
  if (it->second.repeats >= kMaxReplyRepeats) return nullptr;
  ++it->second.repeats;
  return &it->second.reply;
}

void ReplyMemory::Remember(const CommandRequest& request, const CommandReply& reply) {
  if (request.request_id.empty()) return;
  std::string key = Key(request);
  Entry entry{reply, 0};
  entry.reply.transfer.reset();  // the chunks went once, after the first reply
  const auto [it, inserted] = replies_.insert_or_assign(key, std::move(entry));
  (void)it;
  if (!inserted) return;
  order_.push_back(std::move(key));
  while (order_.size() > kRememberedReplies) {
    replies_.erase(order_.front());
    order_.pop_front();
  }
}

}  // namespace craftscan::daemon
