#include "craftscan/drivers/serial_turntable/grbl_turntable.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <utility>

namespace craftscan::serial_turntable {
namespace {

constexpr char kSoftReset = 0x18;
constexpr auto kReadSlice = std::chrono::milliseconds(20);  // abort latency bound
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

std::string Fixed(double value, int decimals) {
  char buf[64];
  std::snprintf(buf, sizeof(buf), "%.*f", decimals, value);
  return buf;
}

std::string Ms(std::chrono::milliseconds ms) { return std::to_string(ms.count()) + " ms"; }

// The first ALARM:N among replies[from..]: lines that came in the same read
// as the reply a wait was for. The controller raised it after that reply;
// dropping it would leave only "Alarm state" without the reason.
const GrblReply* AlarmAmong(const std::vector<GrblReply>& replies, std::size_t from) {
  for (std::size_t i = from; i < replies.size(); ++i) {
    if (replies[i].kind == GrblReplyKind::kAlarm) return &replies[i];
  }
  return nullptr;
}

std::string AlarmText(const GrblReply& alarm) {
  return "ALARM:" + std::to_string(alarm.code) + " (" + std::string(GrblAlarmMessage(alarm.code)) +
         ")";
}

}  // namespace

std::string_view ToString(GrblTurntable::State state) {
  switch (state) {
    case GrblTurntable::State::kClosed:
      return "Closed";
    case GrblTurntable::State::kUnhomed:
      return "Unhomed";
    case GrblTurntable::State::kReady:
      return "Ready";
    case GrblTurntable::State::kMoving:
      return "Moving";
    case GrblTurntable::State::kFault:
      return "Fault";
    case GrblTurntable::State::kDeviceLost:
      return "DeviceLost";
  }
  return "Unknown";
}

bool GrblTurntableOptions::IsValid(std::string* why) const {
  auto fail = [why](std::string text) {
    if (why) *why = std::move(text);
    return false;
  };
  if (port_path.empty()) return fail("port_path is empty");
  if (!(feed_deg_per_min > 0) || !std::isfinite(feed_deg_per_min)) {
    return fail("feed_deg_per_min must be > 0");
  }
  if (!(position_tolerance_deg > 0)) return fail("position_tolerance_deg must be > 0");
  if (banner_timeout.count() <= 0 || command_timeout.count() <= 0 || homing_timeout.count() <= 0) {
    return fail("banner, command and homing timeouts must be > 0");
  }
  if (!(move_timeout_factor >= 1)) return fail("move_timeout_factor must be >= 1");
  if (move_timeout_margin.count() < 0 || settle_time.count() < 0) {
    return fail("move_timeout_margin and settle_time must be >= 0");
  }
  if (status_poll_interval.count() <= 0) return fail("status_poll_interval must be > 0");
  if (timeouts_until_lost < 1) return fail("timeouts_until_lost must be >= 1");
  if (hold_timeout.count() <= 0) return fail("hold_timeout must be > 0");
  return true;
}

GrblTurntable::GrblTurntable(GrblTurntableOptions options)
    : options_(std::move(options)), angle_deg_(kNaN) {}

GrblTurntable::~GrblTurntable() { Close(); }

double GrblTurntable::angle_deg() const {
  return state_.load() == State::kReady ? angle_deg_.load() : kNaN;
}

Status GrblTurntable::WrongState(std::string_view call) const {
  return {StatusCode::kWrongState, std::string(call) + " not allowed in state " +
                                       std::string(ToString(state_.load())) + " (" +
                                       options_.port_path + ")"};
}

std::string GrblTurntable::UnknownSummary() const {
  if (unknown_lines_ == 0) return "";
  return " (" + std::to_string(unknown_lines_) + " unrecognized line(s) received, last: '" +
         last_unknown_ + "')";
}

bool GrblTurntable::SetStateUnlessAborted(State state) {
  std::lock_guard lock(write_mutex_);
  if (abort_requested_.load()) return false;
  state_ = state;
  return true;
}

Status GrblTurntable::Fail(Status status, bool silence) {
  std::lock_guard lock(write_mutex_);
  if (status.code == StatusCode::kTimeout && silence) {
    if (++consecutive_timeouts_ >= options_.timeouts_until_lost) {
      status.code = StatusCode::kDeviceLost;
      status.message += "; " + std::to_string(consecutive_timeouts_) +
                        " timeout(s) in a row: device considered lost";
    }
  }
  if (status.code == StatusCode::kAborted || abort_requested_.load()) {
    status.code = StatusCode::kAborted;
    state_ = State::kUnhomed;  // Abort() reset the controller: position is not trusted
  } else if (status.code == StatusCode::kDeviceLost) {
    state_ = State::kDeviceLost;
  } else {
    state_ = State::kFault;
  }
  angle_deg_ = kNaN;
  last_error_ = status;
  return status;
}

void GrblTurntable::StopWithReset() {
  {
    std::lock_guard lock(write_mutex_);
    reset_pending_ = true;  // ReadReplies() consumes the answer (ALARM:3/6 and the banner)
    if (!port_.Write(std::string_view(&kSoftReset, 1), options_.command_timeout).ok()) return;
  }
  // Wait (bounded) for the banner, so the controller has stopped on return.
  const bool aborted = abort_requested_.exchange(false);
  const auto deadline = Clock::now() + options_.banner_timeout;
  std::vector<GrblReply> ignored;
  while (reset_pending_.load()) {
    ignored.clear();
    const Status s = ReadReplies(deadline, &ignored);
    if (!s.ok()) break;  // a later call's BeginCall() waits for the rest
  }
  if (aborted) abort_requested_ = true;
}

Status GrblTurntable::Write(std::string_view bytes) {
  std::lock_guard lock(write_mutex_);
  Status s = port_.Write(bytes, options_.command_timeout);
  if (s.code == StatusCode::kTimeout) s.message += " (output blocked)";
  return s;
}

Status GrblTurntable::ReadReplies(Clock::time_point deadline, std::vector<GrblReply>* replies) {
  std::vector<GrblReply> parsed;
  bool reset_consumed = false;
  for (;;) {
    if (abort_requested_.load()) return {StatusCode::kAborted, "aborted"};
    auto now = Clock::now();
    auto left = std::chrono::duration_cast<std::chrono::milliseconds>(deadline - now);
    auto slice = std::clamp(left, std::chrono::milliseconds(0), kReadSlice);
    std::string bytes;
    Status s = port_.Read(&bytes, slice);
    if (s.code == StatusCode::kDeviceLost || s.code == StatusCode::kIoError) {
      s.code = StatusCode::kDeviceLost;
      return s;
    }
    if (s.ok()) {
      parsed.clear();
      parser_.Feed(bytes, &parsed);
      for (GrblReply& reply : parsed) {
        if (reset_pending_.load() &&
            (reply.kind == GrblReplyKind::kBanner ||
             (reply.kind == GrblReplyKind::kAlarm && (reply.code == 3 || reply.code == 6)))) {
          // The answer to Abort()'s soft reset ("ALARM:3" if it was moving, then
          // the banner), not a reply to anything the driving thread sent.
          if (reply.kind == GrblReplyKind::kBanner) {
            reset_pending_ = false;
            reset_consumed = true;
          }
          continue;
        }
        if (reply.kind == GrblReplyKind::kUnknown || reply.kind == GrblReplyKind::kOverlong) {
          ++unknown_lines_;
          last_unknown_ = reply.line.substr(0, 40);
          if (reply.kind == GrblReplyKind::kOverlong) last_unknown_ += "... (overlong line)";
        } else {
          replies->push_back(std::move(reply));
        }
      }
      if (abort_requested_.load()) return {StatusCode::kAborted, "aborted"};
      if (!replies->empty() || reset_consumed) return Status::Ok();
    }
    if (Clock::now() >= deadline) return {StatusCode::kTimeout, "timeout"};
  }
}

Status GrblTurntable::WaitForBanner(std::chrono::milliseconds timeout) {
  const auto deadline = Clock::now() + timeout;
  std::vector<GrblReply> replies;
  for (;;) {
    replies.clear();
    Status s = ReadReplies(deadline, &replies);
    if (!s.ok()) return s;
    for (const GrblReply& reply : replies) {
      if (reply.kind == GrblReplyKind::kBanner) {
        version_ = reply.version;
        return Status::Ok();
      }
    }
  }
}

Status GrblTurntable::OpenAndGreet() {
  {
    std::lock_guard lock(write_mutex_);
    Status s = port_.Open(options_.port_path, options_.baud);
    if (!s.ok()) return s;
  }
  parser_.Reset();
  unknown_lines_ = 0;
  last_unknown_.clear();
  consecutive_timeouts_ = 0;
  reset_pending_ = false;
  version_.clear();
  Status s = WaitForBanner(options_.banner_timeout);
  if (s.code == StatusCode::kTimeout) {
    // No banner: the controller was already running (no reset on open). Reset it.
    s = Write(std::string_view(&kSoftReset, 1));
    if (s.ok()) s = WaitForBanner(options_.banner_timeout);
    if (s.code == StatusCode::kTimeout) {
      s.message = "no Grbl banner from " + options_.port_path + " within " +
                  Ms(options_.banner_timeout) + ", nor after a soft reset (0x18)" +
                  UnknownSummary();
    }
  }
  if (!s.ok()) return s;
  if (version_.rfind("1.1", 0) != 0) {
    return {StatusCode::kProtocolError, "unsupported firmware 'Grbl " + version_ + "' on " +
                                            options_.port_path + ": need Grbl 1.1"};
  }
  return Status::Ok();
}

Status GrblTurntable::BeginCall() {
  abort_requested_ = false;
  hold_requested_ = false;
  if (reset_pending_.load()) {
    // Abort() reset the controller: wait until ReadReplies() has consumed the
    // banner, so it is not taken as a reply to the next command.
    const auto deadline = Clock::now() + options_.banner_timeout;
    std::vector<GrblReply> ignored;
    while (reset_pending_.load()) {
      ignored.clear();
      Status s = ReadReplies(deadline, &ignored);
      if (s.code == StatusCode::kTimeout && reset_pending_.load()) {
        reset_pending_ = false;
        return {StatusCode::kTimeout, "no Grbl banner from " + options_.port_path + " within " +
                                          Ms(options_.banner_timeout) +
                                          " after the abort's soft reset" + UnknownSummary()};
      }
      if (!s.ok() && s.code != StatusCode::kTimeout) return s;
    }
  }
  // Anything left over (late status reports, "[MSG:...]") is stale.
  std::vector<GrblReply> stale;
  Status s = ReadReplies(Clock::now(), &stale);
  while (s.ok()) {
    stale.clear();
    s = ReadReplies(Clock::now(), &stale);
  }
  return s.code == StatusCode::kTimeout ? Status::Ok() : s;
}

Status GrblTurntable::Command(const std::string& line, std::chrono::milliseconds timeout) {
  const std::string where = "'" + line + "' on " + options_.port_path;
  Status s = Write(line + "\n");
  if (!s.ok()) return s;
  const auto deadline = Clock::now() + timeout;
  std::vector<GrblReply> replies;
  for (;;) {
    replies.clear();
    s = ReadReplies(deadline, &replies);
    if (s.code == StatusCode::kTimeout) {
      return {StatusCode::kTimeout,
              "no reply to " + where + " within " + Ms(timeout) + UnknownSummary()};
    }
    if (!s.ok()) return s;
    for (std::size_t i = 0; i < replies.size(); ++i) {
      const GrblReply& reply = replies[i];
      switch (reply.kind) {
        case GrblReplyKind::kOk:
          consecutive_timeouts_ = 0;
          if (const GrblReply* alarm = AlarmAmong(replies, i + 1)) {
            return {StatusCode::kAlarm, AlarmText(*alarm) + " right after the ok to " + where};
          }
          return Status::Ok();
        case GrblReplyKind::kError:
          return {StatusCode::kDeviceError, "error:" + std::to_string(reply.code) + " (" +
                                                std::string(GrblErrorMessage(reply.code)) +
                                                ") in reply to " + where};
        case GrblReplyKind::kAlarm:
          return {StatusCode::kAlarm, AlarmText(reply) + " while waiting for " + where};
        case GrblReplyKind::kBanner:
          return {StatusCode::kProtocolError,
                  "controller reset unexpectedly while waiting for " + where};
        default:
          break;  // status reports and [MSG:] feedback are not replies to a line
      }
    }
  }
}

Status GrblTurntable::QueryStatus(std::chrono::milliseconds timeout, GrblStatusReport* report) {
  Status s = Write("?");
  if (!s.ok()) return s;
  const auto deadline = Clock::now() + timeout;
  std::vector<GrblReply> replies;
  for (;;) {
    replies.clear();
    s = ReadReplies(deadline, &replies);
    if (s.code == StatusCode::kTimeout) {
      return {StatusCode::kTimeout, "no status report from " + options_.port_path + " within " +
                                        Ms(timeout) + UnknownSummary()};
    }
    if (!s.ok()) return s;
    for (std::size_t i = 0; i < replies.size(); ++i) {
      const GrblReply& reply = replies[i];
      if (reply.kind == GrblReplyKind::kAlarm) {
        return {StatusCode::kAlarm, AlarmText(reply) + " on " + options_.port_path};
      }
      if (reply.kind == GrblReplyKind::kError) {
        return {StatusCode::kDeviceError, "unexpected error:" + std::to_string(reply.code) + " (" +
                                              std::string(GrblErrorMessage(reply.code)) + ") on " +
                                              options_.port_path};
      }
      if (reply.kind == GrblReplyKind::kBanner) {
        return {StatusCode::kProtocolError,
                "controller reset unexpectedly on " + options_.port_path};
      }
      if (reply.kind == GrblReplyKind::kStatus) {
        if (!reply.status.x) {
          return {StatusCode::kProtocolError, "status report without a position: '" + reply.line +
                                                  "' on " + options_.port_path};
        }
        consecutive_timeouts_ = 0;
        if (const GrblReply* alarm = AlarmAmong(replies, i + 1)) {
          return {StatusCode::kAlarm, AlarmText(*alarm) + " on " + options_.port_path};
        }
        *report = reply.status;
        return Status::Ok();
      }
    }
  }
}

Status GrblTurntable::Connect() {
  std::lock_guard call(command_mutex_);
  if (state_ != State::kClosed) return WrongState("Connect()");
  std::string why;
  if (!options_.IsValid(&why)) return {StatusCode::kInvalidArgument, "invalid options: " + why};
  abort_requested_ = false;
  Status s = OpenAndGreet();
  if (!s.ok()) {
    std::lock_guard lock(write_mutex_);
    port_.Close();
    last_error_ = s;
    return s;
  }
  state_ = State::kUnhomed;
  return s;
}

Status GrblTurntable::Reconnect(const std::string& path) {
  std::lock_guard call(command_mutex_);
  if (state_ == State::kClosed) return WrongState("Reconnect()");
  if (!path.empty()) options_.port_path = path;
  abort_requested_ = false;
  {
    std::lock_guard lock(write_mutex_);
    port_.Close();
    state_ = State::kDeviceLost;
    angle_deg_ = kNaN;
  }
  Status s = OpenAndGreet();
  if (!s.ok()) {
    std::lock_guard lock(write_mutex_);
    port_.Close();
    last_error_ = s;
    return s;
  }
  if (!SetStateUnlessAborted(State::kUnhomed)) return Fail({StatusCode::kAborted, "aborted"});
  return s;
}

void GrblTurntable::Close() {
  std::lock_guard call(command_mutex_);
  std::lock_guard lock(write_mutex_);
  port_.Close();
  state_ = State::kClosed;
  angle_deg_ = kNaN;
}

Status GrblTurntable::Home(std::chrono::milliseconds timeout) {
  std::lock_guard call(command_mutex_);
  const bool bounded = timeout.count() > 0;
  const auto call_deadline = Clock::now() + timeout;
  bool cut = false;  // the last wait was shortened by the call's timeout
  // A configured wait, cut to what is left of the call's timeout.
  const auto limit = [&](std::chrono::milliseconds configured) {
    cut = false;
    if (!bounded) return configured;
    const auto left =
        std::chrono::duration_cast<std::chrono::milliseconds>(call_deadline - Clock::now());
    const auto wait = std::clamp(left, std::chrono::milliseconds(1), configured);
    cut = wait < configured;
    return wait;
  };
  const State from = state_;
  if (from != State::kUnhomed && from != State::kReady && from != State::kFault) {
    return WrongState("Home()");
  }
  Status s = BeginCall();
  if (s.ok() && from == State::kFault) {
    // Whatever went wrong (a half-done move, a stuck command), start from a reset.
    s = Write(std::string_view(&kSoftReset, 1));
    if (s.ok()) s = WaitForBanner(options_.banner_timeout);
    if (s.code == StatusCode::kTimeout) {
      s.message = "no Grbl banner from " + options_.port_path + " within " +
                  Ms(options_.banner_timeout) + " after a soft reset (0x18)";
    }
  }
  if (s.ok()) {
    std::lock_guard lock(write_mutex_);
    if (!abort_requested_) state_ = State::kUnhomed;
    angle_deg_ = kNaN;
  }
  if (s.ok() && options_.homing_enabled) {
    s = Command("$H", limit(options_.homing_timeout));
  } else if (s.ok()) {
    s = Command("$X", limit(options_.command_timeout));
    if (s.ok()) s = Command("G92 X0", limit(options_.command_timeout));
  }
  GrblStatusReport report;
  if (s.ok()) s = QueryStatus(limit(options_.command_timeout), &report);
  if (s.ok() && report.state != GrblState::kIdle) {
    s = {report.state == GrblState::kAlarm ? StatusCode::kAlarm : StatusCode::kProtocolError,
         "controller reports '" + report.state_text + "' instead of Idle after homing on " +
             options_.port_path};
  }
  if (s.code == StatusCode::kTimeout && cut) {
    // The caller's limit, not a silent controller: stop the homing cycle.
    s.message += " (Home()'s timeout of " + Ms(timeout) + " expired; homing stopped)";
    StopWithReset();
    return Fail(std::move(s), /*silence=*/false);
  }
  if (!s.ok()) return Fail(std::move(s));
  origin_x_ = report.x_is_work ? 0.0 : *report.x;
  angle_deg_ = 0.0;
  if (!SetStateUnlessAborted(State::kReady)) return Fail({StatusCode::kAborted, "aborted"});
  return Status::Ok();
}

Status GrblTurntable::MoveTo(double angle_deg, std::chrono::milliseconds timeout) {
  std::lock_guard call(command_mutex_);
  if (state_ != State::kReady) return WrongState("MoveTo()");
  if (!std::isfinite(angle_deg) || std::abs(angle_deg) > 1e6) {
    return {StatusCode::kInvalidArgument,
            "MoveTo(): angle " + Fixed(angle_deg, 3) + " deg is not a finite angle"};
  }
  Status s = BeginCall();
  if (!s.ok()) return Fail(std::move(s));
  const double from_deg = angle_deg_.load();
  if (!SetStateUnlessAborted(State::kMoving)) return Fail({StatusCode::kAborted, "aborted"});
  angle_deg_ = kNaN;

  const std::string target = Fixed(angle_deg, 3);
  const auto start = Clock::now();
  const double nominal_s = std::abs(angle_deg - from_deg) / options_.feed_deg_per_min * 60.0;
  auto limit = std::chrono::duration_cast<std::chrono::milliseconds>(
                   std::chrono::duration<double>(nominal_s * options_.move_timeout_factor)) +
               options_.move_timeout_margin;
  const bool call_bound = timeout.count() > 0 && timeout < limit;
  if (call_bound) limit = timeout;
  const auto deadline = start + limit;
  bool move_expired = false;

  s = Command("G90 G1 X" + target + " F" + Fixed(options_.feed_deg_per_min, 1),
              call_bound ? std::min(limit, options_.command_timeout) : options_.command_timeout);
  GrblStatusReport report;
  while (s.ok()) {
    s = QueryStatus(options_.command_timeout, &report);
    if (!s.ok()) break;
    if (report.state == GrblState::kIdle) break;
    if (report.state == GrblState::kAlarm) {
      s = {StatusCode::kAlarm, "controller entered the Alarm state during the move to " + target +
                                   " deg on " + options_.port_path};
      break;
    }
    if (Clock::now() >= deadline) {
      const double reported = report.x_is_work ? *report.x : *report.x - origin_x_;
      s = {StatusCode::kTimeout,
           "move to " + target + " deg did not finish within " + Ms(limit) +
               (call_bound ? " (MoveTo()'s timeout)" : "") + " (last state '" + report.state_text +
               "' at " + Fixed(reported, 3) + " deg) on " + options_.port_path + "; stopped"};
      move_expired = true;  // the controller is alive; this is not a silence timeout
      break;
    }
    // Wait one poll interval, watching for asynchronous ALARM:N lines.
    std::vector<GrblReply> replies;
    Status w = ReadReplies(Clock::now() + options_.status_poll_interval, &replies);
    while (w.ok()) {
      for (const GrblReply& reply : replies) {
        if (reply.kind == GrblReplyKind::kAlarm) {
          w = {StatusCode::kAlarm, AlarmText(reply) + " during the move to " + target + " deg on " +
                                       options_.port_path};
          break;
        }
      }
      if (!w.ok()) break;
      replies.clear();
      w = ReadReplies(Clock::now() + options_.status_poll_interval, &replies);
    }
    if (w.code != StatusCode::kTimeout) s = std::move(w);
  }
  if (s.ok()) {
    const double reported = report.x_is_work ? *report.x : *report.x - origin_x_;
    if (std::abs(reported - angle_deg) > options_.position_tolerance_deg) {
      s = {StatusCode::kPositionMismatch,
           "position mismatch: commanded " + target + " deg, reported " + Fixed(reported, 3) +
               " deg (tolerance " + Fixed(options_.position_tolerance_deg, 3) + " deg) on " +
               options_.port_path};
    }
  }
  if (s.ok() && options_.settle_time.count() > 0) {
    std::vector<GrblReply> replies;
    const auto settle_end = Clock::now() + options_.settle_time;
    Status w;
    do {
      replies.clear();
      w = ReadReplies(settle_end, &replies);
      for (const GrblReply& reply : replies) {
        if (reply.kind == GrblReplyKind::kAlarm) {
          w = {StatusCode::kAlarm,
               AlarmText(reply) + " while settling at " + target + " deg on " + options_.port_path};
        }
      }
    } while (w.ok());
    if (w.code != StatusCode::kTimeout) s = std::move(w);
  }
  if ((s.code == StatusCode::kAborted || abort_requested_.load()) && hold_requested_.load()) {
    hold_requested_ = false;
    double stopped = 0;
    const Status held = CompleteHold(target, &stopped);
    if (held.ok()) {
      const Status aborted{StatusCode::kAborted, "move to " + target + " deg aborted at " +
                                                     Fixed(stopped, 3) + " deg (feed hold) on " +
                                                     options_.port_path};
      std::lock_guard lock(write_mutex_);
      abort_requested_ = false;
      angle_deg_ = stopped;
      state_ = State::kReady;
      last_error_ = aborted;
      return aborted;
    }
    // The hold failed: halt with a reset; the position is lost.
    StopWithReset();
    abort_requested_ = true;
    return Fail({StatusCode::kAborted, "move to " + target + " deg aborted on " +
                                           options_.port_path + "; the feed hold failed (" +
                                           held.message + "): home again"});
  }
  if (s.code == StatusCode::kAborted || abort_requested_.load()) {
    s = {StatusCode::kAborted, "move to " + target + " deg aborted on " + options_.port_path};
  }
  if (move_expired) {
    StopWithReset();
    return Fail(std::move(s), /*silence=*/false);
  }
  if (!s.ok()) return Fail(std::move(s));
  angle_deg_ = angle_deg;
  if (!SetStateUnlessAborted(State::kReady)) {
    return Fail(
        {StatusCode::kAborted, "move to " + target + " deg aborted on " + options_.port_path});
  }
  return Status::Ok();
}

Status GrblTurntable::CompleteHold(const std::string& target, double* stopped_deg) {
  const std::string where = " on " + options_.port_path;
  const auto deadline = Clock::now() + options_.hold_timeout;
  GrblStatusReport report;
  std::vector<GrblReply> ignored;
  for (;;) {
    if (Clock::now() >= deadline) {
      return {StatusCode::kTimeout, "the feed hold did not complete within " +
                                        Ms(options_.hold_timeout) + " (last state '" +
                                        report.state_text + "')" + where};
    }
    abort_requested_ = false;  // reads work again; a repeated Abort() only re-sends '!'
    Status s = QueryStatus(options_.command_timeout, &report);
    if (s.code == StatusCode::kAborted) continue;
    if (!s.ok()) return s;
    if (report.state == GrblState::kIdle) break;  // the move ended before the hold took
    if (report.state == GrblState::kHold && report.state_text == "Hold:0") break;
    if (report.state == GrblState::kAlarm) {
      return {StatusCode::kAlarm, "controller entered the Alarm state while holding the move to " +
                                      target + " deg" + where};
    }
    if (report.state == GrblState::kRun || report.state == GrblState::kJog) {
      s = Write("!");  // the hold came before the move had started
      if (!s.ok()) return s;
    }
    ignored.clear();
    s = ReadReplies(std::min(deadline, Clock::now() + options_.status_poll_interval), &ignored);
    if (s.code == StatusCode::kDeviceLost || s.code == StatusCode::kIoError) return s;
  }
  const double stopped = report.x_is_work ? *report.x : *report.x - origin_x_;
  // Flush the rest of the move: a reset after Hold:0 keeps the position.
  Status s;
  {
    std::lock_guard lock(write_mutex_);
    reset_pending_ = true;
    s = port_.Write(std::string_view(&kSoftReset, 1), options_.command_timeout);
  }
  if (!s.ok()) return s;
  const auto banner_deadline = Clock::now() + options_.banner_timeout;
  while (reset_pending_.load()) {
    ignored.clear();
    s = ReadReplies(banner_deadline, &ignored);
    if (s.code == StatusCode::kAborted) {
      abort_requested_ = false;
      continue;
    }
    if (s.code == StatusCode::kTimeout) {
      reset_pending_ = false;
      return {StatusCode::kTimeout, "no Grbl banner within " + Ms(options_.banner_timeout) +
                                        " after the feed hold's soft reset" + where};
    }
    if (!s.ok()) return s;
  }
  s = QueryStatus(options_.command_timeout, &report);
  if (!s.ok()) return s;
  if (report.state != GrblState::kIdle) {
    return {StatusCode::kAlarm, "controller reports '" + report.state_text +
                                    "' after the feed hold's soft reset" + where};
  }
  // The reset may clear the G92 work offset: make the stop angle current again.
  s = Command("G92 X" + Fixed(stopped, 3), options_.command_timeout);
  if (!s.ok()) return s;
  *stopped_deg = stopped;
  return Status::Ok();
}

Status GrblTurntable::Abort() {
  std::lock_guard lock(write_mutex_);
  const State s = state_;
  if (s == State::kClosed || s == State::kDeviceLost) return WrongState("Abort()");
  if (options_.abort_mode == GrblTurntableOptions::AbortMode::kFeedHold && s == State::kMoving) {
    // MoveTo() completes the stop (CompleteHold) and keeps the position.
    hold_requested_ = true;
    abort_requested_ = true;
    return port_.Write("!", options_.command_timeout);
  }
  abort_requested_ = true;
  reset_pending_ = true;
  Status w = port_.Write(std::string_view(&kSoftReset, 1), options_.command_timeout);
  angle_deg_ = kNaN;
  if (w.code == StatusCode::kDeviceLost) {
    state_ = State::kDeviceLost;
    return w;
  }
  state_ = State::kUnhomed;
  return w;
}

}  // namespace craftscan::serial_turntable
