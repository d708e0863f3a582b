// Command authorisation for craftscand: roles, the tokens file, and which
// role each command verb needs.
//
// Roles are ordered: observer < operator < admin; a client holding a role
// may do everything the lower roles may.
//
// Verb table (RequiredRole):
//   observer  status, sessions, devices, get          read state, list, fetch results
//   operator  capture, scan, cancel, resume,          run jobs and move the hardware
//             turntable, camera
//   admin     calibrate, calibrate-turntable          change what every later scan
//                                                     depends on (the calibration)
// Any other verb is unknown (std::nullopt): the daemon refuses it as such.
//
// Tokens file (YAML; auth.tokens_file in the daemon config):
//   tokens:
//     - {name: alice, token: "k3J9…", role: operator}
//     - {name: archive, token: "…", role: observer}
// Load checks: a regular file, owned by the effective uid, no permission
// bits for group or others (mode & 077 == 0); names [A-Za-z0-9_.@-]{1,64}
// and unique; tokens 16..128 printable ASCII characters without spaces and
// unique; role one of observer, operator, admin; no other keys. An empty list
// is allowed (every command is then refused). Generate tokens with e.g.
// `openssl rand -base64 24`.
#pragma once

#include <cstddef>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace craftscan::daemon {

enum class Role { kObserver = 0, kOperator = 1, kAdmin = 2 };
std::string_view ToString(Role role);  // "observer", "operator", "admin"
bool RoleFromString(std::string_view text, Role* role);
// Whether a client holding `granted` may do what `required` allows.
inline bool Satisfies(Role granted, Role required) {
  return static_cast<int>(granted) >= static_cast<int>(required);
}

// The role a command verb needs (table above); std::nullopt for an unknown verb.
std::optional<Role> RequiredRole(std::string_view verb);
// The verbs RequiredRole knows, in table order.
const std::vector<std::string_view>& KnownVerbs();

// Who a token belongs to.
struct Identity {
  std::string name;
  Role role = Role::kObserver;
};

// The outcome of TokenAuthority::Authorize.
struct Authorization {
  enum class Code {
    kOk,
    kUnknownVerb,      // RequiredRole(verb) is nullopt
    kUnauthenticated,  // the token matches no entry
    kForbidden,        // known client, role too low
  };
  Code code = Code::kUnauthenticated;
  std::optional<Identity> identity;  // set for kOk and kForbidden
  std::string message;               // for the reply; never contains the token

  bool ok() const { return code == Code::kOk; }
};

// The tokens of a tokens file. Immutable after loading: all methods are
// const and thread-safe.
class TokenAuthority {
 public:
  // Reads and checks the tokens file (see the top of this header). On failure
  // returns std::nullopt with *error naming the file and the problem (e.g.
  // "…/tokens.yaml: mode 0644 lets group or others access it; run chmod 600 …",
  // "…: tokens[2].token: shorter than 16 characters"). Never throws.
  static std::optional<TokenAuthority> Load(const std::string& path, std::string* error);
  // The content checks of Load on YAML text, without the file checks.
  static std::optional<TokenAuthority> Parse(const std::string& yaml_text, std::string* error);

  // The identity whose token equals `token`, or std::nullopt. The comparison
  // takes the same time whichever entry matches or how much of a token
  // matches: every entry is compared in full (time depends only on the
  // length of `token` and the number of entries).
  std::optional<Identity> Authenticate(std::string_view token) const;

  // Authenticates `token` and checks the verb's required role.
  Authorization Authorize(std::string_view token, std::string_view verb) const;

  std::size_t size() const { return entries_.size(); }

 private:
  struct Entry {
    std::string token;
    Identity identity;
  };
  std::vector<Entry> entries_;
};

}  // namespace craftscan::daemon
