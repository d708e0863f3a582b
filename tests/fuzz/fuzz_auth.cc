// Fuzz target: TokenAuthority::Parse (daemon/auth.h), the tokens file. The
// input is the YAML text; its last line (without a leading '#', so it can be
// a YAML comment) is also presented as a token.
// Properties: a failure names the problem; a parsed authority answers
// Authorize for every known verb with a consistent code, and a refusal's
// message never contains the presented token.
#include <optional>
#include <string>
#include <string_view>

#include "craftscan/daemon/auth.h"
#include "fuzz_target.h"

CRAFTSCAN_FUZZ_TARGET(auth) {
  const std::string yaml(reinterpret_cast<const char*>(data), size);
  std::string error;
  const std::optional<daemon::TokenAuthority> authority =
      daemon::TokenAuthority::Parse(yaml, &error);
  if (!Outcome(authority.has_value(), error)) return 0;
  const std::size_t newline = yaml.rfind('\n');
  std::string token = newline == std::string::npos ? yaml : yaml.substr(newline + 1);
  if (!token.empty() && token.front() == '#') token.erase(0, 1);  // a YAML comment line
  for (const std::string_view verb : daemon::KnownVerbs()) {
    const daemon::Authorization a = authority->Authorize(token, verb);
    const std::optional<daemon::Identity> who = authority->Authenticate(token);
    switch (a.code) {
      case daemon::Authorization::Code::kOk:
        CRAFTSCAN_FUZZ_CHECK(who && a.identity && a.identity->name == who->name);
        CRAFTSCAN_FUZZ_CHECK(daemon::Satisfies(who->role, *daemon::RequiredRole(verb)));
        break;
      case daemon::Authorization::Code::kForbidden:
        CRAFTSCAN_FUZZ_CHECK(who && !daemon::Satisfies(who->role, *daemon::RequiredRole(verb)));
        break;
      case daemon::Authorization::Code::kUnauthenticated:
        CRAFTSCAN_FUZZ_CHECK(!who);
        break;
      case daemon::Authorization::Code::kUnknownVerb:
        CRAFTSCAN_FUZZ_CHECK(false);  // every verb of KnownVerbs is known
        break;
    }
    // (A name may happen to contain the token's text; that is not a leak.)
    if (!a.ok() && token.size() >= 16 && !(who && who->name.find(token) != std::string::npos)) {
      CRAFTSCAN_FUZZ_CHECK(a.message.find(token) == std::string::npos);
    }
  }
  return 0;
}
