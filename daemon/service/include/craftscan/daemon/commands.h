// Command handling, independent of DDS: a Command (request id, client,
// token, verb, JSON arguments) becomes a Reply with a code, a message and a
// JSON result. Every command is checked in this order, and the first failure
// is the reply:
//
//   too_large        the arguments exceed limits.max_command_bytes, or an id
//                    or name is longer than 128 bytes
//   bad_request      request id missing, arguments not a JSON object
//   unauthenticated  the token is not in the tokens file
//   unknown_verb     the verb is not one of the verbs below
//   forbidden        the token's role is below the verb's role
//   bad_argument     an unknown key, a wrong type or an out-of-range value
//                    (the message names the key)
//   busy             a job is running (for verbs that start one)
//   not_found        unknown session
//   unavailable      the devices are not open
//   failed           the action was tried and failed (message says why)
//   ok
//
// Verbs (role; arguments):
//   status, devices, sessions            observer; none
//   get                                  observer; {"session": str}: manifest + verification
//   capture                              operator; {"object": str}
//   scan                                 operator; {"object": str, "views": int 2..360,
//                                                   "step_deg": number}
//   cancel                               operator; none
//   resume                               operator; {"session": str}
//   turntable                            operator; {"action": "home"|"move",
//                                                   "angle_deg": number}
//   camera                               operator; {"exposure_us": number, "gain_db": number}
//   calibrate, calibrate-turntable       admin; none
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <string_view>

#include <nlohmann/json.hpp>

#include "craftscan/daemon/auth.h"

namespace craftscan::daemon {

class DeviceManager;
class JobEngine;
class SessionStore;

enum class ReplyCode : std::int32_t {
  kOk = 0,
  kBadRequest = 1,
  kUnauthenticated = 2,
  kUnknownVerb = 3,
  kForbidden = 4,
  kBadArgument = 5,
  kBusy = 6,
  kNotFound = 7,
  kUnavailable = 8,
  kFailed = 9,
  kTooLarge = 10,
  kInternal = 11,
};
std::string_view ToString(ReplyCode code);  // "ok", "bad_request", ...

struct CommandRequest {
  std::string request_id, client, token, verb, arguments;  // arguments: JSON text ("" = {})
};

struct CommandReply {
  std::string request_id, client;
  ReplyCode code = ReplyCode::kInternal;
  std::string message;
  nlohmann::json result = nlohmann::json::object();
};

struct CommandLimits {
  std::size_t max_argument_bytes = 65536;
  std::size_t max_field_bytes = 128;  // request id, client, verb, token, names
};

// Thread-safety: Handle may be called from one thread at a time (the
// service's command loop).
class CommandHandler {
 public:
  // `status` returns the station's status as JSON (for the status verb).
  CommandHandler(CommandLimits limits, const TokenAuthority* tokens, JobEngine* jobs,
                 DeviceManager* devices, SessionStore* store,
                 std::function<nlohmann::json()> status);

  CommandReply Handle(const CommandRequest& request);

 private:
  CommandReply Dispatch(const std::string& verb, const nlohmann::json& args,
                        const Identity& who, CommandReply reply);

  CommandLimits limits_;
  const TokenAuthority* tokens_;
  JobEngine* jobs_;
  DeviceManager* devices_;
  SessionStore* store_;
  std::function<nlohmann::json()> status_;
};

}  // namespace craftscan::daemon
