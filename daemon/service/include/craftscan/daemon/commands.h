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
//   get                                  observer; {"session": str}: manifest + verification;
//                                        with "files": a file transfer (below)
//   capture                              operator; {"object": str}
//   scan                                 operator; {"object": str, "views": int 2..360,
//                                                   "step_deg": number}
//   cancel                               operator; none
//   resume                               operator; {"session": str}
//   turntable                            operator; {"action": "home"|"move",
//                                                   "angle_deg": number}
//   camera                               operator; {"exposure_us": number, "gain_db": number}
//   calibrate, calibrate-turntable       admin; none
//
// get with files: {"session": str, "files": "all" | [name, ...],
//                  "chunk_bytes": int 4096..4194304 (default 1 MiB)}
// sends durable outputs of the session (the manifest's "outputs": fused.ply,
// mesh.ply, mesh.obj, report.json, report.html, previews/...) over the
// station's file topic (craftscan/<station>/file, SessionFile). Names are
// checked with IsValidOutputName (bad_argument) and must be listed in the
// manifest (not_found, naming the outputs there are; "all" of a session
// without outputs is not_found too). The ok Reply's result is
//   {"session": id, "state": "done", "chunk_bytes": n, "total_bytes": n,
//    "files": [{"name": "fused.ply", "size": n, "fnv1a64": "16 hex digits"}, ...]}
// with size and checksum from the manifest; CommandReply::transfer then holds
// the plan the service streams after the Reply: each file in order, in
// chunks of chunk_bytes at increasing offsets, last = true on its last chunk,
// or one chunk with `error` set if the file cannot be sent (the transfer
// stops there). Receivers check offsets (a gap means lost chunks), sizes and
// the FNV-1a 64 checksums. At most kMaxQueuedTransfers transfers wait at a
// time; beyond that get answers busy.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

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

// Bounds of a get file transfer (see the top of this header).
inline constexpr std::size_t kMinTransferChunkBytes = 4096;
inline constexpr std::size_t kMaxTransferChunkBytes = std::size_t{4} << 20;
inline constexpr std::size_t kDefaultTransferChunkBytes = std::size_t{1} << 20;
inline constexpr std::size_t kMaxQueuedTransfers = 4;

// One file of a transfer: its output name, absolute path and the size and
// checksum the manifest lists.
struct TransferFile {
  std::string name, path;
  std::uint64_t size_bytes = 0;
  std::uint64_t fnv1a64 = 0;
};

// What a get with files asks the service to send after the Reply.
struct FileTransfer {
  std::string session;
  std::size_t chunk_bytes = kDefaultTransferChunkBytes;
  std::vector<TransferFile> files;
};

struct CommandReply {
  std::string request_id, client;
  ReplyCode code = ReplyCode::kInternal;
  std::string message;
  nlohmann::json result = nlohmann::json::object();
  // Set only by an ok get with files: the files to stream after the Reply.
  std::optional<FileTransfer> transfer;
};

struct CommandLimits {
  std::size_t max_argument_bytes = 65536;
  std::size_t max_field_bytes = 128;  // request id, client, verb, token, names
};

// The result of CheckCommand: kOk with the parsed arguments and the caller's
// identity, or the refusal (code and message) for the reply.
struct CommandCheck {
  ReplyCode code = ReplyCode::kInternal;
  std::string message;                                  // why it was refused; "" for kOk
  nlohmann::json arguments = nlohmann::json::object();  // kOk: a JSON object
  std::optional<Identity> identity;                     // kOk: who sent it
  bool ok() const { return code == ReplyCode::kOk; }
};

// Every check Handle makes before it acts, in the order listed at the top of
// this file up to bad_argument: sizes, request id, argument JSON, token,
// verb, role, and each argument's key, type and range, including the
// values checked by shape (session ids: IsValidSessionId; turntable action
// "home" | "move", "move" needing angle_deg). Never throws; does no I/O and
// touches no job or device state. `tokens` may be null (every token is then
// unknown). Thread-safe (TokenAuthority is immutable).
CommandCheck CheckCommand(const CommandRequest& request, const CommandLimits& limits,
                          const TokenAuthority* tokens);

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
  // get with "files" (arguments already checked): the reply and the transfer plan.
  CommandReply GetFiles(const std::string& id, const nlohmann::json& args, CommandReply reply);

  CommandLimits limits_;
  const TokenAuthority* tokens_;
  JobEngine* jobs_;
  DeviceManager* devices_;
  SessionStore* store_;
  std::function<nlohmann::json()> status_;
};

}  // namespace craftscan::daemon
