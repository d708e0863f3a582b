#include "craftscan/web/console.h"

#include <openssl/rand.h>
#include <spdlog/spdlog.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <optional>
#include <thread>

#include <nlohmann/json.hpp>

#include "craftscan/client/station_client.h"
#include "craftscan/web/pictures.h"

namespace craftscan::web {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;
using nlohmann::json;

constexpr const char* kCookieName = "craftscan_session";
constexpr auto kStationSilence = std::chrono::seconds(3);
constexpr auto kStatusRepeat = std::chrono::seconds(2);

std::string RandomHex(std::size_t bytes) {
  std::vector<unsigned char> raw(bytes);
  if (RAND_bytes(raw.data(), static_cast<int>(raw.size())) != 1) {
    throw std::runtime_error("RAND_bytes failed");
  }
  static const char* digits = "0123456789abcdef";
  std::string hex;
  for (unsigned char c : raw) {
    hex += digits[c >> 4];
    hex += digits[c & 15];
  }
  return hex;
}

HttpResponse JsonResponse(int status, const json& body) {
  HttpResponse r;
  r.status = status;
  r.body = body.dump();
  return r;
}

HttpResponse Error(int status, const std::string& code, const std::string& message) {
  return JsonResponse(status, {{"error", message}, {"code", code}});
}

std::string ContentType(const std::string& path) {
  const std::string ext = fs::path(path).extension().string();
  static const std::map<std::string, std::string> types = {
      {".html", "text/html; charset=utf-8"},
      {".js", "text/javascript; charset=utf-8"},
      {".mjs", "text/javascript; charset=utf-8"},
      {".css", "text/css; charset=utf-8"},
      {".json", "application/json"},
      {".png", "image/png"},
      {".jpg", "image/jpeg"},
      {".svg", "image/svg+xml"},
      {".ico", "image/x-icon"},
      {".ply", "application/octet-stream"},
      {".obj", "text/plain; charset=utf-8"},
      {".glb", "model/gltf-binary"},
      {".txt", "text/plain; charset=utf-8"},
  };
  const auto it = types.find(ext);
  return it == types.end() ? "application/octet-stream" : it->second;
}

std::string CookieValue(const HttpRequest& request) {
  const std::string header = request.header("cookie");
  const std::string key = std::string(kCookieName) + "=";
  std::size_t pos = 0;
  while (pos < header.size()) {
    while (pos < header.size() && (header[pos] == ' ' || header[pos] == ';')) ++pos;
    const std::size_t end = std::min(header.find(';', pos), header.size());
    if (header.compare(pos, key.size(), key) == 0) {
      return header.substr(pos + key.size(), end - pos - key.size());
    }
    pos = end;
  }
  return "";
}

// Splits the target's path (no query) into segments after "/".
std::vector<std::string> Segments(const std::string& path) {
  std::vector<std::string> out;
  std::size_t pos = 1;
  while (pos <= path.size()) {
    const std::size_t end = std::min(path.find('/', pos), path.size());
    out.push_back(path.substr(pos, end - pos));
    pos = end + 1;
  }
  return out;
}

bool IsSessionId(const std::string& id) {
  return !id.empty() && id.size() <= 128 && IsSafeRelativePath(id) &&
         id.find('/') == std::string::npos;
}

// The HTTP status for a daemon's refusal, when the console answers with its
// own status rather than relaying the Reply as it is.
int HttpStatusOf(const std::string& code_name) {
  static const std::map<std::string, int> statuses = {
      {"bad_request", 400}, {"bad_argument", 400}, {"too_large", 413}, {"unauthenticated", 401},
      {"forbidden", 403},   {"not_found", 404},    {"busy", 409},      {"unavailable", 503}};
  const auto it = statuses.find(code_name);
  return it == statuses.end() ? 502 : it->second;
}

json PreviewImageJson(const client::PreviewImageUpdate& image) {
  return {{"image", "data:image/jpeg;base64," + Base64(image.jpeg)},
          {"focus", image.focus},
          {"histogram", image.histogram},
          {"clipped_pct", image.clipped_pct},
          {"black_pct", image.black_pct}};
}

json PreviewJson(const client::PreviewUpdate& u) {
  json overlay = u.overlay.empty() ? json() : json::parse(u.overlay, nullptr, false);
  if (overlay.is_discarded()) overlay = json();
  return {{"type", "preview"},
          {"job_id", u.job_id},
          {"frame", u.frame_number},
          {"stamp_ns", u.stamp_ns},
          {"ready_ns", u.ready_ns},
          {"exposure_us", u.exposure_us},
          {"gain_db", u.gain_db},
          {"width", u.width},
          {"height", u.height},
          {"full_width", u.full_width},
          {"full_height", u.full_height},
          {"grid_cols", u.grid_cols},
          {"grid_rows", u.grid_rows},
          {"left", PreviewImageJson(u.left)},
          {"right", PreviewImageJson(u.right)},
          {"overlay", overlay}};
}

json ReplyJson(const client::Reply& reply) {
  return {{"code", reply.code},
          {"code_name", reply.code_name},
          {"message", reply.message},
          {"result", reply.result}};
}

}  // namespace

bool IsSafeRelativePath(const std::string& path) {
  if (path.empty() || path.size() > 256) return false;
  std::size_t pos = 0;
  while (true) {
    const std::size_t end = std::min(path.find('/', pos), path.size());
    const std::string segment = path.substr(pos, end - pos);
    if (segment.empty() || segment.front() == '.') return false;
    for (char c : segment) {
      const bool ok = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') ||
                      c == '.' || c == '_' || c == '-';
      if (!ok) return false;
    }
    if (end == path.size()) return true;
    pos = end + 1;
  }
}

std::string ResolveAssetsDir(const std::string& configured) {
  if (!configured.empty()) return configured;
  std::error_code ec;
  const fs::path self = fs::read_symlink("/proc/self/exe", ec);
  if (!ec) {
    const fs::path beside = self.parent_path() / "assets";
    if (fs::exists(beside / "index.html", ec)) return beside.string();
  }
  return "/usr/share/craftscan/web/assets";
}

struct Console::Impl {
  struct UserSession {
    std::string station, token, role, name;
    Clock::time_point last_used;
  };
  struct Listener {
    std::string station;
    Sink sink;
  };
  struct Station {
    std::string id;
    std::unique_ptr<client::StationClient> client;
    std::mutex mutex;  // status, heard
    json status = json::object();
    Clock::time_point heard{};
    bool online = false;
    Clock::time_point last_broadcast{};
    std::mutex fetch_mutex;  // one Fetch per client at a time
  };

  WebConfig config;
  std::string assets_dir;
  std::map<std::string, std::unique_ptr<Station>> stations;

  std::mutex sessions_mutex;
  std::map<std::string, UserSession> sessions;  // by cookie value

  std::mutex listeners_mutex;
  std::map<int, Listener> listeners;
  int next_listener = 1;

  std::mutex tick_mutex;
  std::condition_variable tick_cv;
  bool stopping = false;
  std::thread ticker;

  ~Impl() {
    {
      std::lock_guard lock(tick_mutex);
      stopping = true;
    }
    tick_cv.notify_all();
    if (ticker.joinable()) ticker.join();
    // The clients first: their threads call into the stations' state.
    for (auto& [id, station] : stations) station->client.reset();
    stations.clear();
  }

  void Broadcast(const std::string& station, const std::string& message) {
    std::lock_guard lock(listeners_mutex);
    for (auto& [id, l] : listeners) {
      if (l.station == station) l.sink(message);
    }
  }

  json StatusJson(Station& s) {
    std::lock_guard lock(s.mutex);
    json j = s.status;
    j["station"] = s.id;
    j["online"] = s.online;
    if (!s.online && !j.contains("state")) j["state"] = "unknown";
    return j;
  }

  void BroadcastStatus(Station& s) {
    json j = StatusJson(s);
    j["type"] = "status";
    {
      std::lock_guard lock(s.mutex);
      s.last_broadcast = Clock::now();
    }
    Broadcast(s.id, j.dump());
  }

  void OnStatus(Station& s, const client::StatusUpdate& u) {
    json devices = json::array();
    for (const auto& d : u.devices) {
      devices.push_back(
          {{"name", d.name}, {"kind", d.kind}, {"state", d.state}, {"message", d.message}});
    }
    bool changed = false;
    {
      std::lock_guard lock(s.mutex);
      json next = {{"state", u.state},
                   {"devices", devices},
                   {"job_id", u.job_id},
                   {"job_verb", u.job_verb},
                   {"job_state", u.job_state},
                   {"progress", u.progress},
                   {"last_error", u.last_error},
                   {"stamp_ns", u.stamp_ns},
                   {"calibration_id", u.calibration_id}};
      json old = s.status;
      old.erase("stamp_ns");
      json cmp = next;
      cmp.erase("stamp_ns");
      changed = !s.online || old != cmp;
      s.status = std::move(next);
      s.heard = Clock::now();
      s.online = true;
    }
    if (changed) BroadcastStatus(s);
  }

  void Tick() {
    std::unique_lock lock(tick_mutex);
    while (!stopping) {
      tick_cv.wait_for(lock, std::chrono::milliseconds(500));
      if (stopping) break;
      for (auto& [id, s] : stations) {
        bool went = false, repeat = false;
        {
          std::lock_guard slock(s->mutex);
          const auto now = Clock::now();
          if (s->online && now - s->heard > kStationSilence) {
            s->online = false;
            went = true;
            spdlog::warn("station {}: not heard for {} s", id,
                         std::chrono::duration_cast<std::chrono::seconds>(kStationSilence).count());
          }
          repeat = now - s->last_broadcast > kStatusRepeat;
        }
        if (went || repeat) BroadcastStatus(*s);
      }
    }
  }

  // --- sessions --------------------------------------------------------

  std::optional<UserSession> FindSession(const HttpRequest& request) {
    const std::string cookie = CookieValue(request);
    if (cookie.size() != 64) return std::nullopt;
    std::lock_guard lock(sessions_mutex);
    const auto it = sessions.find(cookie);
    if (it == sessions.end()) return std::nullopt;
    const auto idle = std::chrono::minutes(config.session_idle_minutes);
    if (Clock::now() - it->second.last_used > idle) {
      sessions.erase(it);
      return std::nullopt;
    }
    it->second.last_used = Clock::now();
    return it->second;
  }

  // The request's Origin, if any, must be this server's own.
  bool OriginOk(const HttpRequest& request, std::string* why) {
    const std::string origin = request.header("origin");
    if (origin.empty()) return true;
    const std::string host = request.header("host");
    const std::string own = std::string(request.tls ? "https://" : "http://") + host;
    if (!host.empty() && origin == own) return true;
    *why = "cross-origin request refused (Origin " + origin + " is not " + own + ")";
    return false;
  }

  HttpResponse Refuse(const HttpRequest& request, int status, const std::string& code,
                      const std::string& message) {
    spdlog::warn("{} {} {}: {} {}", request.peer, request.method, request.target.substr(0, 200),
                 status, message);
    return Error(status, code, message);
  }

  // --- handlers -------------------------------------------------------

  HttpResponse Login(const HttpRequest& request, const json& body) {
    if (!body.is_object() || !body.contains("token") || !body["token"].is_string()) {
      return Refuse(request, 400, "bad_request", "expected {\"station\": id, \"token\": text}");
    }
    std::string station_id = config.stations.front();
    if (body.contains("station")) {
      if (!body["station"].is_string()) {
        return Refuse(request, 400, "bad_request", "station: must be a string");
      }
      station_id = body["station"].get<std::string>();
    }
    const auto it = stations.find(station_id);
    if (it == stations.end()) {
      return Refuse(request, 404, "not_found",
                    "unknown station '" + station_id.substr(0, 64) + "' (this console serves " +
                        std::to_string(config.stations.size()) + ")");
    }
    const std::string token = body["token"].get<std::string>();
    if (token.empty() || token.size() > 128) {
      return Refuse(request, 401, "unauthenticated", "the token is empty or too long");
    }
    const client::CallResult r = it->second->client->CallRaw("status", "", token, Timeout());
    if (r.status != client::CallStatus::kReplied) {
      return Refuse(request, 504, "unreachable",
                    "station " + station_id + " is not answering: " + r.message);
    }
    if (!r.reply.ok()) {
      const int status = r.reply.code_name == "unauthenticated" ? 401 : 403;
      return Refuse(request, status, r.reply.code_name,
                    "station " + station_id + " refused the token: " + r.reply.message);
    }
    const json you = r.reply.result.value("you", json::object());
    UserSession session{station_id, token, you.value("role", std::string("observer")),
                        you.value("name", std::string()), Clock::now()};
    const std::string cookie = RandomHex(32);
    {
      std::lock_guard lock(sessions_mutex);
      sessions[cookie] = session;
    }
    spdlog::info("{} signed in to {} as {} ({})", request.peer, station_id, session.name,
                 session.role);
    HttpResponse response = JsonResponse(200, {{"station", station_id},
                                               {"role", session.role},
                                               {"client", session.name},
                                               {"stations", config.stations}});
    response.headers.emplace_back("Set-Cookie", std::string(kCookieName) + "=" + cookie +
                                                    "; HttpOnly; SameSite=Strict; Path=/" +
                                                    (request.tls ? "; Secure" : ""));
    return response;
  }

  std::chrono::milliseconds Timeout() const {
    return std::chrono::milliseconds(config.command_timeout_ms);
  }

  HttpResponse Relay(const HttpRequest& request, const UserSession& who, const std::string& verb,
                     const json& args) {
    Station& s = *stations.at(who.station);
    const client::CallResult r =
        s.client->CallRaw(verb, args.is_null() ? "" : args.dump(), who.token, Timeout());
    if (r.status != client::CallStatus::kReplied) {
      return Refuse(request, 504, "unreachable",
                    "station " + who.station + " is not answering: " + r.message);
    }
    if (!r.reply.ok()) {
      spdlog::info("{} {} ({}): {} {}", request.peer, verb, who.name, r.reply.code_name,
                   r.reply.message);
    }
    return JsonResponse(200, ReplyJson(r.reply));
  }

  // A relayed verb's result alone, or the daemon's refusal as an HTTP error.
  HttpResponse RelayResult(const HttpRequest& request, const UserSession& who,
                           const std::string& verb, const json& args) {
    HttpResponse r = Relay(request, who, verb, args);
    if (r.status != 200) return r;
    const json reply = json::parse(r.body);
    if (reply.value("code", -1) != 0) {
      return Error(HttpStatusOf(reply.value("code_name", "")), reply.value("code_name", ""),
                   reply.value("message", ""));
    }
    r.body = reply["result"].dump();
    return r;
  }

  HttpResponse Command(const HttpRequest& request, const UserSession& who, const json& body) {
    if (!body.is_object() || !body.contains("verb") || !body["verb"].is_string()) {
      return Refuse(request, 400, "bad_request", "expected {\"verb\": text, \"args\": {...}}");
    }
    const std::string verb = body["verb"];
    const json args = body.value("args", json::object());
    if (!args.is_object()) return Refuse(request, 400, "bad_request", "args: must be an object");
    if (verb == "get" && args.contains("files")) {
      return Refuse(request, 400, "bad_request",
                    "file transfers go through /api/sessions/<id>/files/<name>");
    }
    return Relay(request, who, verb, args);
  }

  HttpResponse SessionFile(const HttpRequest& request, const UserSession& who,
                           const std::string& id, const std::string& name) {
    Station& s = *stations.at(who.station);
    // The manifest says what the file should be; a cached copy with the same
    // checksum is served as it is.
    const client::CallResult m =
        s.client->CallRaw("get", json{{"session", id}}.dump(), who.token, Timeout());
    if (m.status != client::CallStatus::kReplied) {
      return Refuse(request, 504, "unreachable",
                    "station " + who.station + " is not answering: " + m.message);
    }
    if (!m.reply.ok()) {
      return Refuse(request, HttpStatusOf(m.reply.code_name), m.reply.code_name, m.reply.message);
    }
    const json outputs =
        m.reply.result.value("manifest", json::object()).value("outputs", json::object());
    if (!outputs.is_object() || !outputs.contains(name)) {
      return Refuse(request, 404, "not_found", "session " + id + " has no output '" + name + "'");
    }
    const std::string checksum = outputs[name].value("fnv1a64", std::string());
    const fs::path dir = fs::path(config.cache_dir) / who.station / id;
    const fs::path file = dir / name;
    const fs::path stamp = dir / (".fnv1a64." + fs::path(name).filename().string());
    auto cached = [&] {
      std::ifstream in(stamp);
      std::string have;
      return in >> have && have == checksum && fs::exists(file);
    };
    {
      std::lock_guard lock(s.fetch_mutex);
      if (!cached()) {
        client::FetchRequest fetch;
        fetch.session = id;
        fetch.files = {name};
        fetch.out_dir = dir.string();
        fetch.timeout = Timeout();
        fetch.token = who.token;
        const client::FetchResult f = s.client->Fetch(fetch);
        if (f.status != client::FetchStatus::kOk) {
          const int status = f.status == client::FetchStatus::kUnreachable ? 504
                             : f.status == client::FetchStatus::kRefused   ? 404
                                                                           : 502;
          return Refuse(request, status, "transfer_failed",
                        "could not fetch " + name + " of " + id + ": " + f.message);
        }
        std::ofstream out(stamp, std::ios::trunc);
        out << checksum << "\n";
      }
    }
    HttpResponse r;
    r.content_type = ContentType(name);
    r.file_path = file.string();
    const std::string base = fs::path(name).filename().string();
    if (r.content_type == "application/octet-stream" ||
        request.target.find("download=1") != std::string::npos) {
      r.headers.emplace_back("Content-Disposition", "attachment; filename=\"" + base + "\"");
    }
    return r;
  }

  HttpResponse Asset(const HttpRequest& request, const std::string& relative) {
    if (!IsSafeRelativePath(relative)) {
      return Refuse(request, 400, "bad_path", "not a file name: '" + relative.substr(0, 100) + "'");
    }
    const fs::path file = fs::path(assets_dir) / relative;
    std::error_code ec;
    if (!fs::is_regular_file(file, ec)) {
      return Error(404, "not_found", "no such file: /assets/" + relative);
    }
    HttpResponse r;
    r.content_type = ContentType(relative);
    r.file_path = file.string();
    return r;
  }

  HttpResponse Api(const HttpRequest& request, const std::vector<std::string>& seg) {
    // seg[0] == "api"
    const std::string what = seg.size() > 1 ? seg[1] : "";
    const bool post = request.method == "POST";
    if (post) {
      std::string why;
      if (!OriginOk(request, &why)) return Refuse(request, 403, "forbidden", why);
      if (request.header("x-craftscan-request") != "1") {
        return Refuse(request, 403, "forbidden",
                      "a console request needs the header X-Craftscan-Request: 1");
      }
      const std::string type = request.header("content-type");
      if (type.rfind("application/json", 0) != 0) {
        return Refuse(request, 415, "unsupported_media_type", "the body must be application/json");
      }
    } else if (request.method != "GET") {
      return Refuse(request, 405, "method_not_allowed", request.method + " is not used here");
    }
    json body;
    if (post) {
      body = json::parse(request.body, nullptr, false);
      if (body.is_discarded()) {
        return Refuse(request, 400, "bad_request", "the body is not valid JSON");
      }
    }
    if (what == "login" && post && seg.size() == 2) return Login(request, body);
    if (what == "stations" && !post && seg.size() == 2) {
      json list = json::array();
      for (const std::string& id : config.stations) {
        const json st = StatusJson(*stations.at(id));
        list.push_back({{"id", id},
                        {"state", st.value("state", "unknown")},
                        {"online", st.value("online", false)}});
      }
      return JsonResponse(200, {{"stations", list}});
    }
    const std::optional<UserSession> who = FindSession(request);
    if (!who) return Refuse(request, 401, "unauthenticated", "sign in first");
    if (what == "logout" && post) {
      std::lock_guard lock(sessions_mutex);
      sessions.erase(CookieValue(request));
      HttpResponse r = JsonResponse(200, {{"signed_out", true}});
      r.headers.emplace_back("Set-Cookie", std::string(kCookieName) +
                                               "=; HttpOnly; SameSite=Strict; Path=/; Max-Age=0");
      return r;
    }
    if (what == "me" && !post) {
      return JsonResponse(200,
                          {{"station", who->station}, {"role", who->role}, {"client", who->name}});
    }
    if (what == "status" && !post) return JsonResponse(200, StatusJson(*stations.at(who->station)));
    if (what == "command" && post) return Command(request, *who, body);
    if (what == "sessions" && !post) {
      if (seg.size() == 2) {
        return RelayResult(request, *who, "sessions", nullptr);
      }
      const std::string& id = seg[2];
      if (!IsSessionId(id)) {
        return Refuse(request, 400, "bad_path", "not a session id: '" + id.substr(0, 100) + "'");
      }
      if (seg.size() == 3) {
        return RelayResult(request, *who, "get", {{"session", id}});
      }
      if (seg.size() >= 5 && seg[3] == "files") {
        std::string name = seg[4];
        for (std::size_t i = 5; i < seg.size(); ++i) name += "/" + seg[i];
        if (!IsSafeRelativePath(name)) {
          return Refuse(request, 400, "bad_path",
                        "not an output name: '" + name.substr(0, 100) + "'");
        }
        return SessionFile(request, *who, id, name);
      }
    }
    return Refuse(request, 404, "not_found", "no such API: " + request.method + " /api/" + what);
  }

  HttpResponse Route(const HttpRequest& request) {
    std::string path = request.target.substr(0, request.target.find('?'));
    if (path.empty() || path.front() != '/') {
      return Refuse(request, 400, "bad_request", "the request target must be a path");
    }
    if (path.find('%') != std::string::npos || path.find("//") != std::string::npos) {
      return Refuse(request, 400, "bad_path", "encoded or empty path segments are not served");
    }
    const std::vector<std::string> seg = Segments(path);
    if (!seg.empty() && seg[0] == "api") return Api(request, seg);
    if (request.method != "GET") {
      return Refuse(request, 405, "method_not_allowed", request.method + " is not used here");
    }
    if (path == "/" || path == "/index.html") return Asset(request, "index.html");
    if (seg.size() >= 2 && seg[0] == "assets") return Asset(request, path.substr(8));
    if (path == "/favicon.ico") return Error(404, "not_found", "no favicon");
    return Refuse(request, 404, "not_found", "no such page: " + path.substr(0, 100));
  }
};

std::unique_ptr<Console> Console::Create(const WebConfig& config, std::string* error) {
  std::string why;
  if (!config.IsValid(&why)) {
    if (error) *error = why;
    return nullptr;
  }
  auto impl = std::make_unique<Impl>();
  impl->config = config;
  impl->assets_dir = ResolveAssetsDir(config.assets_dir);
  std::error_code ec;
  if (!fs::is_regular_file(fs::path(impl->assets_dir) / "index.html", ec)) {
    if (error) *error = "assets_dir: no index.html in " + impl->assets_dir;
    return nullptr;
  }
  fs::create_directories(config.cache_dir, ec);
  if (ec || ::access(config.cache_dir.c_str(), W_OK) != 0) {
    if (error) *error = "cache_dir: cannot create or write " + config.cache_dir;
    return nullptr;
  }
  char host[256] = {};
  ::gethostname(host, sizeof host - 1);
  for (const std::string& id : config.stations) {
    auto station = std::make_unique<Impl::Station>();
    station->id = id;
    client::ConnectOptions options;
    options.station = id;
    options.domain_id = config.domain_id;
    options.dds_config = config.dds_config.empty() ? client::DefaultDdsConfig() : config.dds_config;
    options.client_name = std::string("craftscan-web@") + host;
    std::replace_if(
        options.client_name.begin(), options.client_name.end(),
        [](char c) { return c <= ' ' || c > '~'; }, '_');
    if (options.client_name.size() > 64) options.client_name.resize(64);
    std::string connect_error;
    station->client = client::StationClient::Connect(options, &connect_error);
    if (!station->client) {
      if (error) *error = "station " + id + ": " + connect_error;
      return nullptr;
    }
    impl->stations[id] = std::move(station);
  }
  Impl* raw = impl.get();
  for (auto& [id, s] : impl->stations) {
    Impl::Station* st = s.get();
    std::string sub_error;
    const bool ok =
        st->client->SubscribeStatus(
            [raw, st](const client::StatusUpdate& u) { raw->OnStatus(*st, u); }, &sub_error) &&
        st->client->SubscribeProgress(
            [raw, st](const client::ProgressUpdate& u) {
              raw->Broadcast(st->id, json{{"type", "progress"},
                                          {"job_id", u.job_id},
                                          {"stage", u.stage},
                                          {"current", u.current},
                                          {"total", u.total},
                                          {"message", u.message},
                                          {"stamp_ns", u.stamp_ns}}
                                         .dump());
            },
            &sub_error) &&
        st->client->SubscribeCaptures(
            [raw, st](const client::CaptureUpdate& u) {
              raw->Broadcast(st->id, json{{"type", "capture"},
                                          {"session", u.session},
                                          {"view_index", u.view_index},
                                          {"angle_deg", u.angle_deg},
                                          {"left", JpegDataUrl(u.left)},
                                          {"right", JpegDataUrl(u.right)}}
                                         .dump());
            },
            &sub_error) &&
        st->client->SubscribeDisparity(
            [raw, st](const client::DisparityUpdate& u) {
              raw->Broadcast(st->id, DisparityMessage(u).dump());
            },
            &sub_error) &&
        st->client->SubscribePreview(
            [raw, st](const client::PreviewUpdate& u) {
              raw->Broadcast(st->id, PreviewJson(u).dump());
            },
            &sub_error) &&
        st->client->SubscribeClouds(
            [raw, st](const client::CloudUpdate& u) {
              raw->Broadcast(st->id, json{{"type", "cloud"},
                                          {"session", u.session},
                                          {"view_index", u.view_index},
                                          {"kind", u.kind},
                                          {"points", u.cloud.size()}}
                                         .dump());
            },
            &sub_error);
    if (!ok) {
      if (error) *error = "station " + id + ": " + sub_error;
      return nullptr;
    }
  }
  impl->ticker = std::thread([raw] { raw->Tick(); });
  return std::unique_ptr<Console>(new Console(std::move(impl)));
}

Console::Console(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
Console::~Console() = default;

const WebConfig& Console::config() const { return impl_->config; }

HttpResponse Console::Handle(const HttpRequest& request) {
  HttpResponse r;
  const auto start = Clock::now();
  try {
    r = impl_->Route(request);
  } catch (const std::exception& e) {
    spdlog::error("{} {} {}: internal error: {}", request.peer, request.method,
                  request.target.substr(0, 200), e.what());
    r = Error(500, "internal", std::string("internal error: ") + e.what());
  }
  if (request.target.rfind("/api/", 0) == 0) r.headers.emplace_back("Cache-Control", "no-store");
  spdlog::debug(
      "{} {} {} → {} ({} ms)", request.peer, request.method, request.target.substr(0, 200),
      r.status,
      std::chrono::duration_cast<std::chrono::milliseconds>(Clock::now() - start).count());
  return r;
}

bool Console::AuthorizeWebSocket(const HttpRequest& request, std::string* station,
                                 HttpResponse* refusal) {
  std::string why;
  if (!impl_->OriginOk(request, &why)) {
    *refusal = impl_->Refuse(request, 403, "forbidden", why);
    return false;
  }
  const auto who = impl_->FindSession(request);
  if (!who) {
    *refusal = impl_->Refuse(request, 401, "unauthenticated", "sign in first");
    return false;
  }
  *station = who->station;
  return true;
}

int Console::AddListener(const std::string& station, Sink sink) {
  const auto it = impl_->stations.find(station);
  int id = 0;
  {
    std::lock_guard lock(impl_->listeners_mutex);
    id = impl_->next_listener++;
    impl_->listeners[id] = {station, sink};
  }
  if (it != impl_->stations.end()) {
    json j = impl_->StatusJson(*it->second);
    j["type"] = "status";
    sink(j.dump());
  }
  return id;
}

void Console::RemoveListener(int id) {
  std::lock_guard lock(impl_->listeners_mutex);
  impl_->listeners.erase(id);
}

std::string Console::HandleWebSocketMessage(const std::string& text) {
  const json j = json::parse(text, nullptr, false);
  if (j.is_object() && j.value("type", "") == "ping") return R"({"type":"pong"})";
  return json{{"type", "error"}, {"error", "unknown message; only {\"type\": \"ping\"} is read"}}
      .dump();
}

}  // namespace craftscan::web
