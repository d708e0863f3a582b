// A deliberately plain HTTP/1.1 and WebSocket client for the console's
// tests: POSIX sockets and hand-written requests, so the tests can send what
// a browser never would (forged origins, bad paths, oversized bodies) and
// nothing of the server's own HTTP code checks the server.
#pragma once

#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <chrono>
#include <cstdint>
#include <map>
#include <string>
#include <utility>
#include <vector>

namespace craftscan::testing {

struct HttpReply {
  int status = 0;                              // 0: no answer
  std::map<std::string, std::string> headers;  // lower-case names
  std::string body;
};

class Socket {
 public:
  explicit Socket(std::uint16_t port) {
    fd_ = ::socket(AF_INET, SOCK_STREAM, 0);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_port = htons(port);
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    if (::connect(fd_, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0) {
      ::close(fd_);
      fd_ = -1;
    }
  }
  ~Socket() {
    if (fd_ >= 0) ::close(fd_);
  }
  Socket(const Socket&) = delete;
  Socket& operator=(const Socket&) = delete;
  bool ok() const { return fd_ >= 0; }
  bool Send(const std::string& data) {
    std::size_t done = 0;
    while (done < data.size()) {
      const ssize_t n = ::send(fd_, data.data() + done, data.size() - done, MSG_NOSIGNAL);
      if (n <= 0) return false;
      done += static_cast<std::size_t>(n);
    }
    return true;
  }
  // Appends what arrives within `timeout` (stops at EOF); false at EOF or error.
  bool Receive(std::string* into, std::chrono::milliseconds timeout) {
    pollfd p{fd_, POLLIN, 0};
    if (::poll(&p, 1, static_cast<int>(timeout.count())) <= 0) return true;
    char buffer[65536];
    const ssize_t n = ::recv(fd_, buffer, sizeof buffer, 0);
    if (n <= 0) return false;
    into->append(buffer, static_cast<std::size_t>(n));
    return true;
  }

 private:
  int fd_ = -1;
};

inline std::string Lower(std::string s) {
  for (char& c : s) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return s;
}

// Parses the head; *head_end past the blank line. False if incomplete.
inline bool ParseHead(const std::string& raw, HttpReply* reply, std::size_t* head_end) {
  const std::size_t end = raw.find("\r\n\r\n");
  if (end == std::string::npos) return false;
  *head_end = end + 4;
  std::size_t pos = raw.find("\r\n");
  const std::string status_line = raw.substr(0, pos);
  const std::size_t sp = status_line.find(' ');
  reply->status = sp == std::string::npos ? 0 : std::atoi(status_line.c_str() + sp + 1);
  while (pos < end) {
    const std::size_t next = raw.find("\r\n", pos + 2);
    const std::string line = raw.substr(pos + 2, next - pos - 2);
    const std::size_t colon = line.find(':');
    if (colon != std::string::npos) {
      std::string value = line.substr(colon + 1);
      while (!value.empty() && value.front() == ' ') value.erase(0, 1);
      reply->headers[Lower(line.substr(0, colon))] = value;
    }
    pos = next;
  }
  return true;
}

// One request on a new connection (Connection: close); `extra` are whole
// header lines ("Name: value").
inline HttpReply Request(std::uint16_t port, const std::string& method, const std::string& target,
                         const std::vector<std::string>& extra = {}, const std::string& body = "",
                         std::chrono::milliseconds timeout = std::chrono::seconds(60)) {
  HttpReply reply;
  Socket s(port);
  if (!s.ok()) return reply;
  std::string request = method + " " + target +
                        " HTTP/1.1\r\nHost: 127.0.0.1:" + std::to_string(port) +
                        "\r\nConnection: close\r\n";
  for (const std::string& h : extra) request += h + "\r\n";
  if (!body.empty() || method == "POST") {
    request += "Content-Length: " + std::to_string(body.size()) + "\r\n";
  }
  request += "\r\n" + body;
  s.Send(request);
  std::string raw;
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (std::chrono::steady_clock::now() < deadline) {
    if (!s.Receive(&raw, std::chrono::milliseconds(100))) break;
  }
  std::size_t head_end = 0;
  if (!ParseHead(raw, &reply, &head_end)) return reply;
  reply.body = raw.substr(head_end);
  return reply;
}

// A WebSocket client: the upgrade, then text messages from the server.
class WebSocketClient {
 public:
  WebSocketClient(std::uint16_t port, const std::vector<std::string>& extra) : socket_(port) {
    if (!socket_.ok()) return;
    std::string request = "GET /api/ws HTTP/1.1\r\nHost: 127.0.0.1:" + std::to_string(port) +
                          "\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                          "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
                          "Sec-WebSocket-Version: 13\r\n";
    for (const std::string& h : extra) request += h + "\r\n";
    socket_.Send(request + "\r\n");
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(10);
    std::size_t head_end = 0;
    while (std::chrono::steady_clock::now() < deadline && !ParseHead(raw_, &head_, &head_end)) {
      if (!socket_.Receive(&raw_, std::chrono::milliseconds(100))) break;
    }
    if (head_end > 0) raw_.erase(0, head_end);
  }
  int status() const { return head_.status; }

  // The next text message within `timeout`; "" if none.
  std::string Next(std::chrono::milliseconds timeout) {
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    while (true) {
      std::string message;
      if (TakeFrame(&message)) return message;
      if (std::chrono::steady_clock::now() > deadline) return "";
      if (!socket_.Receive(&raw_, std::chrono::milliseconds(50))) {
        if (!TakeFrame(&message)) return "";
        return message;
      }
    }
  }

  // A masked text frame (clients must mask).
  bool SendText(const std::string& text) {
    std::string frame;
    frame += static_cast<char>(0x81);
    if (text.size() < 126) {
      frame += static_cast<char>(0x80 | text.size());
    } else {
      frame += static_cast<char>(0x80 | 126);
      frame += static_cast<char>((text.size() >> 8) & 0xff);
      frame += static_cast<char>(text.size() & 0xff);
    }
    const unsigned char mask[4] = {0x12, 0x34, 0x56, 0x78};
    frame.append(reinterpret_cast<const char*>(mask), 4);
    for (std::size_t i = 0; i < text.size(); ++i) {
      frame += static_cast<char>(text[i] ^ mask[i % 4]);
    }
    return socket_.Send(frame);
  }

 private:
  // One whole message from raw_ (fragments joined); control frames are skipped.
  bool TakeFrame(std::string* message) {
    while (raw_.size() >= 2) {
      const unsigned char b0 = static_cast<unsigned char>(raw_[0]);
      std::uint64_t length = static_cast<unsigned char>(raw_[1]) & 0x7f;
      std::size_t header = 2;
      if (length == 126) {
        if (raw_.size() < 4) return false;
        length = (static_cast<unsigned char>(raw_[2]) << 8) | static_cast<unsigned char>(raw_[3]);
        header = 4;
      } else if (length == 127) {
        if (raw_.size() < 10) return false;
        length = 0;
        for (int i = 0; i < 8; ++i)
          length = (length << 8) | static_cast<unsigned char>(raw_[2 + i]);
        header = 10;
      }
      if (raw_.size() < header + length) return false;
      const std::string payload = raw_.substr(header, length);
      raw_.erase(0, header + length);
      const int opcode = b0 & 0x0f;
      const bool fin = (b0 & 0x80) != 0;
      if (opcode == 0x1 || opcode == 0x0) {  // text, or its continuation
        partial_ += payload;
        if (fin) {
          *message = std::move(partial_);
          partial_.clear();
          return true;
        }
      }
    }
    return false;
  }

  Socket socket_;
  HttpReply head_;
  std::string raw_, partial_;
};

}  // namespace craftscan::testing
