// Parses what a GRBL 1.1 controller sends: pure, no I/O, safe on any bytes.
//
//   GrblReplyParser parser;
//   std::vector<GrblReply> replies;
//   parser.Feed(bytes_from_port, &replies);  // complete lines only; the rest waits
//
// Lines end with CR or LF (any mix; empty lines are skipped). Bytes outside
// printable ASCII are dropped from a line and counted in
// GrblReply::dropped_bytes, so "\xff\xfeok" still reads as ok. A line longer
// than `max_line_length` bytes becomes one kOverlong reply and the rest of it
// is discarded up to the next line end: memory stays bounded whatever comes.
//
// Reply kinds:
//   ok                              kOk
//   error:N                         kError  (code N; ErrorMessage(N))
//   ALARM:N                         kAlarm  (code N; AlarmMessage(N))
//   Grbl 1.1h ['$' for help]        kBanner (version "1.1h")
//   <Idle|MPos:12.000,0.000,0.000|FS:0,0>
//                                   kStatus (state, x position)
//   [MSG:...], [GC:...], ...        kFeedback (text inside the brackets)
//   anything else                   kUnknown
#pragma once

#include <cstddef>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace craftscan::serial_turntable {

enum class GrblState { kUnknown, kIdle, kRun, kHold, kJog, kAlarm, kDoor, kCheck, kHome, kSleep };
std::string_view ToString(GrblState state);

// A real-time status report, e.g. <Run|MPos:12.000,0.000,0.000|FS:500,0>.
struct GrblStatusReport {
  GrblState state = GrblState::kUnknown;
  std::string state_text;  // as sent, with any sub-state ("Hold:0")
  // X of the machine position (MPos, deg for a turntable), or of the work
  // position when the controller reports WPos ($10=0; then x_is_work = true).
  // Always finite: a non-numeric or non-finite X leaves it empty.
  std::optional<double> x;
  bool x_is_work = false;
  std::optional<double> work_offset_x;  // WCO:x when present (finite)
};

enum class GrblReplyKind { kOk, kError, kAlarm, kBanner, kStatus, kFeedback, kUnknown, kOverlong };
std::string_view ToString(GrblReplyKind kind);

struct GrblReply {
  GrblReplyKind kind = GrblReplyKind::kUnknown;
  std::string line;         // the line without line end and dropped bytes (truncated if overlong)
  int code = 0;             // kError, kAlarm
  std::string version;      // kBanner: "1.1h"
  GrblStatusReport status;  // kStatus
  std::size_t dropped_bytes = 0;  // non-printable bytes removed from this line
};

// Classifies one line (no line end). Never fails: unrecognized lines are kUnknown.
GrblReply ClassifyGrblLine(std::string_view line);

// Human-readable text for GRBL 1.1 error:N and ALARM:N codes; "unknown
// error"/"unknown alarm" for codes GRBL 1.1 does not define.
std::string_view GrblErrorMessage(int code);
std::string_view GrblAlarmMessage(int code);

class GrblReplyParser {
 public:
  static constexpr std::size_t kDefaultMaxLineLength = 256;  // GRBL's own lines are < 100 bytes

  explicit GrblReplyParser(std::size_t max_line_length = kDefaultMaxLineLength);

  // Consumes `bytes`; appends one reply per completed line to `replies`.
  void Feed(std::string_view bytes, std::vector<GrblReply>* replies);
  // Forgets a partial line (e.g. after reopening the port).
  void Reset();
  // Bytes of the current incomplete line held back.
  std::size_t pending_bytes() const { return line_.size(); }

 private:
  void EndLine(std::vector<GrblReply>* replies);

  std::size_t max_line_length_;
  std::string line_;
  std::size_t dropped_ = 0;
  bool overlong_ = false;
};

}  // namespace craftscan::serial_turntable
