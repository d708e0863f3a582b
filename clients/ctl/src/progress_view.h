// How craftscanctl shows a job's progress: on a terminal, one live bar per
// stage (capture, match, register, ...), redrawn in place with ANSI cursor
// moves; otherwise (piped, redirected) one plain line per progress update,
// so logs and scripts see every step.
#pragma once

#include <cstdint>
#include <cstdio>
#include <string>
#include <vector>

namespace craftscan::ctl {

// Whether `stream` is a terminal (isatty).
bool IsTerminal(std::FILE* stream);
// Columns of the terminal behind `stream`, or 80 when unknown.
int TerminalColumns(std::FILE* stream);

// "[########........]" of `width` cells for current/total (all '.' for total
// ≤ 0; clamped to full).
std::string Bar(std::int64_t current, std::int64_t total, int width);

// Not thread-safe: one thread draws.
class ProgressView {
 public:
  // live: bars redrawn in place (a terminal); else plain lines. Writes to `out`.
  ProgressView(std::FILE* out, bool live);

  // A progress update of stage `stage` (current of total; total 0 = unknown).
  void Update(const std::string& stage, std::int64_t current, std::int64_t total,
              const std::string& message);
  // Ends the live display (moves below the bars). Idempotent.
  void Finish();

 private:
  struct Line {
    std::string stage, message;
    std::int64_t current = 0, total = 0;
  };
  void Redraw();

  std::FILE* out_;
  bool live_;
  std::vector<Line> lines_;  // stages in order of first appearance
  int drawn_ = 0;            // lines on screen (live)
};

}  // namespace craftscan::ctl
