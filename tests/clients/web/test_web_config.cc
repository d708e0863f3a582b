// craftscan-web's configuration and path rules (unit).
#include <gtest/gtest.h>

#include <string>

#include "craftscan/web/console.h"
#include "craftscan/web/web_config.h"
#include "test_paths.h"

namespace craftscan::web {
namespace {

TEST(WebConfig, TheShippedExampleLoadsWithTheDefaults) {
  WebConfig config;
  std::string error;
  ASSERT_TRUE(LoadWebConfig(std::string(::craftscan::testing::SystemdDir()) + "/craftscan-web.yaml",
                            &config, &error))
      << error;
  const WebConfig defaults;
  EXPECT_EQ(config.listen_host, "127.0.0.1");
  EXPECT_EQ(config.listen_port, 8080);
  EXPECT_EQ(config.stations, defaults.stations);
  EXPECT_FALSE(config.tls());
  EXPECT_EQ(config.cache_dir, defaults.cache_dir);
  EXPECT_EQ(config.session_idle_minutes, defaults.session_idle_minutes);
  EXPECT_EQ(config.max_body_bytes, defaults.max_body_bytes);
}

TEST(WebConfig, ParsesEveryKey) {
  WebConfig c;
  std::string error;
  ASSERT_TRUE(ParseWebConfig(R"(version: 1
listen: "[::1]:9443"
stations: [a1, b_2]
domain_id: 7
dds_config: file:///x.xml
tls: {certificate: /c.pem, private_key: /k.pem}
assets_dir: /a
cache_dir: /c
session_idle_minutes: 5
max_body_bytes: 2048
command_timeout_ms: 500
)",
                             &c, &error))
      << error;
  EXPECT_EQ(c.listen_host, "::1");
  EXPECT_EQ(c.listen_port, 9443);
  EXPECT_EQ(c.stations, (std::vector<std::string>{"a1", "b_2"}));
  EXPECT_EQ(c.domain_id, 7u);
  EXPECT_TRUE(c.tls());
  EXPECT_EQ(c.tls_private_key, "/k.pem");
  EXPECT_EQ(c.session_idle_minutes, 5);
  EXPECT_EQ(c.max_body_bytes, 2048u);
  EXPECT_EQ(c.command_timeout_ms, 500);
}

TEST(WebConfig, ErrorsNameTheKeyAndLine) {
  const struct {
    const char* yaml;
    const char* expected;
  } cases[] = {
      {"", "version: 1"},
      {"listen: 1.2.3.4:80\n", "version: missing"},
      {"version: 2\n", "version: 2 is not supported"},
      {"version: 1\nlisten: 8080\n", "listen: must be host:port"},
      {"version: 1\nlisten: a:99999\n", "the port must be 0..65535"},
      {"version: 1\nstations: []\n", "stations: list at least one"},
      {"version: 1\nstations: [a, a]\n", "listed twice"},
      {"version: 1\nstations: [\"a b\"]\n", "is not a station id"},
      {"version: 1\ndomain_id: 231\n", "domain_id: must be an integer in 0..230"},
      {"version: 1\ntls: {certificate: /c}\n", "give both certificate and private_key"},
      {"version: 1\ntls: {cert: /c}\n", "tls.cert: unknown key"},
      {"version: 1\nmax_body_bytes: 10\n", "max_body_bytes: must be an integer in 1024"},
      {"version: 1\nlisten_port: 80\n", "listen_port: unknown key"},
      {"version: 1\nsession_idle_minutes: [1]\n", "session_idle_minutes: must be an integer"},
      {"version: 1\n  bad: [\n", "not valid YAML"},
  };
  for (const auto& c : cases) {
    WebConfig config;
    std::string error;
    EXPECT_FALSE(ParseWebConfig(c.yaml, &config, &error)) << c.yaml;
    EXPECT_NE(error.find(c.expected), std::string::npos) << c.yaml << " → " << error;
  }
  WebConfig config;
  std::string error;
  EXPECT_FALSE(ParseWebConfig("version: 1\n\nlisten_port: 80\n", &config, &error));
  EXPECT_NE(error.find("(line 3)"), std::string::npos) << error;
  EXPECT_FALSE(LoadWebConfig("/nonexistent/web.yaml", &config, &error));
  EXPECT_NE(error.find("/nonexistent/web.yaml"), std::string::npos) << error;
}

TEST(WebPaths, OnlyPlainRelativePathsPass) {
  for (const char* good : {"index.html", "previews/front.png", "a-b_c.1/x.js"}) {
    EXPECT_TRUE(IsSafeRelativePath(good)) << good;
  }
  for (const char* bad : {"", "/etc/passwd", "../x", "a/../../b", "a//b", ".hidden", "a/.b", "a/",
                          "a\\b", "a b", "a%2fb", "..", "."}) {
    EXPECT_FALSE(IsSafeRelativePath(bad)) << bad;
  }
  EXPECT_FALSE(IsSafeRelativePath(std::string(300, 'a')));
}

}  // namespace
}  // namespace craftscan::web
