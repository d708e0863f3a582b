#include "turntable_emulator.h"

#include <fcntl.h>
#include <poll.h>
#include <pty.h>
#include <termios.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <mutex>
#include <optional>
#include <thread>
#include <vector>

namespace craftscan::testing {
namespace {

using Clock = std::chrono::steady_clock;

enum class EmuState { kIdle, kRun, kHold, kHome, kAlarm };

const char* Name(EmuState s) {
  switch (s) {
    case EmuState::kIdle:
      return "Idle";
    case EmuState::kRun:
      return "Run";
    case EmuState::kHold:
      return "Hold";
    case EmuState::kHome:
      return "Home";
    case EmuState::kAlarm:
      return "Alarm";
  }
  return "Idle";
}

struct Move {
  double target_deg;  // machine coordinates
  double feed_per_min;
};

std::string Fmt(const char* format, double a, double b = 0) {
  char buf[128];
  std::snprintf(buf, sizeof(buf), format, a, b);
  return buf;
}

}  // namespace

struct TurntableEmulator::Impl {
  EmulatorOptions options;
  int master = -1;
  int slave = -1;
  std::string slave_path;
  std::thread thread;
  std::atomic<bool> stop{false};
  std::atomic<bool> hung_up{false};

  std::mutex mu;
  EmuState state = EmuState::kIdle;
  double pos_deg = 0;  // machine position at move_start (or current when not moving)
  Move current{0, 0};
  Clock::time_point move_start, move_end, homing_end;
  // Feed hold: from hold_from_deg at hold_start, velocity hold_v_deg_s
  // (signed) decelerating to a stop at hold_end.
  Clock::time_point hold_start, hold_end;
  double hold_from_deg = 0, hold_v_deg_s = 0;
  std::deque<Move> queue;
  std::deque<std::string> held_lines;  // received during homing
  double wco_deg = 0;                  // G92 work offset: WPos = MPos − wco
  bool absolute = true;
  int motion_mode = 0;
  std::optional<double> feed;
  double offset_deg = 0;
  bool silent = false;
  std::string line;
  bool line_overflow = false;
  int lines = 0;
  int resets = 0;

  // ---- everything below is called with mu held ----

  void Send(const std::string& text) {
    if (!silent) SendAlways(text);
  }

  void SendAlways(const std::string& text) {
    if (master < 0) return;
    std::string_view rest = text;
    const auto deadline = Clock::now() + std::chrono::milliseconds(200);
    while (!rest.empty() && Clock::now() < deadline) {
      ssize_t n = ::write(master, rest.data(), rest.size());
      if (n > 0) {
        rest.remove_prefix(static_cast<std::size_t>(n));
      } else if (n < 0 && (errno == EAGAIN || errno == EINTR)) {
        pollfd pfd{master, POLLOUT, 0};
        ::poll(&pfd, 1, 10);
      } else {
        return;
      }
    }
  }

  double Position(Clock::time_point now) const {
    if (state == EmuState::kHold) {
      const double t = std::chrono::duration<double>(std::min(now, hold_end) - hold_start).count();
      const double a = hold_v_deg_s >= 0 ? options.hold_decel_deg_s2 : -options.hold_decel_deg_s2;
      const double p = hold_from_deg + hold_v_deg_s * t - 0.5 * a * t * t;
      // A hold never carries the platter past the move's target.
      return hold_v_deg_s >= 0 ? std::min(p, current.target_deg) : std::max(p, current.target_deg);
    }
    if (state != EmuState::kRun) return pos_deg;
    if (now >= move_end) return current.target_deg;
    const double t = std::chrono::duration<double>(now - move_start).count() /
                     std::chrono::duration<double>(move_end - move_start).count();
    return pos_deg + (current.target_deg - pos_deg) * t;
  }

  // Where the machine will be when the queue is done (machine coordinates).
  double PlannedEnd() const {
    if (!queue.empty()) return queue.back().target_deg;
    return state == EmuState::kRun || state == EmuState::kHold ? current.target_deg : pos_deg;
  }

  bool HoldComplete(Clock::time_point now) const {
    return state == EmuState::kHold && now >= hold_end;
  }

  // '!' during a move: decelerate to a stop.
  void FeedHold(Clock::time_point now) {
    if (state != EmuState::kRun) return;  // GRBL ignores a hold when nothing moves
    hold_from_deg = Position(now);
    const double speed = current.feed_per_min / 60.0;
    hold_v_deg_s = current.target_deg >= pos_deg ? speed : -speed;
    hold_start = now;
    hold_end = now + std::chrono::duration_cast<Clock::duration>(
                         std::chrono::duration<double>(speed / options.hold_decel_deg_s2));
    state = EmuState::kHold;
  }

  // '~' after a completed hold: the move continues to its target.
  void CycleStart(Clock::time_point now) {
    if (!HoldComplete(now)) return;
    pos_deg = Position(now);
    state = EmuState::kIdle;
    StartMove(current, now);
  }

  void StartMove(const Move& move, Clock::time_point now) {
    current = move;
    move_start = now;
    const double seconds = std::abs(move.target_deg - pos_deg) / move.feed_per_min * 60.0;
    move_end =
        now + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(seconds));
    state = EmuState::kRun;
  }

  void Advance(Clock::time_point now) {
    if (state == EmuState::kHome && now >= homing_end) {
      pos_deg = 0;
      wco_deg = 0;
      state = EmuState::kIdle;
      Send("ok\r\n");
      while (!held_lines.empty() && state != EmuState::kHome) {
        std::string held = std::move(held_lines.front());
        held_lines.pop_front();
        ExecuteLine(held, now);
      }
    }
    while (state == EmuState::kRun && now >= move_end) {
      pos_deg = current.target_deg;
      const auto end = move_end;
      state = EmuState::kIdle;
      if (!queue.empty()) {
        Move next = queue.front();
        queue.pop_front();
        StartMove(next, end);
      }
    }
  }

  void Halt(Clock::time_point now) {
    pos_deg = Position(now);
    queue.clear();
    held_lines.clear();
  }

  void SoftReset(Clock::time_point now) {
    ++resets;
    // Reset in a completed hold keeps the position; while still slowing
    // down it is a reset in motion.
    const EmuState was = HoldComplete(now)          ? EmuState::kIdle
                         : state == EmuState::kHold ? EmuState::kRun
                                                    : state;
    Halt(now);
    line.clear();
    line_overflow = false;
    absolute = true;
    motion_mode = 0;
    feed.reset();
    wco_deg = 0;
    if (was == EmuState::kRun || was == EmuState::kHome) {
      state = EmuState::kAlarm;
      Send(was == EmuState::kRun ? "ALARM:3\r\n" : "ALARM:6\r\n");
    } else if (was != EmuState::kAlarm) {
      state = EmuState::kIdle;
    }
    Send("\r\nGrbl " + options.version + " ['$' for help]\r\n");
    if (state == EmuState::kAlarm) Send("[MSG:'$H'|'$X' to unlock]\r\n");
  }

  void StatusReport(Clock::time_point now) {
    const double x = Position(now) + offset_deg;
    const double f = state == EmuState::kRun ? current.feed_per_min : 0;
    std::string name = Name(state);
    if (state == EmuState::kHold) name += HoldComplete(now) ? ":0" : ":1";
    Send("<" + name + Fmt("|MPos:%.3f,0.000,0.000|FS:%.0f,0>\r\n", x, f));
  }

  void Error(int code) { Send("error:" + std::to_string(code) + "\r\n"); }

  void ExecuteLine(const std::string& text, Clock::time_point now) {
    if (state == EmuState::kHome) {
      held_lines.push_back(text);
      return;
    }
    if (text.empty()) return Send("ok\r\n");
    if (text[0] == '$') {
      if (text == "$H") {
        if (!options.homing_enabled) return Error(5);
        if (state == EmuState::kRun || state == EmuState::kHold) return Error(8);
        Halt(now);
        state = EmuState::kHome;
        homing_end = now + options.homing_time;
        return;  // ok when homing is done
      }
      if (text == "$X") {
        if (state == EmuState::kAlarm) {
          state = EmuState::kIdle;
          Send("[MSG:Caution: Unlocked]\r\n");
        }
        return Send("ok\r\n");
      }
      if (text == "$$" || text == "$I" || text == "$G" || text == "$#" || text == "$N") {
        return Send("ok\r\n");
      }
      return Error(3);
    }
    if (state == EmuState::kAlarm) return Error(9);
    // G-code: letter + number words (spaces already removed).
    std::vector<int> g_codes;
    std::optional<double> x, f;
    std::size_t i = 0;
    while (i < text.size()) {
      const char letter = text[i++];
      if (letter < 'A' || letter > 'Z') return Error(1);
      const char* begin = text.c_str() + i;
      char* end = nullptr;
      const double value = std::strtod(begin, &end);
      if (end == begin) return Error(2);
      i += static_cast<std::size_t>(end - begin);
      switch (letter) {
        case 'G':
          if (value != std::floor(value)) return Error(20);
          g_codes.push_back(static_cast<int>(value));
          break;
        case 'X':
          if (x) return Error(25);
          x = value;
          break;
        case 'F':
          if (f) return Error(25);
          if (value <= 0) return Error(4);
          f = value;
          break;
        default:
          return Error(20);
      }
    }
    bool g92 = false;
    int motion = -1;
    for (int g : g_codes) {
      if (g == 0 || g == 1) {
        if (motion >= 0) return Error(21);
        motion = g;
      } else if (g == 90 || g == 91 || g == 92) {
        g92 = g92 || g == 92;
      } else {
        return Error(20);
      }
    }
    if (g92 && motion >= 0) return Error(21);
    if (g92 && !x) return Error(26);
    if (motion == 1 && !f && !feed) return Error(22);
    // Valid: apply.
    for (int g : g_codes) {
      if (g == 90) absolute = true;
      if (g == 91) absolute = false;
    }
    if (f) feed = f;
    if (motion >= 0) motion_mode = motion;
    if (g92) {
      wco_deg = PlannedEnd() - *x;
    } else if (x) {
      if (motion_mode == 1 && !feed) return Error(22);
      const double target = absolute ? *x + wco_deg : PlannedEnd() + *x;
      Move move{target, motion_mode == 0 ? options.rapid_deg_per_min : *feed};
      if (state == EmuState::kRun || state == EmuState::kHold) {
        queue.push_back(move);
      } else {
        StartMove(move, now);
      }
    }
    Send("ok\r\n");
  }

  void OnByte(char c, Clock::time_point now) {
    if (silent) return;
    if (c == '?') return StatusReport(now);
    if (c == 0x18) return SoftReset(now);
    if (c == '!') return FeedHold(now);
    if (c == '~') return CycleStart(now);
    if (c == '\n' || c == '\r') {
      if (line.empty() && c == '\r') return;  // CR LF: one line
      ++lines;
      if (line_overflow) {
        Error(11);
      } else {
        ExecuteLine(line, now);
      }
      line.clear();
      line_overflow = false;
      return;
    }
    if (c == ' ') return;
    if (line.size() >= 80) {
      line_overflow = true;
      return;
    }
    line.push_back(c >= 'a' && c <= 'z' ? static_cast<char>(c - 'a' + 'A') : c);
  }

  // ---- the thread ----
  void Run() {
    char buf[512];
    while (!stop.load()) {
      pollfd pfd{master, POLLIN, 0};
      int r = ::poll(&pfd, 1, 2);
      const auto now = Clock::now();
      std::lock_guard lock(mu);
      if (r > 0 && (pfd.revents & POLLIN)) {
        ssize_t n = ::read(master, buf, sizeof(buf));
        for (ssize_t k = 0; k < n; ++k) OnByte(buf[k], now);
      }
      Advance(Clock::now());
    }
  }
};

TurntableEmulator::TurntableEmulator(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}

TurntableEmulator::~TurntableEmulator() { Stop(); }

std::unique_ptr<TurntableEmulator> TurntableEmulator::Start(const EmulatorOptions& options,
                                                            std::string* error) {
  auto impl = std::make_unique<Impl>();
  impl->options = options;
  if (::openpty(&impl->master, &impl->slave, nullptr, nullptr, nullptr) != 0) {
    *error = std::string("openpty failed: ") + std::strerror(errno);
    return nullptr;
  }
  // Raw mode before anything is written: no echo, no CR/LF translation.
  termios tio{};
  ::tcgetattr(impl->slave, &tio);
  ::cfmakeraw(&tio);
  ::tcsetattr(impl->slave, TCSANOW, &tio);
  ::fcntl(impl->master, F_SETFL, ::fcntl(impl->master, F_GETFL) | O_NONBLOCK);
  ::fcntl(impl->master, F_SETFD, FD_CLOEXEC);
  ::fcntl(impl->slave, F_SETFD, FD_CLOEXEC);
  const char* name = ::ttyname(impl->slave);
  impl->slave_path = name ? name : "";
  if (impl->slave_path.empty()) {
    *error = "ttyname failed for the PTY slave";
    ::close(impl->master);
    ::close(impl->slave);
    return nullptr;
  }
  if (!options.link_path.empty()) {
    const std::string tmp = options.link_path + ".tmp" + std::to_string(::getpid());
    ::unlink(tmp.c_str());
    if (::symlink(impl->slave_path.c_str(), tmp.c_str()) != 0 ||
        ::rename(tmp.c_str(), options.link_path.c_str()) != 0) {
      *error = "cannot link " + options.link_path + " to " + impl->slave_path + ": " +
               std::strerror(errno);
      ::close(impl->master);
      ::close(impl->slave);
      return nullptr;
    }
  }
  impl->pos_deg = options.start_position_deg;
  impl->state = options.start_in_alarm ? EmuState::kAlarm : EmuState::kIdle;
  if (options.banner_on_start) {
    impl->Send("\r\nGrbl " + options.version + " ['$' for help]\r\n");
    if (options.start_in_alarm) impl->Send("[MSG:'$H'|'$X' to unlock]\r\n");
  }
  Impl* raw = impl.get();
  impl->thread = std::thread([raw] { raw->Run(); });
  return std::unique_ptr<TurntableEmulator>(new TurntableEmulator(std::move(impl)));
}

const std::string& TurntableEmulator::slave_path() const { return impl_->slave_path; }

void TurntableEmulator::Stop() {
  impl_->stop = true;
  if (impl_->thread.joinable()) impl_->thread.join();
  std::lock_guard lock(impl_->mu);
  if (impl_->master >= 0) ::close(impl_->master);
  if (impl_->slave >= 0) ::close(impl_->slave);
  impl_->master = impl_->slave = -1;
}

void TurntableEmulator::InjectGarbage(const std::string& bytes) {
  std::lock_guard lock(impl_->mu);
  impl_->SendAlways(bytes);
}

void TurntableEmulator::SetSilent(bool silent) {
  std::lock_guard lock(impl_->mu);
  impl_->silent = silent;
}

void TurntableEmulator::RaiseAlarm(int code) {
  std::lock_guard lock(impl_->mu);
  impl_->Halt(Clock::now());
  impl_->state = EmuState::kAlarm;
  impl_->Send("ALARM:" + std::to_string(code) + "\r\n");
}

void TurntableEmulator::SetPositionOffset(double offset_deg) {
  std::lock_guard lock(impl_->mu);
  impl_->offset_deg = offset_deg;
}

void TurntableEmulator::HangUp() {
  impl_->hung_up = true;
  Stop();
}

double TurntableEmulator::machine_position_deg() {
  std::lock_guard lock(impl_->mu);
  return impl_->Position(Clock::now());
}

std::string TurntableEmulator::state() {
  std::lock_guard lock(impl_->mu);
  return Name(impl_->state);
}

int TurntableEmulator::lines_received() {
  std::lock_guard lock(impl_->mu);
  return impl_->lines;
}

int TurntableEmulator::resets_received() {
  std::lock_guard lock(impl_->mu);
  return impl_->resets;
}

bool TurntableEmulator::hung_up() { return impl_->hung_up.load(); }

}  // namespace craftscan::testing
