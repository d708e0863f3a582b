// The service manager's end of the sd_notify protocol, for tests: a unix
// datagram socket (a path in a fresh temp folder, or an abstract "@…" name)
// whose address goes into NOTIFY_SOCKET; tests receive what the code under
// test sent, with the sender's pid (SO_PASSCRED), as systemd does.
//
//   FakeNotifySocket manager;                 // ASSERT_TRUE(manager.ok()) << manager.error();
//   ScopedEnv env("NOTIFY_SOCKET", manager.address());
//   ... code under test calls sd_notify ...   // or a child process inherits it
//   auto m = manager.Receive();               // std::optional<NotifyMessage>
//   EXPECT_TRUE(m && m->Has("READY=1"));
//
// Receive waits at most `timeout` (no test should hang when nothing comes);
// the waits are guards, not measurements. Not thread-safe.
#pragma once

#include <poll.h>
#include <stdlib.h>
#include <sys/socket.h>
#include <sys/types.h>
#include <sys/un.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <chrono>
#include <cstddef>
#include <cstring>
#include <filesystem>
#include <optional>
#include <random>
#include <sstream>
#include <string>
#include <string_view>
#include <vector>

namespace craftscan::testing {

// One datagram: newline-separated VARIABLE=value assignments.
struct NotifyMessage {
  std::string text;
  pid_t pid = 0;  // sender (from SCM_CREDENTIALS), 0 if none came
  uid_t uid = 0;

  std::vector<std::string> Assignments() const {
    std::vector<std::string> lines;
    std::istringstream in(text);
    for (std::string line; std::getline(in, line);) {
      if (!line.empty()) lines.push_back(line);
    }
    return lines;
  }
  // Whether one line is exactly `assignment` (e.g. "READY=1").
  bool Has(std::string_view assignment) const {
    for (const std::string& line : Assignments()) {
      if (line == assignment) return true;
    }
    return false;
  }
  // The value of VARIABLE (e.g. Value("STATUS")), or nullopt.
  std::optional<std::string> Value(std::string_view variable) const {
    const std::string prefix = std::string(variable) + "=";
    for (const std::string& line : Assignments()) {
      if (line.rfind(prefix, 0) == 0) return line.substr(prefix.size());
    }
    return std::nullopt;
  }
};

class FakeNotifySocket {
 public:
  enum class Kind { kPath, kAbstract };

  explicit FakeNotifySocket(Kind kind = Kind::kPath) {
    fd_ = ::socket(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC | SOCK_NONBLOCK, 0);
    if (fd_ < 0) {
      error_ = std::string("socket: ") + std::strerror(errno);
      return;
    }
    const int on = 1;
    if (::setsockopt(fd_, SOL_SOCKET, SO_PASSCRED, &on, sizeof on) != 0) {
      error_ = std::string("SO_PASSCRED: ") + std::strerror(errno);
      return;
    }
    sockaddr_un addr{};
    addr.sun_family = AF_UNIX;
    socklen_t length = 0;
    if (kind == Kind::kPath) {
      std::string dir_template =
          (std::filesystem::temp_directory_path() / "craftscan-notify-XXXXXX").string();
      if (::mkdtemp(dir_template.data()) == nullptr) {
        error_ = std::string("mkdtemp: ") + std::strerror(errno);
        return;
      }
      dir_ = dir_template;
      address_ = dir_ + "/notify";
      if (address_.size() >= sizeof addr.sun_path) {
        error_ = "socket path too long: " + address_;
        return;
      }
      std::memcpy(addr.sun_path, address_.c_str(), address_.size() + 1);
      length = static_cast<socklen_t>(offsetof(sockaddr_un, sun_path) + address_.size() + 1);
    } else {
      static std::atomic<int> counter{0};
      const std::string name = "craftscan-notify-" + std::to_string(::getpid()) + "-" +
                               std::to_string(counter++) + "-" +
                               std::to_string(std::random_device{}());
      address_ = "@" + name;
      // Abstract namespace: a leading NUL, the name, no terminator.
      addr.sun_path[0] = '\0';
      std::memcpy(addr.sun_path + 1, name.data(), name.size());
      length = static_cast<socklen_t>(offsetof(sockaddr_un, sun_path) + 1 + name.size());
    }
    if (::bind(fd_, reinterpret_cast<const sockaddr*>(&addr), length) != 0) {
      error_ = "bind " + address_ + ": " + std::strerror(errno);
      return;
    }
    ok_ = true;
  }

  ~FakeNotifySocket() {
    if (fd_ >= 0) ::close(fd_);
    if (!dir_.empty()) {
      std::error_code ec;
      std::filesystem::remove_all(dir_, ec);
    }
  }
  FakeNotifySocket(const FakeNotifySocket&) = delete;
  FakeNotifySocket& operator=(const FakeNotifySocket&) = delete;

  bool ok() const { return ok_; }
  const std::string& error() const { return error_; }
  // The value for NOTIFY_SOCKET: a path, or "@name" for the abstract socket.
  const std::string& address() const { return address_; }

  // The next datagram, waiting up to `timeout`; nullopt if none came.
  std::optional<NotifyMessage> Receive(
      std::chrono::milliseconds timeout = std::chrono::milliseconds(5000)) {
    if (!ok_) return std::nullopt;
    pollfd p{fd_, POLLIN, 0};
    int r = 0;
    do {
      r = ::poll(&p, 1, static_cast<int>(timeout.count()));
    } while (r < 0 && errno == EINTR);
    if (r <= 0) return std::nullopt;
    return ReadOne();
  }

  // Every datagram already queued, without waiting.
  std::vector<NotifyMessage> Drain() {
    std::vector<NotifyMessage> messages;
    while (auto m = ReadOne()) messages.push_back(std::move(*m));
    return messages;
  }

  // Receives until a datagram has the line `assignment` (e.g. "READY=1");
  // returns it, or nullopt when none came within `timeout` per datagram.
  std::optional<NotifyMessage> WaitFor(
      std::string_view assignment,
      std::chrono::milliseconds timeout = std::chrono::milliseconds(5000)) {
    while (auto m = Receive(timeout)) {
      if (m->Has(assignment)) return m;
    }
    return std::nullopt;
  }

 private:
  std::optional<NotifyMessage> ReadOne() {
    std::vector<char> buffer(64 * 1024);
    alignas(cmsghdr) char control[CMSG_SPACE(sizeof(ucred))];
    iovec iov{buffer.data(), buffer.size()};
    msghdr msg{};
    msg.msg_iov = &iov;
    msg.msg_iovlen = 1;
    msg.msg_control = control;
    msg.msg_controllen = sizeof control;
    ssize_t n = 0;
    do {
      n = ::recvmsg(fd_, &msg, MSG_DONTWAIT | MSG_CMSG_CLOEXEC);
    } while (n < 0 && errno == EINTR);
    if (n < 0) return std::nullopt;
    NotifyMessage m;
    m.text.assign(buffer.data(), static_cast<std::size_t>(n));
    for (cmsghdr* c = CMSG_FIRSTHDR(&msg); c != nullptr; c = CMSG_NXTHDR(&msg, c)) {
      if (c->cmsg_level == SOL_SOCKET && c->cmsg_type == SCM_CREDENTIALS) {
        ucred cred{};
        std::memcpy(&cred, CMSG_DATA(c), sizeof cred);
        m.pid = cred.pid;
        m.uid = cred.uid;
      }
    }
    return m;
  }

  int fd_ = -1;
  bool ok_ = false;
  std::string error_, address_, dir_;
};

// Sets an environment variable (or unsets it, for nullopt) for the scope of
// the object and restores the previous state after. Not thread-safe (the
// environment is process-wide).
class ScopedEnv {
 public:
  ScopedEnv(std::string name, std::optional<std::string> value) : name_(std::move(name)) {
    if (const char* old = ::getenv(name_.c_str())) old_ = old;
    if (value) {
      ::setenv(name_.c_str(), value->c_str(), 1);
    } else {
      ::unsetenv(name_.c_str());
    }
  }
  ~ScopedEnv() {
    if (old_) {
      ::setenv(name_.c_str(), old_->c_str(), 1);
    } else {
      ::unsetenv(name_.c_str());
    }
  }
  ScopedEnv(const ScopedEnv&) = delete;
  ScopedEnv& operator=(const ScopedEnv&) = delete;

 private:
  std::string name_;
  std::optional<std::string> old_;
};

}  // namespace craftscan::testing
