// craftscan-web end to end: the console's server (in this process, on a free
// loopback port) in front of the real craftscand on the simulated station
// (640x512 images) over loopback DDS on a private domain, spoken to by a
// plain socket client (http_test_client.h).
#include <gtest/gtest.h>
#include <signal.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <memory>
#include <set>
#include <sstream>
#include <string>
#include <thread>

#include <nlohmann/json.hpp>

#include "craftscan/web/console.h"
#include "craftscan/web/http_server.h"
#include "daemon_fixture.h"
#include "file_util.h"
#include "http_test_client.h"

namespace craftscan::testing {
namespace {

using namespace std::chrono_literals;
using nlohmann::json;

constexpr const char* kPost[] = {"X-Craftscan-Request: 1", "Content-Type: application/json"};

class ConsoleStation {
 public:
  ConsoleStation() = default;
  // extra_sim: DaemonFixture's (", key: value" of the sim driver).
  explicit ConsoleStation(std::string extra_sim) : fixture_("640x512", std::move(extra_sim)) {}
  bool Start(std::string* error) {
    if (!fixture_.Prepare(error) || !fixture_.Start(error)) return false;
    assets_ = fixture_.root() + "/assets";
    std::filesystem::create_directories(assets_ + "/css");
    std::ofstream(assets_ + "/index.html") << "<!doctype html><title>console</title>";
    std::ofstream(assets_ + "/css/site.css") << "body{}";
    web::WebConfig config;
    config.listen_port = 0;
    config.stations = {fixture_.station()};
    config.domain_id = fixture_.domain();
    config.dds_config = fixture_.dds_config();
    config.assets_dir = assets_;
    config.cache_dir = fixture_.root() + "/cache";
    config.command_timeout_ms = 20000;
    console_ = web::Console::Create(config, error);
    if (!console_) return false;
    server_ = web::HttpServer::Start(console_.get(), error);
    return server_ != nullptr;
  }
  std::uint16_t port() const { return server_->port(); }
  DaemonFixture& fixture() { return fixture_; }

  // Signs in; the cookie header line for later requests ("" on failure).
  std::string SignIn(const std::string& token, HttpReply* reply = nullptr) {
    HttpReply r = Request(port(), "POST", "/api/login", {kPost[0], kPost[1]},
                          json{{"station", fixture_.station()}, {"token", token}}.dump());
    if (reply) *reply = r;
    const std::string set = r.headers.count("set-cookie") ? r.headers.at("set-cookie") : "";
    const std::size_t end = set.find(';');
    return r.status == 200 && end != std::string::npos ? "Cookie: " + set.substr(0, end) : "";
  }
  HttpReply Post(const std::string& cookie, const std::string& target, const json& body) {
    return Request(port(), "POST", target, {kPost[0], kPost[1], cookie}, body.dump());
  }

 private:
  DaemonFixture fixture_{"640x512"};
  std::string assets_;
  std::unique_ptr<web::Console> console_;
  std::unique_ptr<web::HttpServer> server_;
};

json Body(const HttpReply& r) {
  json j = json::parse(r.body, nullptr, false);
  return j.is_discarded() ? json() : j;
}

// Runs a shell command; its stdout.
std::string Shell(const std::string& command) {
  std::string out;
  FILE* pipe = ::popen(command.c_str(), "r");
  if (!pipe) return out;
  char buffer[4096];
  std::size_t n = 0;
  while ((n = std::fread(buffer, 1, sizeof buffer, pipe)) > 0) out.append(buffer, n);
  ::pclose(pipe);
  return out;
}

// With a certificate the console speaks HTTPS only (OpenSSL's own client
// checks it); a missing key is refused at start, naming the key.
TEST(CraftscanWeb, ServesHttpsWithACertificate) {
  char dir_template[] = "/tmp/craftscan-web-tls-XXXXXX";
  const std::string dir = ::mkdtemp(dir_template);
  std::ostringstream make_cert;
  make_cert << "openssl req -x509 -newkey rsa:2048 -nodes -keyout " << dir << "/key.pem -out "
            << dir << "/cert.pem -days 1 -subj /CN=localhost >/dev/null 2>&1; echo $?";
  ASSERT_EQ(Shell(make_cert.str()), "0\n");
  std::filesystem::create_directories(dir + "/assets");
  std::ofstream(dir + "/assets/index.html") << "<!doctype html><title>secure console</title>";
  web::WebConfig config;
  config.listen_port = 0;
  config.stations = {"nobody"};
  config.domain_id = 1 + static_cast<std::uint32_t>(::getpid() % 200);
  config.dds_config = dds::LoopbackOnlyConfigXml();
  config.assets_dir = dir + "/assets";
  config.cache_dir = dir + "/cache";
  config.tls_certificate = dir + "/cert.pem";
  config.tls_private_key = dir + "/missing.pem";
  std::string error;
  auto console = web::Console::Create(config, &error);
  ASSERT_TRUE(console) << error;
  EXPECT_FALSE(web::HttpServer::Start(console.get(), &error));
  EXPECT_NE(error.find("tls.private_key"), std::string::npos) << error;
  console.reset();

  config.tls_private_key = dir + "/key.pem";
  console = web::Console::Create(config, &error);
  ASSERT_TRUE(console) << error;
  auto server = web::HttpServer::Start(console.get(), &error);
  ASSERT_TRUE(server) << error;
  const std::string port = std::to_string(server->port());
  std::ostringstream get;
  get << "printf 'GET / HTTP/1.1\\r\\nHost: 127.0.0.1:" << port
      << "\\r\\nConnection: close\\r\\n\\r\\n' | timeout 10 openssl s_client -connect 127.0.0.1:"
      << port << " -quiet 2>/dev/null";
  const std::string https = Shell(get.str());
  EXPECT_NE(https.find("HTTP/1.1 200"), std::string::npos) << https;
  EXPECT_NE(https.find("secure console"), std::string::npos) << https;
  EXPECT_NE(https.find("Strict-Transport-Security"), std::string::npos) << https;
  // Plain HTTP on the TLS port gets no page.
  const HttpReply plain = Request(server->port(), "GET", "/", {}, "", 5s);
  EXPECT_NE(plain.status, 200);
  EXPECT_EQ(plain.body.find("secure console"), std::string::npos);
  server.reset();
  console.reset();
  std::error_code ignored;
  std::filesystem::remove_all(dir, ignored);
}

TEST(CraftscanWeb, SignInRolesAndEveryRefusal) {
  ConsoleStation station;
  std::string error;
  ASSERT_TRUE(station.Start(&error)) << error;
  const std::uint16_t port = station.port();

  // The page and its files; security headers on every answer.
  HttpReply r = Request(port, "GET", "/");
  EXPECT_EQ(r.status, 200);
  EXPECT_NE(r.body.find("console"), std::string::npos);
  EXPECT_NE(r.headers["content-security-policy"].find("default-src 'self'"), std::string::npos);
  EXPECT_EQ(r.headers["x-content-type-options"], "nosniff");
  EXPECT_EQ(Request(port, "GET", "/assets/css/site.css").headers["content-type"],
            "text/css; charset=utf-8");

  // Path tricks never leave the assets folder.
  for (const char* target : {"/assets/../../../etc/passwd", "/assets/%2e%2e/%2e%2e/etc/passwd",
                             "/assets//etc/passwd", "/assets/.hidden", "/../etc/passwd"}) {
    r = Request(port, "GET", target);
    EXPECT_TRUE(r.status == 400 || r.status == 404) << target << " → " << r.status;
    EXPECT_EQ(r.body.find("root:"), std::string::npos) << target;
  }

  // No session: refused.
  r = Request(port, "GET", "/api/status");
  EXPECT_EQ(r.status, 401);
  EXPECT_EQ(Body(r).value("code", ""), "unauthenticated") << r.body;
  r = Request(port, "GET", "/api/status", {"Cookie: craftscan_session=" + std::string(64, 'a')});
  EXPECT_EQ(r.status, 401) << "a forged session id";

  // A wrong token: the station's refusal, said so.
  ASSERT_EQ(station.SignIn("not-a-token-0123456789", &r), "");
  EXPECT_EQ(r.status, 401) << r.body;
  EXPECT_NE(Body(r).value("error", "").find("refused the token"), std::string::npos) << r.body;
  // An unknown station.
  r = Request(port, "POST", "/api/login", {kPost[0], kPost[1]},
              R"({"station": "elsewhere", "token": "x"})");
  EXPECT_EQ(r.status, 404) << r.body;

  // The observer: signed in with its role; the session cookie is HttpOnly, SameSite.
  const std::string observer = station.SignIn(kObserverToken, &r);
  ASSERT_FALSE(observer.empty()) << r.status << " " << r.body << station.fixture().Log();
  EXPECT_EQ(Body(r).value("role", ""), "observer");
  EXPECT_NE(r.headers["set-cookie"].find("HttpOnly"), std::string::npos);
  EXPECT_NE(r.headers["set-cookie"].find("SameSite=Strict"), std::string::npos);
  r = Request(port, "GET", "/api/me", {observer});
  EXPECT_EQ(Body(r).value("role", ""), "observer") << r.body;
  EXPECT_EQ(Body(r).value("client", ""), "watcher") << r.body;
  r = Request(port, "GET", "/api/status", {observer});
  ASSERT_EQ(r.status, 200);
  EXPECT_EQ(Body(r).value("station", ""), station.fixture().station());
  EXPECT_TRUE(Body(r).value("online", false)) << r.body;
  EXPECT_EQ(Body(r).value("state", ""), "idle") << r.body;

  // The daemon still checks each command: the observer cannot scan.
  r = station.Post(observer, "/api/command", {{"verb", "scan"}, {"args", {{"views", 4}}}});
  ASSERT_EQ(r.status, 200) << r.body;
  EXPECT_EQ(Body(r).value("code_name", ""), "forbidden") << r.body;

  // Forged and malformed requests.
  r = Request(port, "POST", "/api/command", {kPost[1], observer}, R"({"verb": "status"})");
  EXPECT_EQ(r.status, 403) << "no X-Craftscan-Request: " << r.body;
  r = Request(port, "POST", "/api/command",
              {kPost[0], kPost[1], observer, "Origin: http://evil.example"},
              R"({"verb": "status"})");
  EXPECT_EQ(r.status, 403) << r.body;
  EXPECT_NE(Body(r).value("error", "").find("cross-origin"), std::string::npos) << r.body;
  r = Request(port, "POST", "/api/command",
              {kPost[0], kPost[1], observer, "Origin: http://127.0.0.1:" + std::to_string(port)},
              R"({"verb": "status"})");
  EXPECT_EQ(r.status, 200) << "its own origin: " << r.body;
  r = Request(port, "POST", "/api/command", {kPost[0], "Content-Type: text/plain", observer},
              R"({"verb": "status"})");
  EXPECT_EQ(r.status, 415) << r.body;
  r = Request(port, "POST", "/api/command", {kPost[0], kPost[1], observer}, R"({"verb": )");
  EXPECT_EQ(r.status, 400) << r.body;
  EXPECT_NE(Body(r).value("error", "").find("not valid JSON"), std::string::npos) << r.body;
  r = Request(port, "POST", "/api/command", {kPost[0], kPost[1], observer}, R"({"verb": 3})");
  EXPECT_EQ(r.status, 400) << r.body;
  r = Request(port, "POST", "/api/command", {kPost[0], kPost[1], observer},
              "{\"verb\": \"status\", \"pad\": \"" + std::string(100000, 'x') + "\"}");
  EXPECT_EQ(r.status, 413) << r.body;
  r = Request(port, "DELETE", "/api/sessions", {observer});
  EXPECT_EQ(r.status, 405) << r.body;
  r = Request(port, "GET", "/api/sessions/..%2f..%2fetc/files/passwd", {observer});
  EXPECT_EQ(r.status, 400) << r.body;
  r = Request(port, "GET", "/api/sessions/x/files/../../etc/passwd", {observer});
  EXPECT_EQ(r.status, 400) << r.body;
  r = Request(port, "GET", "/api/sessions/nosuch/files/fused.ply", {observer});
  EXPECT_EQ(r.status, 400) << "the daemon's bad_argument: " << r.body;
  r = Request(port, "GET", "/api/sessions/20200101-000000-nothing/files/fused.ply", {observer});
  EXPECT_EQ(r.status, 404) << r.body;
  // The refusals are logged (by the server: the test only sees the replies).

  // The WebSocket needs the session and the console's own origin.
  WebSocketClient anonymous(port, {});
  EXPECT_EQ(anonymous.status(), 401);
  WebSocketClient forged(port, {observer, "Origin: http://evil.example"});
  EXPECT_EQ(forged.status(), 403);
  WebSocketClient ws(port, {observer});
  ASSERT_EQ(ws.status(), 101);
  const json first = json::parse(ws.Next(5s), nullptr, false);
  EXPECT_EQ(first.value("type", ""), "status") << first;
  ws.SendText(R"({"type":"ping"})");
  bool pong = false;
  for (int i = 0; i < 10 && !pong; ++i) pong = ws.Next(2s).find("pong") != std::string::npos;
  EXPECT_TRUE(pong);

  // Sign-out ends the session.
  r = station.Post(observer, "/api/logout", json::object());
  EXPECT_EQ(r.status, 200);
  EXPECT_EQ(Request(port, "GET", "/api/me", {observer}).status, 401);
}

// The next preview message within `timeout` (other messages skipped).
json NextPreview(WebSocketClient& ws, std::chrono::seconds timeout) {
  const auto until = std::chrono::steady_clock::now() + timeout;
  while (std::chrono::steady_clock::now() < until) {
    const json m = json::parse(ws.Next(1s), nullptr, false);
    if (m.is_object() && m.value("type", "") == "preview") return m;
  }
  return json();
}

TEST(CraftscanWeb, LivePreviewWhileIdleGivesWayToAScan) {
  ConsoleStation station;
  std::string error;
  ASSERT_TRUE(station.Start(&error)) << error;
  const std::string op = station.SignIn(kOperatorToken);
  const std::string observer = station.SignIn(kObserverToken);
  ASSERT_FALSE(op.empty() || observer.empty()) << station.fixture().Log();
  WebSocketClient ws(station.port(), {op});
  ASSERT_EQ(ws.status(), 101);

  // Observers may watch but not start it.
  HttpReply r = station.Post(observer, "/api/command",
                             {{"verb", "preview"}, {"args", {{"action", "start"}}}});
  EXPECT_EQ(Body(r).value("code_name", ""), "forbidden") << r.body;
  r = station.Post(op, "/api/command",
                   {{"verb", "preview"}, {"args", {{"action", "start"}, {"fps", 0}}}});
  EXPECT_EQ(Body(r).value("code_name", ""), "bad_argument") << r.body;

  r = station.Post(op, "/api/command",
                   {{"verb", "preview"},
                    {"args", {{"action", "start"}, {"fps", 5}, {"width", 320}, {"seconds", 30}}}});
  ASSERT_EQ(Body(r).value("code_name", ""), "ok") << r.body;
  const auto start = std::chrono::steady_clock::now();
  std::vector<json> frames;
  while (frames.size() < 4) {
    json m = NextPreview(ws, 10s);
    ASSERT_TRUE(m.is_object()) << "no preview frame; " << station.fixture().Log();
    frames.push_back(std::move(m));
  }
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  std::printf("4 preview frames in %.2f s\n", seconds);
  // The sim camera's size (the sanitizers make it smaller: TestImageSize).
  int full_width = 0, full_height = 0;
  ASSERT_EQ(std::sscanf(TestImageSize("640x512").c_str(), "%dx%d", &full_width, &full_height), 2);
  for (const json& f : frames) {
    EXPECT_EQ(f.value("width", 0), std::min(320, full_width));
    EXPECT_EQ(f.value("full_width", 0), full_width);
    for (const char* side : {"left", "right"}) {
      const json& image = f[side];
      EXPECT_EQ(image.value("image", "").rfind("data:image/jpeg;base64,", 0), 0u);
      ASSERT_EQ(image["focus"].size(), 16u);
      for (const json& v : image["focus"]) EXPECT_GE(v.get<double>(), 0);
      double pixels = 0;
      for (const json& v : image["histogram"]) pixels += v.get<double>();
      EXPECT_EQ(pixels, static_cast<double>(full_width) * full_height)
          << "the histogram counts every pixel";
      EXPECT_GE(image.value("clipped_pct", -1.0), 0);
    }
  }
  EXPECT_NE(frames[0]["left"]["image"], frames[3]["left"]["image"]) << "the picture is live";
  EXPECT_LT(frames[0].value("frame", 0), frames[3].value("frame", 0));

  // Exposure from the console: the preview goes on with the new setting.
  r = station.Post(op, "/api/command", {{"verb", "camera"}, {"args", {{"exposure_us", 5000}}}});
  ASSERT_EQ(Body(r).value("code_name", ""), "ok") << r.body;
  double exposure = 0;
  for (int i = 0; i < 10 && exposure != 5000; ++i) {
    const json m = NextPreview(ws, 10s);
    if (!m.is_object()) break;
    exposure = m.value("exposure_us", 0.0);
  }
  EXPECT_EQ(exposure, 5000);

  // A scan stops the preview and runs; no preview frame during it.
  r = station.Post(
      op, "/api/command",
      {{"verb", "scan"}, {"args", {{"object", "box"}, {"views", 2}, {"step_deg", 30}}}});
  ASSERT_EQ(Body(r).value("code_name", ""), "ok") << r.body;
  const std::string job = Body(r)["result"].value("id", "");
  r = station.Post(op, "/api/command", {{"verb", "preview"}, {"args", {{"action", "start"}}}});
  EXPECT_EQ(Body(r).value("code_name", ""), "busy") << r.body;
  bool done = false;
  int previews_during_scan = 0;
  const auto deadline = std::chrono::steady_clock::now() + 120s;
  while (!done && std::chrono::steady_clock::now() < deadline) {
    const json m = json::parse(ws.Next(2s), nullptr, false);
    if (!m.is_object()) continue;
    if (m.value("type", "") == "preview" && m.value("job_id", "") == job) ++previews_during_scan;
    done = m.value("type", "") == "progress" && m.value("job_id", "") == job &&
           m.value("stage", "") == "done";
  }
  EXPECT_TRUE(done) << station.fixture().Log();
  EXPECT_EQ(previews_during_scan, 0);

  // A preview asked for 1 s ends by itself.
  r = station.Post(op, "/api/command",
                   {{"verb", "preview"}, {"args", {{"action", "start"}, {"seconds", 1}}}});
  ASSERT_EQ(Body(r).value("code_name", ""), "ok") << r.body;
  const std::string preview_job = Body(r)["result"].value("id", "");
  bool ended = false;
  const auto until = std::chrono::steady_clock::now() + 15s;
  while (!ended && std::chrono::steady_clock::now() < until) {
    const json m = json::parse(ws.Next(1s), nullptr, false);
    ended = m.is_object() && m.value("type", "") == "progress" &&
            m.value("job_id", "") == preview_job && m.value("stage", "") == "done";
  }
  EXPECT_TRUE(ended);
}

// The guided calibration with the sim's technician, through the console, is
// the browser test tests/browser/calibrate.mjs (the page, and every overlay
// the page is sent).

TEST(CraftscanWeb, ScanLiveThenDownloadOutputsThenStationGone) {
  ConsoleStation station;
  std::string error;
  ASSERT_TRUE(station.Start(&error)) << error;
  const std::uint16_t port = station.port();
  const std::string op = station.SignIn(kOperatorToken);
  ASSERT_FALSE(op.empty()) << station.fixture().Log();
  WebSocketClient ws(port, {op});
  ASSERT_EQ(ws.status(), 101);

  HttpReply r = station.Post(
      op, "/api/command",
      {{"verb", "scan"}, {"args", {{"object", "box"}, {"views", 4}, {"step_deg", 90}}}});
  ASSERT_EQ(r.status, 200) << r.body;
  ASSERT_EQ(Body(r).value("code_name", ""), "ok") << r.body;
  const std::string job = Body(r)["result"].value("id", "");

  // Live: captures with thumbnails, each view's disparity picture, progress
  // to the job's end.
  int captures = 0;
  std::set<int> disparities;
  std::string final_stage, session;
  const auto deadline = std::chrono::steady_clock::now() + 300s;
  while (final_stage.empty() && std::chrono::steady_clock::now() < deadline) {
    const json m = json::parse(ws.Next(5s), nullptr, false);
    if (!m.is_object()) continue;
    if (m.value("type", "") == "capture") {
      ++captures;
      session = m.value("session", "");
      EXPECT_EQ(m.value("left", "").rfind("data:image/jpeg;base64,", 0), 0u);
      EXPECT_GT(m.value("right", "").size(), 1000u);
    } else if (m.value("type", "") == "disparity") {
      disparities.insert(m.value("view_index", -1));
      EXPECT_EQ(m.value("image", "").rfind("data:image/jpeg;base64,", 0), 0u) << m.dump();
      EXPECT_EQ(std::to_string(m.value("width", 0)) + "x" + std::to_string(m.value("height", 0)),
                TestImageSize("640x512"));
      EXPECT_GT(m.value("valid_fraction", 0.0), 0.05) << "the box fills part of the view";
      EXPECT_LE(m.value("valid_fraction", 2.0), 1.0);
      EXPECT_LT(m.value("scale_min", 1e9), m.value("scale_max", -1e9));
    } else if (m.value("type", "") == "progress" && m.value("job_id", "") == job) {
      const std::string stage = m.value("stage", "");
      if (m.value("message", "").find("taken;") != std::string::npos) {
        std::printf("  %s\n", m.value("message", "").c_str());
      }
      if (stage == "done" || stage == "failed" || stage == "cancelled") final_stage = stage;
    }
  }
  ASSERT_EQ(final_stage, "done") << station.fixture().Log();
  EXPECT_EQ(captures, 4);
  EXPECT_EQ(disparities, (std::set<int>{0, 1, 2, 3}));
  ASSERT_FALSE(session.empty());

  // Sessions and the manifest through the console.
  r = Request(port, "GET", "/api/sessions", {op});
  ASSERT_EQ(r.status, 200) << r.body;
  bool listed = false;
  for (const json& s : Body(r).value("sessions", json::array())) {
    listed |= s.value("id", "") == session && s.value("state", "") == "done";
  }
  EXPECT_TRUE(listed) << r.body;
  r = Request(port, "GET", "/api/sessions/" + session, {op});
  ASSERT_EQ(r.status, 200) << r.body;
  const json outputs = Body(r)["manifest"].value("outputs", json::object());
  ASSERT_TRUE(outputs.contains("fused.ply")) << r.body;

  // Every output byte for byte as the station wrote it (fetched, verified, cached).
  const std::string dir = station.fixture().data_dir() + "/sessions/" + session;
  for (const auto& [name, record] : outputs.items()) {
    r = Request(port, "GET", "/api/sessions/" + session + "/files/" + name, {op});
    ASSERT_EQ(r.status, 200) << name << ": " << r.body;
    EXPECT_TRUE(r.body == ReadFile(dir + "/" + name)) << name << " differs";
  }
  r = Request(port, "GET", "/api/sessions/" + session + "/files/fused.ply", {op});
  EXPECT_EQ(r.headers["content-disposition"], "attachment; filename=\"fused.ply\"");
  r = Request(port, "GET", "/api/sessions/" + session + "/files/nothing.ply", {op});
  EXPECT_EQ(r.status, 404) << r.body;

  // Delete: admins only, into the trash, never unlinked.
  r = station.Post(op, "/api/command", {{"verb", "delete"}, {"args", {{"session", session}}}});
  EXPECT_EQ(Body(r).value("code_name", ""), "forbidden") << r.body;
  const std::string admin = station.SignIn(kAdminToken);
  r = station.Post(admin, "/api/command", {{"verb", "delete"}, {"args", {{"session", session}}}});
  ASSERT_EQ(Body(r).value("code_name", ""), "ok") << r.body;
  const std::filesystem::path trash = Body(r)["result"].value("trash", "");
  EXPECT_EQ(trash, std::filesystem::path(station.fixture().data_dir()) / "trash" / session);
  EXPECT_FALSE(std::filesystem::exists(dir));
  EXPECT_TRUE(std::filesystem::exists(trash / "fused.ply"));
  EXPECT_TRUE(std::filesystem::exists(trash / "views" / "000" / "left.png"));
  r = Request(port, "GET", "/api/sessions", {op});
  EXPECT_EQ(r.body.find(session), std::string::npos) << r.body;
  r = station.Post(admin, "/api/command", {{"verb", "delete"}, {"args", {{"session", session}}}});
  EXPECT_EQ(Body(r).value("code_name", ""), "not_found") << r.body;

  // The daemon killed: the console says the station is gone.
  station.fixture().Stop(SIGKILL);
  bool gone = false;
  const auto until = std::chrono::steady_clock::now() + 15s;
  while (!gone && std::chrono::steady_clock::now() < until) {
    const json m = json::parse(ws.Next(2s), nullptr, false);
    gone = m.is_object() && m.value("type", "") == "status" && !m.value("online", true);
  }
  EXPECT_TRUE(gone);
  r = station.Post(op, "/api/command", {{"verb", "status"}});
  EXPECT_EQ(r.status, 504) << r.body;
  EXPECT_NE(Body(r).value("error", "").find("not answering"), std::string::npos) << r.body;
}

}  // namespace
}  // namespace craftscan::testing
