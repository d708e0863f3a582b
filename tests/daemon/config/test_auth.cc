// Command authorisation: the tokens file checks (permissions, ownership,
// content), authentication, the verb → role table.
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <string>

#include "../../unit/test_util.h"
#include "craftscan/daemon/auth.h"

namespace craftscan::daemon {
namespace {

using ::testing::HasSubstr;

constexpr char kAliceToken[] = "alice-0123456789abcdef";
constexpr char kBobToken[] = "bob-ZYXWVUTSRQPONMLK";
constexpr char kRootToken[] = "root-!#$%&()*+,-./0123";

const std::string kTokens = std::string("tokens:\n") + "  - {name: alice, token: \"" + kAliceToken +
                            "\", role: operator}\n" + "  - {name: bob, token: \"" + kBobToken +
                            "\", role: observer}\n" + "  - {name: root@site, token: \"" +
                            kRootToken + "\", role: admin}\n";

class TokensFile : public testing::TempDirTest {
 protected:
  std::string WriteTokens(const std::string& text, mode_t mode) {
    const std::string path = WriteBytes("tokens.yaml", text);
    EXPECT_EQ(::chmod(path.c_str(), mode), 0);
    return path;
  }
};

TEST_F(TokensFile, LoadsAPrivateFile) {
  const std::string path = WriteTokens(kTokens, 0600);
  std::string error;
  const auto authority = TokenAuthority::Load(path, &error);
  ASSERT_TRUE(authority) << error;
  EXPECT_EQ(authority->size(), 3u);
  // Read-only for the owner is fine too.
  ASSERT_EQ(::chmod(path.c_str(), 0400), 0);
  EXPECT_TRUE(TokenAuthority::Load(path, &error)) << error;
}

TEST_F(TokensFile, RefusesModesOpenToGroupOrOthers) {
  for (mode_t mode : {0640, 0604, 0660, 0644, 0602, 0610, 0777}) {
    const std::string path = WriteTokens(kTokens, mode);
    std::string error;
    EXPECT_FALSE(TokenAuthority::Load(path, &error)) << std::oct << mode;
    char mode_text[8];
    std::snprintf(mode_text, sizeof mode_text, "%04o", static_cast<unsigned>(mode));
    EXPECT_THAT(error, HasSubstr(path + ": mode " + mode_text +
                                 " lets group or others access it; run chmod 600"));
  }
}

TEST_F(TokensFile, RefusesAFileOwnedBySomeoneElse) {
  const std::string path = WriteTokens(kTokens, 0600);
  const uid_t other = ::geteuid() == 0 ? 65534 : 0;
  if (::chown(path.c_str(), other, static_cast<gid_t>(-1)) != 0) {
    GTEST_SKIP() << "cannot chown the test file to another user (needs root)";
  }
  std::string error;
  EXPECT_FALSE(TokenAuthority::Load(path, &error));
  EXPECT_THAT(error, HasSubstr(path + ": owned by uid " + std::to_string(other) +
                               ", but craftscand runs as uid " + std::to_string(::geteuid())));
}

TEST_F(TokensFile, RefusesWhatIsNotARegularFile) {
  std::string error;
  EXPECT_FALSE(TokenAuthority::Load(dir_.string(), &error));
  EXPECT_EQ(error, dir_.string() + ": not a regular file");
  const std::string fifo = Path("fifo");
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  EXPECT_FALSE(TokenAuthority::Load(fifo, &error));  // must not block waiting for a writer
  EXPECT_EQ(error, fifo + ": not a regular file");
  EXPECT_FALSE(TokenAuthority::Load(Path("absent.yaml"), &error));
  EXPECT_THAT(error, HasSubstr("absent.yaml: cannot open: No such file"));
}

TEST_F(TokensFile, ContentErrorsNameTheFileAndEntry) {
  const std::string path =
      WriteTokens("tokens:\n  - {name: eve, token: short, role: admin}\n", 0600);
  std::string error;
  EXPECT_FALSE(TokenAuthority::Load(path, &error));
  EXPECT_EQ(error, path + ": tokens[1].token (eve): shorter than 16 characters");
}

struct BadTokensCase {
  std::string yaml;
  std::string expected;
};
class BadTokens : public ::testing::TestWithParam<BadTokensCase> {};

TEST_P(BadTokens, IsRefused) {
  std::string error;
  EXPECT_FALSE(TokenAuthority::Parse(GetParam().yaml, &error));
  EXPECT_THAT(error, HasSubstr(GetParam().expected)) << GetParam().yaml;
  EXPECT_THAT(error, ::testing::Not(HasSubstr("0123456789abcdef"))) << "token leaked in message";
}

INSTANTIATE_TEST_SUITE_P(
    Content, BadTokens,
    ::testing::Values(
        BadTokensCase{"", "expected a mapping with a 'tokens' list"},
        BadTokensCase{"tokens: 3\n", "tokens: must be a list"},
        BadTokensCase{"users: []\n", "users: unknown key (expected only 'tokens')"},
        BadTokensCase{"tokens:\n  - alice\n", "tokens[1]: must be a mapping {name, token, role}"},
        BadTokensCase{"tokens:\n  - {name: a, role: admin}\n", "tokens[1].token: missing"},
        BadTokensCase{"tokens:\n  - {name: a, token: 0123456789abcdef, role: admin, note: x}\n",
                      "tokens[1].note: unknown key"},
        BadTokensCase{"tokens:\n  - {name: a b, token: 0123456789abcdef, role: admin}\n",
                      "tokens[1].name: must be 1 to 64 characters"},
        BadTokensCase{"tokens:\n  - {name: a, token: 0123456789abcde, role: admin}\n",
                      "tokens[1].token (a): shorter than 16 characters"},
        BadTokensCase{
            "tokens:\n  - {name: a, token: \"0123456789 abcdef\", role: admin}\n",
            "tokens[1].token (a): must be at most 128 printable ASCII characters without spaces"},
        BadTokensCase{"tokens:\n  - {name: a, token: 0123456789abcdef, role: root}\n",
                      "tokens[1].role (a): must be one of observer, operator, admin; got 'root'"},
        BadTokensCase{"tokens:\n  - {name: a, token: 0123456789abcdef, role: admin}\n"
                      "  - {name: b, token: 0123456789abcdef, role: observer}\n",
                      "tokens[2].token (b): same token as a; every client needs its own token"},
        BadTokensCase{"tokens:\n  - {name: a, token: 0123456789abcdef, role: admin}\n"
                      "  - {name: a, token: 0123456789abcdeg, role: observer}\n",
                      "tokens[2].name: 'a' is listed twice"},
        BadTokensCase{"tokens: [\n", "YAML syntax error"}));

TEST(TokenAuthority, AuthenticatesGoodTokensOnly) {
  std::string error;
  const auto authority = TokenAuthority::Parse(kTokens, &error);
  ASSERT_TRUE(authority) << error;

  const auto alice = authority->Authenticate(kAliceToken);
  ASSERT_TRUE(alice);
  EXPECT_EQ(alice->name, "alice");
  EXPECT_EQ(alice->role, Role::kOperator);
  const auto root = authority->Authenticate(kRootToken);
  ASSERT_TRUE(root);
  EXPECT_EQ(root->name, "root@site");
  EXPECT_EQ(root->role, Role::kAdmin);
  EXPECT_EQ(authority->Authenticate(kBobToken)->role, Role::kObserver);

  const std::string good = kAliceToken;
  EXPECT_FALSE(authority->Authenticate(""));
  EXPECT_FALSE(authority->Authenticate(good.substr(0, good.size() - 1)));  // prefix
  EXPECT_FALSE(authority->Authenticate(good + "x"));                       // extension
  std::string flipped = good;
  flipped[0] ^= 1;
  EXPECT_FALSE(authority->Authenticate(flipped));
  flipped = good;
  flipped.back() ^= 1;
  EXPECT_FALSE(authority->Authenticate(flipped));
  // A token repeated twice is not the token (the comparison wraps over the
  // stored token internally; the lengths must match too).
  EXPECT_FALSE(authority->Authenticate(good + good));
  EXPECT_FALSE(authority->Authenticate(std::string("alice-0123456789abcdef\0", 23)));
}

TEST(TokenAuthority, EmptyListRefusesEveryone) {
  std::string error;
  const auto authority = TokenAuthority::Parse("tokens: []\n", &error);
  ASSERT_TRUE(authority) << error;
  EXPECT_EQ(authority->size(), 0u);
  EXPECT_FALSE(authority->Authenticate(kAliceToken));
}

TEST(TokenAuthority, AuthorizeChecksTokenThenRole) {
  std::string error;
  const auto authority = TokenAuthority::Parse(kTokens, &error);
  ASSERT_TRUE(authority) << error;

  Authorization a = authority->Authorize(kAliceToken, "scan");
  EXPECT_TRUE(a.ok());
  EXPECT_EQ(a.identity->name, "alice");

  a = authority->Authorize(kAliceToken, "calibrate");
  EXPECT_EQ(a.code, Authorization::Code::kForbidden);
  EXPECT_EQ(a.message, "'calibrate' needs role admin; alice has operator");

  a = authority->Authorize(kBobToken, "status");
  EXPECT_TRUE(a.ok());
  a = authority->Authorize(kBobToken, "capture");
  EXPECT_EQ(a.code, Authorization::Code::kForbidden);

  a = authority->Authorize(kRootToken, "calibrate-turntable");
  EXPECT_TRUE(a.ok());

  a = authority->Authorize("wrong-token-wrong-token", "status");
  EXPECT_EQ(a.code, Authorization::Code::kUnauthenticated);
  EXPECT_FALSE(a.identity);
  EXPECT_EQ(a.message, "invalid token");

  a = authority->Authorize(kRootToken, std::string("format-disk\n\x01", 13));
  EXPECT_EQ(a.code, Authorization::Code::kUnknownVerb);
  EXPECT_EQ(a.message,
            "unknown command 'format-disk?"
            "?'");
}

TEST(Roles, VerbTable) {
  const std::vector<std::pair<std::string, Role>> table = {
      {"status", Role::kObserver},           {"sessions", Role::kObserver},
      {"devices", Role::kObserver},          {"get", Role::kObserver},
      {"capture", Role::kOperator},          {"scan", Role::kOperator},
      {"cancel", Role::kOperator},           {"resume", Role::kOperator},
      {"turntable", Role::kOperator},        {"camera", Role::kOperator},
      {"preview", Role::kOperator},          {"calibrate", Role::kAdmin},
      {"calibrate-turntable", Role::kAdmin}, {"delete", Role::kAdmin},
  };
  for (const auto& [verb, role] : table) {
    const auto required = RequiredRole(verb);
    ASSERT_TRUE(required) << verb;
    EXPECT_EQ(*required, role) << verb;
  }
  EXPECT_EQ(KnownVerbs().size(), table.size());
  for (const char* unknown :
       {"", "Status", "status ", "shutdown", "calibrate_turntable", "reload", "config-set"}) {
    EXPECT_FALSE(RequiredRole(unknown)) << unknown;
  }
}

TEST(Roles, OrderAndNames) {
  EXPECT_TRUE(Satisfies(Role::kAdmin, Role::kObserver));
  EXPECT_TRUE(Satisfies(Role::kOperator, Role::kOperator));
  EXPECT_FALSE(Satisfies(Role::kOperator, Role::kAdmin));
  EXPECT_FALSE(Satisfies(Role::kObserver, Role::kOperator));
  for (Role r : {Role::kObserver, Role::kOperator, Role::kAdmin}) {
    Role back = Role::kObserver;
    ASSERT_TRUE(RoleFromString(ToString(r), &back));
    EXPECT_EQ(back, r);
  }
  Role role = Role::kObserver;
  EXPECT_FALSE(RoleFromString("Admin", &role));
}

}  // namespace
}  // namespace craftscan::daemon
