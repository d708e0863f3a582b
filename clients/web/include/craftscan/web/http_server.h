// craftscan-web's HTTP/1.1 and WebSocket server (Boost.Beast on Asio, TLS
// through OpenSSL when the config names a certificate). Sockets are served
// asynchronously by two I/O threads; each request is then handed to
// Console::Handle on a small pool, since relaying to a station blocks for
// as long as the station takes to answer. WebSocket connections on /api/ws
// receive the Console's live updates.
//
// Limits: bodies above the config's max_body_bytes → 413; headers above
// 16 KiB → 431; a request not complete within 30 s closes the connection;
// at most 256 connections at a time (more are closed at once); at most 256
// queued messages per WebSocket (a slow browser loses the oldest captures,
// never the newest status).
#pragma once

#include <cstdint>
#include <memory>
#include <string>

namespace craftscan::web {

class Console;

class HttpServer {
 public:
  // Binds the config's listen address (port 0: any free port, see port())
  // and starts serving. Null with *error (the address in use, a bad TLS
  // certificate or key, ...). The console must outlive the server.
  static std::unique_ptr<HttpServer> Start(Console* console, std::string* error);
  ~HttpServer();  // stops and joins
  HttpServer(const HttpServer&) = delete;
  HttpServer& operator=(const HttpServer&) = delete;

  std::uint16_t port() const;

 private:
  struct Impl;
  explicit HttpServer(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace craftscan::web
