#include "craftscan/drivers/serial_turntable/serial_port.h"

#include <fcntl.h>
#include <poll.h>
#include <termios.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

namespace craftscan::serial_turntable {
namespace {

using Clock = std::chrono::steady_clock;

bool BaudConstant(int baud, speed_t* speed) {
  switch (baud) {
    case 9600:
      *speed = B9600;
      return true;
    case 19200:
      *speed = B19200;
      return true;
    case 38400:
      *speed = B38400;
      return true;
    case 57600:
      *speed = B57600;
      return true;
    case 115200:
      *speed = B115200;
      return true;
    case 230400:
      *speed = B230400;
      return true;
    default:
      return false;
  }
}

bool IsLostErrno(int err) { return err == EIO || err == ENXIO || err == EPIPE || err == ENODEV; }

int RemainingMs(Clock::time_point deadline) {
  auto left = std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now());
  return left.count() > 0 ? static_cast<int>(left.count()) : 0;
}

}  // namespace

SerialPort::~SerialPort() { Close(); }

Status SerialPort::Errno(std::string_view what, int err) const {
  return {IsLostErrno(err) ? StatusCode::kDeviceLost : StatusCode::kIoError,
          std::string(what) + " " + path_ + ": " + std::strerror(err)};
}

Status SerialPort::Open(const std::string& path, int baud) {
  Close();
  path_ = path;
  speed_t speed;
  if (!BaudConstant(baud, &speed)) {
    return {StatusCode::kInvalidArgument,
            "unsupported baud rate " + std::to_string(baud) + " for " + path};
  }
  int fd = ::open(path.c_str(), O_RDWR | O_NOCTTY | O_NONBLOCK | O_CLOEXEC);
  if (fd < 0) {
    Status s = Errno("cannot open", errno);
    s.code = StatusCode::kIoError;  // a missing device at open time is not a "lost" device
    return s;
  }
  termios tio{};
  if (::tcgetattr(fd, &tio) != 0) {
    int err = errno;
    ::close(fd);
    return {StatusCode::kIoError,
            "cannot configure " + path + " (not a terminal?): " + std::strerror(err)};
  }
  ::cfmakeraw(&tio);
  tio.c_cflag &= ~(CSTOPB | PARENB | CRTSCTS | CSIZE);
  tio.c_cflag |= CS8 | CLOCAL | CREAD;
  tio.c_iflag &= ~(IXON | IXOFF | IXANY);
  tio.c_cc[VMIN] = 0;
  tio.c_cc[VTIME] = 0;
  if (::cfsetispeed(&tio, speed) != 0 || ::cfsetospeed(&tio, speed) != 0 ||
      ::tcsetattr(fd, TCSANOW, &tio) != 0) {
    int err = errno;
    ::close(fd);
    return {StatusCode::kIoError, "cannot configure " + path + ": " + std::strerror(err)};
  }
  fd_ = fd;
  return Status::Ok();
}

void SerialPort::Close() {
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
}

void SerialPort::DiscardInput() {
  if (fd_ >= 0) ::tcflush(fd_, TCIFLUSH);
}

Status SerialPort::Write(std::string_view bytes, std::chrono::milliseconds timeout) {
  if (fd_ < 0) return {StatusCode::kIoError, "write to closed port " + path_};
  const auto deadline = Clock::now() + timeout;
  while (!bytes.empty()) {
    ssize_t n = ::write(fd_, bytes.data(), bytes.size());
    if (n > 0) {
      bytes.remove_prefix(static_cast<std::size_t>(n));
      continue;
    }
    if (n < 0 && errno == EINTR) continue;
    if (n < 0 && errno != EAGAIN && errno != EWOULDBLOCK) return Errno("cannot write to", errno);
    pollfd pfd{fd_, POLLOUT, 0};
    int r = ::poll(&pfd, 1, RemainingMs(deadline));
    if (r < 0 && errno == EINTR) continue;
    if (r < 0) return Errno("cannot poll", errno);
    if (r == 0) {
      return {StatusCode::kTimeout,
              "write to " + path_ + " blocked for " + std::to_string(timeout.count()) + " ms"};
    }
    if (pfd.revents & (POLLHUP | POLLERR | POLLNVAL)) {
      return {StatusCode::kDeviceLost, "device " + path_ + " hung up"};
    }
  }
  return Status::Ok();
}

Status SerialPort::Read(std::string* out, std::chrono::milliseconds timeout,
                        std::size_t max_bytes) {
  if (fd_ < 0) return {StatusCode::kIoError, "read from closed port " + path_};
  const auto deadline = Clock::now() + timeout;
  for (;;) {
    pollfd pfd{fd_, POLLIN, 0};
    int r = ::poll(&pfd, 1, RemainingMs(deadline));
    if (r < 0 && errno == EINTR) continue;
    if (r < 0) return Errno("cannot poll", errno);
    if (r == 0) return {StatusCode::kTimeout, "no data from " + path_};
    if (pfd.revents & POLLIN) {
      char buf[4096];
      std::size_t want = max_bytes < sizeof(buf) ? max_bytes : sizeof(buf);
      ssize_t n = ::read(fd_, buf, want);
      if (n > 0) {
        out->append(buf, static_cast<std::size_t>(n));
        return Status::Ok();
      }
      if (n == 0) return {StatusCode::kDeviceLost, "device " + path_ + " hung up (end of file)"};
      if (errno == EINTR || errno == EAGAIN || errno == EWOULDBLOCK) continue;
      return Errno("cannot read from", errno);
    }
    if (pfd.revents & (POLLHUP | POLLERR | POLLNVAL)) {
      return {StatusCode::kDeviceLost, "device " + path_ + " hung up"};
    }
  }
}

}  // namespace craftscan::serial_turntable
