// The console's logic, apart from any socket: sign-in sessions, the request
// rules of API.md (cookie, Origin, X-Craftscan-Request, body size, JSON),
// the relay of commands to each station's daemon (StationClient, the user's
// own token), cached session files and the live updates the WebSocket
// connections receive. http_server.cc feeds it parsed requests; the tests
// call it directly and through the server.
//
// Thread-safety: every public member may be called from any thread. Handle
// blocks for as long as the station takes to answer (bounded by
// command_timeout_ms, and per chunk for file transfers).
#pragma once

#include <functional>
#include <map>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "craftscan/web/web_config.h"

namespace craftscan::web {

struct HttpRequest {
  std::string method;                          // "GET", "POST", ...
  std::string target;                          // path and query, as received
  std::map<std::string, std::string> headers;  // names in lower case
  std::string body;
  std::string peer;  // "address:port", for the log
  bool tls = false;
  std::string header(const std::string& lower_name) const {
    const auto it = headers.find(lower_name);
    return it == headers.end() ? std::string() : it->second;
  }
};

struct HttpResponse {
  int status = 200;
  std::string content_type = "application/json";
  std::string body;
  std::string file_path;  // when not empty: send this file's bytes instead of body
  std::vector<std::pair<std::string, std::string>> headers;  // extra (Set-Cookie, ...)
};

// Where the console's files are: `configured` if not empty, else
// <directory of the running binary>/assets when it exists (the build tree),
// else /usr/share/craftscan/web/assets.
std::string ResolveAssetsDir(const std::string& configured);

// A path inside the console's file space (an asset, a session output):
// 1..256 bytes of segments [A-Za-z0-9._-] separated by '/', no segment
// empty, "." or "..", none starting with '.'.
bool IsSafeRelativePath(const std::string& path);

class Console {
 public:
  // Joins the DDS domain and subscribes to every configured station. Null
  // with *error for an invalid config, an assets folder without index.html,
  // a cache folder that cannot be made, or a DDS failure.
  static std::unique_ptr<Console> Create(const WebConfig& config, std::string* error);
  ~Console();
  Console(const Console&) = delete;
  Console& operator=(const Console&) = delete;

  // One HTTP request (not a WebSocket upgrade) → its response.
  HttpResponse Handle(const HttpRequest& request);

  // A WebSocket upgrade of /api/ws: true with *station when the request
  // carries a valid session and an acceptable Origin; else false with the
  // refusal to send.
  bool AuthorizeWebSocket(const HttpRequest& request, std::string* station, HttpResponse* refusal);

  // Live updates of `station` (JSON text messages, API.md). The sink is
  // called from the console's threads, must not block, and must not call
  // back into the console. The current status is sent at once.
  using Sink = std::function<void(const std::string& message)>;
  int AddListener(const std::string& station, Sink sink);
  void RemoveListener(int id);
  // A message from the browser → the answer to send ("" = none).
  std::string HandleWebSocketMessage(const std::string& text);

  const WebConfig& config() const;

 private:
  struct Impl;
  explicit Console(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace craftscan::web
