// A POSIX serial port (termios directly, so pseudo-terminals work too): raw
// 8N1, no flow control, non-blocking I/O with poll() and a timeout per call.
//
//   SerialPort port;
//   Status s = port.Open("/dev/ttyUSB0", 115200);
//   s = port.Write("?", std::chrono::milliseconds(100));
//   std::string bytes;
//   s = port.Read(&bytes, std::chrono::milliseconds(50));  // kTimeout if nothing came
//
// Errors name the path and carry strerror(). EIO, ENXIO and a hang-up
// (POLLHUP/POLLERR: the USB adapter was unplugged, the PTY master closed) are
// reported as StatusCode::kDeviceLost; the port stays "open" until Close() so
// the caller decides when to reopen.
//
// Thread-safety: Read() from one thread at a time; Write() may be called from
// another thread concurrently with Read() (one write(2) per call for short
// writes, e.g. a real-time byte). Open()/Close() must not race with anything.
#pragma once

#include <chrono>
#include <cstddef>
#include <string>
#include <string_view>

#include "craftscan/drivers/serial_turntable/status.h"

namespace craftscan::serial_turntable {

class SerialPort {
 public:
  SerialPort() = default;
  ~SerialPort();
  SerialPort(const SerialPort&) = delete;
  SerialPort& operator=(const SerialPort&) = delete;

  // Opens `path` (O_NOCTTY, non-blocking) and configures raw 8N1 at `baud`
  // (one of 9600, 19200, 38400, 57600, 115200, 230400). Closes a port already
  // open first. kInvalidArgument for an unsupported baud rate, kIoError when
  // the path cannot be opened or configured.
  Status Open(const std::string& path, int baud);
  void Close();
  bool is_open() const { return fd_ >= 0; }
  const std::string& path() const { return path_; }

  // Writes all of `bytes`, waiting up to `timeout` in total for the device to
  // accept them. kTimeout when the output stays blocked, kDeviceLost on
  // EIO/ENXIO/EPIPE/hang-up.
  Status Write(std::string_view bytes, std::chrono::milliseconds timeout);

  // Appends to `out` what is available, up to `max_bytes`, waiting up to
  // `timeout` for the first byte (0 = just check). kTimeout when nothing
  // arrived, kDeviceLost on EIO/ENXIO/hang-up.
  Status Read(std::string* out, std::chrono::milliseconds timeout, std::size_t max_bytes = 4096);

  // Discards bytes received but not read yet.
  void DiscardInput();

 private:
  Status Errno(std::string_view what, int err) const;

  int fd_ = -1;
  std::string path_;
};

}  // namespace craftscan::serial_turntable
