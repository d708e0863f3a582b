// Fuzz target: CheckCommand (daemon/commands.h), everything the daemon
// checks in a DDS command before it acts: sizes, request id, argument JSON,
// token, verb, role and every argument. Input: one byte choosing the token
// (observer, operator, admin, unknown, empty), then request id, client and
// verb on one line each, then the arguments' JSON text.
// Properties: an accepted command is exactly what Dispatch may rely on (a
// known verb, a role that suffices, arguments whose reads cannot throw); a
// refusal has a pre-dispatch code and a message.
#include <string>
#include <string_view>

#include "craftscan/daemon/auth.h"
#include "craftscan/daemon/commands.h"
#include "craftscan/daemon/session_manifest.h"
#include "fuzz_target.h"

namespace {

using craftscan::daemon::ReplyCode;

const craftscan::daemon::TokenAuthority& Tokens() {
  static const craftscan::daemon::TokenAuthority tokens = [] {
    std::string error;
    auto parsed = craftscan::daemon::TokenAuthority::Parse(
        "tokens:\n"
        "  - {name: watcher, token: observer-token-0123456789, role: observer}\n"
        "  - {name: alice, token: operator-token-0123456789, role: operator}\n"
        "  - {name: root, token: admin-token-0123456789abc, role: admin}\n",
        &error);
    if (!parsed) craftscan::fuzz::CheckFailed(error.c_str(), __FILE__, __LINE__);
    return *parsed;
  }();
  return tokens;
}

// The argument reads CommandHandler::Dispatch makes for an accepted command
// (commands.cc); each throws if CheckCommand let a wrong type through.
void ReadLikeDispatch(const std::string& verb, const nlohmann::json& args) {
  if (verb == "get" || verb == "resume") {
    const std::string id = args["session"];
    CRAFTSCAN_FUZZ_CHECK(craftscan::daemon::IsValidSessionId(id));
  }
  if (verb == "get" && args.contains("files")) {  // CommandHandler::GetFiles
    const nlohmann::json& files = args["files"];
    if (files.is_string()) {
      CRAFTSCAN_FUZZ_CHECK(files == "all");
    } else {
      for (const nlohmann::json& item : files) {
        CRAFTSCAN_FUZZ_CHECK(
            craftscan::daemon::IsValidOutputName(item.get_ref<const std::string&>(), nullptr));
      }
    }
    (void)args.value("chunk_bytes", craftscan::daemon::kDefaultTransferChunkBytes);
  } else if (verb == "capture") {
    (void)args.value("object", std::string("object"));
  } else if (verb == "scan") {
    (void)args.value("object", std::string("object"));
    (void)args.value("views", 0);
    (void)args.value("step_deg", 0.0);
  } else if (verb == "turntable") {
    const std::string action = args["action"];
    CRAFTSCAN_FUZZ_CHECK(action == "home" || action == "move");
    if (action == "move") {
      const double angle = args["angle_deg"];
      (void)angle;
    }
  } else if (verb == "camera") {
    (void)args.value("exposure_us", 1.0);
    (void)args.value("gain_db", 0.0);
  }
}

}  // namespace

CRAFTSCAN_FUZZ_TARGET(commands) {
  FuzzInput in(data, size);
  const std::uint32_t who = in.Small(4);
  const std::vector<std::uint8_t> rest_bytes = in.Rest();
  std::string_view rest(reinterpret_cast<const char*>(rest_bytes.data()), rest_bytes.size());
  auto line = [&rest] {
    const std::size_t end = rest.find('\n');
    const std::string text(rest.substr(0, end));
    rest.remove_prefix(end == std::string_view::npos ? rest.size() : end + 1);
    return text;
  };
  daemon::CommandRequest request;
  request.request_id = line();
  request.client = line();
  request.verb = line();
  request.arguments = std::string(rest);
  const char* const kTokens[] = {"observer-token-0123456789", "operator-token-0123456789",
                                 "admin-token-0123456789abc", "unknown-token-0123456789a", ""};
  request.token = kTokens[who];

  daemon::CommandLimits limits;
  limits.max_argument_bytes = 4096;  // small enough for the fuzzer to reach too_large
  const daemon::CommandCheck check = daemon::CheckCommand(request, limits, &Tokens());
  if (!Outcome(check.ok(), check.message)) {
    CRAFTSCAN_FUZZ_CHECK(
        check.code == ReplyCode::kTooLarge || check.code == ReplyCode::kBadRequest ||
        check.code == ReplyCode::kUnauthenticated || check.code == ReplyCode::kUnknownVerb ||
        check.code == ReplyCode::kForbidden || check.code == ReplyCode::kBadArgument);
    CRAFTSCAN_FUZZ_CHECK(check.code != ReplyCode::kUnauthenticated || who >= 3);
    return 0;
  }
  CRAFTSCAN_FUZZ_CHECK(check.message.empty());
  CRAFTSCAN_FUZZ_CHECK(who < 3 && check.identity.has_value());
  CRAFTSCAN_FUZZ_CHECK(!request.request_id.empty());
  CRAFTSCAN_FUZZ_CHECK(request.arguments.size() <= limits.max_argument_bytes);
  CRAFTSCAN_FUZZ_CHECK(check.arguments.is_object());
  const std::optional<daemon::Role> needed = daemon::RequiredRole(request.verb);
  CRAFTSCAN_FUZZ_CHECK(needed && daemon::Satisfies(check.identity->role, *needed));
  try {
    ReadLikeDispatch(request.verb, check.arguments);
  } catch (const std::exception& e) {
    CheckFailed(
        (std::string("an accepted command's arguments read without error: ") + e.what()).c_str(),
        __FILE__, __LINE__);
  }
  return 0;
}
