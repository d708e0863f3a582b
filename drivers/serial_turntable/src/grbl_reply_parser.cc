#include "craftscan/drivers/serial_turntable/grbl_reply_parser.h"

#include <charconv>
#include <cmath>
#include <cstdlib>

namespace craftscan::serial_turntable {
namespace {

bool StartsWith(std::string_view s, std::string_view prefix) {
  return s.substr(0, prefix.size()) == prefix;
}

// Parses a whole decimal integer; false on anything else.
bool ParseInt(std::string_view s, int* value) {
  if (s.empty()) return false;
  auto [ptr, ec] = std::from_chars(s.data(), s.data() + s.size(), *value);
  return ec == std::errc() && ptr == s.data() + s.size();
}

// Parses a decimal number (GRBL prints "%.3f"); false on anything else,
// including the "nan" and "inf" from_chars accepts: a NaN position would
// make every later position check pass (found by tests/fuzz).
bool ParseDouble(std::string_view s, double* value) {
  if (s.empty() || s.size() > 64) return false;
  auto [ptr, ec] = std::from_chars(s.data(), s.data() + s.size(), *value);
  return ec == std::errc() && ptr == s.data() + s.size() && std::isfinite(*value);
}

std::optional<double> FirstCoordinate(std::string_view list) {
  double x;
  if (!ParseDouble(list.substr(0, list.find(',')), &x)) return std::nullopt;
  return x;
}

GrblState StateFromName(std::string_view name) {
  std::string_view base = name.substr(0, name.find(':'));
  if (base == "Idle") return GrblState::kIdle;
  if (base == "Run") return GrblState::kRun;
  if (base == "Hold") return GrblState::kHold;
  if (base == "Jog") return GrblState::kJog;
  if (base == "Alarm") return GrblState::kAlarm;
  if (base == "Door") return GrblState::kDoor;
  if (base == "Check") return GrblState::kCheck;
  if (base == "Home") return GrblState::kHome;
  if (base == "Sleep") return GrblState::kSleep;
  return GrblState::kUnknown;
}

bool ParseStatus(std::string_view body, GrblStatusReport* report) {
  std::size_t bar = body.find('|');
  report->state_text = std::string(body.substr(0, bar));
  report->state = StateFromName(report->state_text);
  if (report->state == GrblState::kUnknown) return false;
  while (bar != std::string_view::npos) {
    body.remove_prefix(bar + 1);
    bar = body.find('|');
    std::string_view field = body.substr(0, bar);
    if (StartsWith(field, "MPos:")) {
      report->x = FirstCoordinate(field.substr(5));
      report->x_is_work = false;
    } else if (StartsWith(field, "WPos:")) {
      report->x = FirstCoordinate(field.substr(5));
      report->x_is_work = true;
    } else if (StartsWith(field, "WCO:")) {
      report->work_offset_x = FirstCoordinate(field.substr(4));
    }
  }
  return true;
}

}  // namespace

std::string_view ToString(GrblState state) {
  switch (state) {
    case GrblState::kUnknown:
      return "Unknown";
    case GrblState::kIdle:
      return "Idle";
    case GrblState::kRun:
      return "Run";
    case GrblState::kHold:
      return "Hold";
    case GrblState::kJog:
      return "Jog";
    case GrblState::kAlarm:
      return "Alarm";
    case GrblState::kDoor:
      return "Door";
    case GrblState::kCheck:
      return "Check";
    case GrblState::kHome:
      return "Home";
    case GrblState::kSleep:
      return "Sleep";
  }
  return "Unknown";
}

std::string_view ToString(GrblReplyKind kind) {
  switch (kind) {
    case GrblReplyKind::kOk:
      return "ok";
    case GrblReplyKind::kError:
      return "error";
    case GrblReplyKind::kAlarm:
      return "alarm";
    case GrblReplyKind::kBanner:
      return "banner";
    case GrblReplyKind::kStatus:
      return "status";
    case GrblReplyKind::kFeedback:
      return "feedback";
    case GrblReplyKind::kUnknown:
      return "unknown";
    case GrblReplyKind::kOverlong:
      return "overlong";
  }
  return "unknown";
}

std::string_view GrblErrorMessage(int code) {
  switch (code) {
    case 1:
      return "G-code word letter not found";
    case 2:
      return "numeric value format is not valid or missing";
    case 3:
      return "'$' system command not recognized or supported";
    case 4:
      return "negative value for an expected positive value";
    case 5:
      return "homing cycle is not enabled via settings";
    case 6:
      return "minimum step pulse time must be greater than 3 us";
    case 7:
      return "EEPROM read failed, settings restored to defaults";
    case 8:
      return "'$' command cannot be used unless Grbl is idle";
    case 9:
      return "G-code locked out during alarm or jog state";
    case 10:
      return "soft limits cannot be enabled without homing";
    case 11:
      return "max characters per line exceeded, line not executed";
    case 12:
      return "'$' setting value exceeds the maximum step rate";
    case 13:
      return "safety door detected as opened";
    case 14:
      return "build info or startup line exceeds EEPROM line length";
    case 15:
      return "jog target exceeds machine travel";
    case 16:
      return "invalid jog command";
    case 17:
      return "laser mode requires PWM output";
    case 20:
      return "unsupported or invalid G-code command";
    case 21:
      return "more than one G-code command from the same modal group";
    case 22:
      return "feed rate has not yet been set or is undefined";
    case 23:
      return "G-code command requires an integer value";
    case 24:
      return "two G-code commands both require axis words";
    case 25:
      return "repeated G-code word in block";
    case 26:
      return "G-code command requires axis words, none found";
    case 27:
      return "line number out of range";
    case 28:
      return "G-code command is missing a required P or L value";
    case 29:
      return "unsupported work coordinate system";
    case 30:
      return "G53 requires G0 or G1 motion mode";
    case 31:
      return "unused axis words with G80 active";
    case 32:
      return "G2/G3 arc without axis words in the selected plane";
    case 33:
      return "motion command has an invalid target";
    case 34:
      return "G2/G3 arc radius definition error";
    case 35:
      return "G2/G3 arc offset definition missing IJK word";
    case 36:
      return "unused, leftover G-code words in block";
    case 37:
      return "G43.1 offset applied to an axis other than the configured one";
    case 38:
      return "tool number greater than the maximum supported";
    default:
      return "unknown error";
  }
}

std::string_view GrblAlarmMessage(int code) {
  switch (code) {
    case 1:
      return "hard limit triggered; position likely lost, re-homing required";
    case 2:
      return "soft limit: motion target exceeds machine travel";
    case 3:
      return "reset while in motion; position likely lost, re-homing required";
    case 4:
      return "probe fail: probe not in the expected initial state";
    case 5:
      return "probe fail: probe did not contact the workpiece";
    case 6:
      return "homing fail: reset during active homing cycle";
    case 7:
      return "homing fail: safety door opened during homing";
    case 8:
      return "homing fail: could not clear limit switch when pulling off";
    case 9:
      return "homing fail: could not find limit switch";
    case 10:
      return "homing fail: could not find second limit switch";
    default:
      return "unknown alarm";
  }
}

GrblReply ClassifyGrblLine(std::string_view line) {
  GrblReply reply;
  reply.line = std::string(line);
  if (line == "ok") {
    reply.kind = GrblReplyKind::kOk;
  } else if (StartsWith(line, "error:") && ParseInt(line.substr(6), &reply.code)) {
    reply.kind = GrblReplyKind::kError;
  } else if (StartsWith(line, "ALARM:") && ParseInt(line.substr(6), &reply.code)) {
    reply.kind = GrblReplyKind::kAlarm;
  } else if (StartsWith(line, "Grbl ")) {
    std::string_view rest = line.substr(5);
    std::string_view version = rest.substr(0, rest.find(' '));
    if (!version.empty() && version.front() >= '0' && version.front() <= '9') {
      reply.kind = GrblReplyKind::kBanner;
      reply.version = std::string(version);
    }
  } else if (line.size() >= 2 && line.front() == '<' && line.back() == '>') {
    if (ParseStatus(line.substr(1, line.size() - 2), &reply.status)) {
      reply.kind = GrblReplyKind::kStatus;
    }
  } else if (line.size() >= 2 && line.front() == '[' && line.back() == ']') {
    reply.kind = GrblReplyKind::kFeedback;
  }
  if (reply.kind == GrblReplyKind::kUnknown) reply.status = {};
  return reply;
}

GrblReplyParser::GrblReplyParser(std::size_t max_line_length)
    : max_line_length_(max_line_length == 0 ? 1 : max_line_length) {}

void GrblReplyParser::Reset() {
  line_.clear();
  dropped_ = 0;
  overlong_ = false;
}

void GrblReplyParser::EndLine(std::vector<GrblReply>* replies) {
  if (overlong_) {
    GrblReply reply;
    reply.kind = GrblReplyKind::kOverlong;
    reply.line = line_;
    reply.dropped_bytes = dropped_;
    replies->push_back(std::move(reply));
  } else if (!line_.empty()) {
    GrblReply reply = ClassifyGrblLine(line_);
    reply.dropped_bytes = dropped_;
    replies->push_back(std::move(reply));
  }
  // A line of only dropped bytes (line noise) produces nothing.
  Reset();
}

void GrblReplyParser::Feed(std::string_view bytes, std::vector<GrblReply>* replies) {
  for (char c : bytes) {
    const auto u = static_cast<unsigned char>(c);
    if (u == '\r' || u == '\n') {
      EndLine(replies);
    } else if (u < 0x20 || u >= 0x7f) {
      ++dropped_;
    } else if (overlong_) {
      // Discard the rest of an overlong line; keep what was kept for context.
    } else if (line_.size() >= max_line_length_) {
      overlong_ = true;
    } else {
      line_.push_back(c);
    }
  }
}

}  // namespace craftscan::serial_turntable
