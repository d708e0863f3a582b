#include "craftscan/daemon/auth.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>
#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <set>
#include <utility>

namespace craftscan::daemon {
namespace {

constexpr std::size_t kMinTokenLength = 16;
// A command carries its token in a field of at most 128 bytes
// (CommandLimits::max_field_bytes): a longer token could never be presented.
constexpr std::size_t kMaxTokenLength = 128;
constexpr std::size_t kMaxFileBytes = 1 << 20;

struct VerbRole {
  std::string_view verb;
  Role role;
};
constexpr std::array<VerbRole, 14> kVerbRoles = {{
    {"status", Role::kObserver},
    {"sessions", Role::kObserver},
    {"devices", Role::kObserver},
    {"get", Role::kObserver},
    {"capture", Role::kOperator},
    {"scan", Role::kOperator},
    {"cancel", Role::kOperator},
    {"resume", Role::kOperator},
    {"turntable", Role::kOperator},
    {"camera", Role::kOperator},
    {"preview", Role::kOperator},
    {"calibrate", Role::kAdmin},
    {"calibrate-turntable", Role::kAdmin},
    {"delete", Role::kAdmin},
}};

std::optional<TokenAuthority> Fail(std::string* error, std::string message) {
  if (error) *error = std::move(message);
  return std::nullopt;
}

bool IsName(std::string_view name) {
  if (name.empty() || name.size() > 64) return false;
  return std::all_of(name.begin(), name.end(), [](char ch) {
    return (ch >= 'a' && ch <= 'z') || (ch >= 'A' && ch <= 'Z') || (ch >= '0' && ch <= '9') ||
           ch == '_' || ch == '.' || ch == '@' || ch == '-';
  });
}

bool IsTokenText(std::string_view token) {
  return std::all_of(token.begin(), token.end(), [](char ch) { return ch > ' ' && ch < 0x7f; });
}

// Equality of `presented` with `stored` in time that depends only on
// presented.size(): no early exit on the first difference.
bool ConstantTimeEquals(std::string_view presented, std::string_view stored) {
  std::uint32_t difference = presented.size() == stored.size() ? 0 : 1;
  if (stored.empty()) return false;
  for (std::size_t i = 0; i < presented.size(); ++i) {
    difference |= static_cast<std::uint8_t>(presented[i]) ^
                  static_cast<std::uint8_t>(stored[i % stored.size()]);
  }
  return difference == 0;
}

// A client-supplied verb for a message: printable ASCII, at most 64 characters.
std::string Printable(std::string_view text) {
  std::string out;
  for (char ch : text.substr(0, 64)) out += (ch >= ' ' && ch < 0x7f) ? ch : '?';
  return text.size() > 64 ? out + "…" : out;
}

std::string ModeText(mode_t mode) {
  std::array<char, 8> text{};
  std::snprintf(text.data(), text.size(), "%04o", static_cast<unsigned>(mode & 07777));
  return text.data();
}

}  // namespace

std::string_view ToString(Role role) {
  switch (role) {
    case Role::kObserver:
      return "observer";
    case Role::kOperator:
      return "operator";
    case Role::kAdmin:
      return "admin";
  }
  return "unknown";
}

bool RoleFromString(std::string_view text, Role* role) {
  for (Role r : {Role::kObserver, Role::kOperator, Role::kAdmin}) {
    if (text == ToString(r)) {
      *role = r;
      return true;
    }
  }
  return false;
}

std::optional<Role> RequiredRole(std::string_view verb) {
  for (const VerbRole& entry : kVerbRoles) {
    if (entry.verb == verb) return entry.role;
  }
  return std::nullopt;
}

const std::vector<std::string_view>& KnownVerbs() {
  static const std::vector<std::string_view> verbs = [] {
    std::vector<std::string_view> v;
    for (const VerbRole& entry : kVerbRoles) v.push_back(entry.verb);
    return v;
  }();
  return verbs;
}

std::optional<TokenAuthority> TokenAuthority::Load(const std::string& path, std::string* error) {
  // O_NONBLOCK: opening a FIFO must not wait for a writer; the checks below
  // refuse it anyway. The checks run on the opened file (fstat), so the file
  // cannot be swapped between check and read.
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NOCTTY | O_NONBLOCK);
  if (fd < 0) return Fail(error, path + ": cannot open: " + std::strerror(errno));
  struct FdCloser {
    int fd;
    ~FdCloser() { ::close(fd); }
  } closer{fd};
  struct stat st {};
  if (::fstat(fd, &st) != 0) return Fail(error, path + ": cannot stat: " + std::strerror(errno));
  if (!S_ISREG(st.st_mode)) return Fail(error, path + ": not a regular file");
  if (st.st_uid != ::geteuid()) {
    return Fail(error, path + ": owned by uid " + std::to_string(st.st_uid) +
                           ", but craftscand runs as uid " + std::to_string(::geteuid()) +
                           "; the tokens file must belong to the daemon's user");
  }
  if ((st.st_mode & 077) != 0) {
    return Fail(error, path + ": mode " + ModeText(st.st_mode) +
                           " lets group or others access it; run chmod 600 " + path);
  }
  if (static_cast<std::size_t>(st.st_size) > kMaxFileBytes) {
    return Fail(error, path + ": larger than " + std::to_string(kMaxFileBytes) + " bytes");
  }
  std::string text;
  std::array<char, 4096> buffer{};
  for (;;) {
    const ssize_t n = ::read(fd, buffer.data(), buffer.size());
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) return Fail(error, path + ": read error: " + std::strerror(errno));
    if (n == 0) break;
    text.append(buffer.data(), static_cast<std::size_t>(n));
    if (text.size() > kMaxFileBytes) {
      return Fail(error, path + ": larger than " + std::to_string(kMaxFileBytes) + " bytes");
    }
  }
  std::string why;
  std::optional<TokenAuthority> authority = Parse(text, &why);
  if (!authority) return Fail(error, path + ": " + why);
  return authority;
}

std::optional<TokenAuthority> TokenAuthority::Parse(const std::string& yaml_text,
                                                    std::string* error) {
  TokenAuthority authority;
  try {
    const YAML::Node root = YAML::Load(yaml_text);
    if (!root.IsMap()) return Fail(error, "expected a mapping with a 'tokens' list");
    for (const auto& entry : root) {
      if (!entry.first.IsScalar() || entry.first.Scalar() != "tokens") {
        return Fail(error, (entry.first.IsScalar() ? entry.first.Scalar() : std::string("key")) +
                               ": unknown key (expected only 'tokens')");
      }
    }
    const YAML::Node tokens = root["tokens"];
    if (!tokens || tokens.IsNull()) return Fail(error, "tokens: missing");
    if (!tokens.IsSequence()) return Fail(error, "tokens: must be a list");
    std::set<std::string> names;
    for (std::size_t i = 0; i < tokens.size(); ++i) {
      const std::string where = "tokens[" + std::to_string(i + 1) + "]";
      const YAML::Node item = tokens[i];
      if (!item.IsMap()) return Fail(error, where + ": must be a mapping {name, token, role}");
      for (const auto& field : item) {
        const std::string key = field.first.IsScalar() ? field.first.Scalar() : "";
        if (key != "name" && key != "token" && key != "role") {
          return Fail(error, where + "." + key + ": unknown key (expected name, token, role)");
        }
        if (!field.second.IsScalar()) {
          return Fail(error, where + "." + key + ": must be a single value");
        }
      }
      for (const char* key : {"name", "token", "role"}) {
        if (!item[key]) return Fail(error, where + "." + key + ": missing");
      }
      Entry e;
      e.identity.name = item["name"].Scalar();
      e.token = item["token"].Scalar();
      const std::string role = item["role"].Scalar();
      if (!IsName(e.identity.name)) {
        return Fail(error, where + ".name: must be 1 to 64 characters of A-Z, a-z, 0-9, _ . @ -");
      }
      if (!names.insert(e.identity.name).second) {
        return Fail(error, where + ".name: '" + e.identity.name + "' is listed twice");
      }
      if (e.token.size() < kMinTokenLength) {
        return Fail(error, where + ".token (" + e.identity.name + "): shorter than " +
                               std::to_string(kMinTokenLength) + " characters");
      }
      if (e.token.size() > kMaxTokenLength || !IsTokenText(e.token)) {
        return Fail(error, where + ".token (" + e.identity.name + "): must be at most " +
                               std::to_string(kMaxTokenLength) +
                               " printable ASCII characters without spaces");
      }
      for (const Entry& other : authority.entries_) {
        if (other.token == e.token) {
          return Fail(error, where + ".token (" + e.identity.name + "): same token as " +
                                 other.identity.name + "; every client needs its own token");
        }
      }
      if (!RoleFromString(role, &e.identity.role)) {
        return Fail(error, where + ".role (" + e.identity.name +
                               "): must be one of observer, operator, admin; got '" + role + "'");
      }
      authority.entries_.push_back(std::move(e));
    }
  } catch (const YAML::Exception& e) {
    std::string where;
    if (!e.mark.is_null()) where = " at line " + std::to_string(e.mark.line + 1);
    return Fail(error, "YAML syntax error" + where + ": " + e.msg);
  }
  return authority;
}

std::optional<Identity> TokenAuthority::Authenticate(std::string_view token) const {
  const Entry* match = nullptr;
  for (const Entry& entry : entries_) {
    // Evaluate every comparison; tokens are unique, so at most one matches.
    const bool equal = ConstantTimeEquals(token, entry.token);
    if (equal) match = &entry;
  }
  if (match == nullptr) return std::nullopt;
  return match->identity;
}

Authorization TokenAuthority::Authorize(std::string_view token, std::string_view verb) const {
  Authorization result;
  const std::optional<Role> required = RequiredRole(verb);
  if (!required) {
    result.code = Authorization::Code::kUnknownVerb;
    result.message = "unknown command '" + Printable(verb) + "'";
    return result;
  }
  result.identity = Authenticate(token);
  if (!result.identity) {
    result.code = Authorization::Code::kUnauthenticated;
    result.message = "invalid token";
    return result;
  }
  if (!Satisfies(result.identity->role, *required)) {
    result.code = Authorization::Code::kForbidden;
    result.message = "'" + std::string(verb) + "' needs role " + std::string(ToString(*required)) +
                     "; " + result.identity->name + " has " +
                     std::string(ToString(result.identity->role));
    return result;
  }
  result.code = Authorization::Code::kOk;
  return result;
}

}  // namespace craftscan::daemon
