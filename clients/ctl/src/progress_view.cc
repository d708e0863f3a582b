#include "progress_view.h"

#include <sys/ioctl.h>
#include <unistd.h>

#include <algorithm>

namespace craftscan::ctl {

bool IsTerminal(std::FILE* stream) { return ::isatty(::fileno(stream)) == 1; }

int TerminalColumns(std::FILE* stream) {
  winsize size{};
  if (::ioctl(::fileno(stream), TIOCGWINSZ, &size) == 0 && size.ws_col >= 20) return size.ws_col;
  return 80;
}

std::string Bar(std::int64_t current, std::int64_t total, int width) {
  const int filled =
      total > 0 ? static_cast<int>(std::clamp<std::int64_t>(current * width / total, 0, width)) : 0;
  std::string bar("[");  // (appends: GCC 12 warns falsely on "literal" + string, PR 105651)
  bar.append(static_cast<std::size_t>(filled), '#');
  bar.append(static_cast<std::size_t>(width - filled), '.');
  return bar.append("]");
}

ProgressView::ProgressView(std::FILE* out, bool live) : out_(out), live_(live) {}

void ProgressView::Update(const std::string& stage, std::int64_t current, std::int64_t total,
                          const std::string& message) {
  if (!live_) {
    std::string count = total > 0 ? std::to_string(current) + "/" + std::to_string(total) : "";
    std::fprintf(out_, "%-10s %s%s%s\n", stage.c_str(), count.c_str(),
                 message.empty() ? "" : (count.empty() ? "" : ": "), message.c_str());
    std::fflush(out_);
    return;
  }
  auto it =
      std::find_if(lines_.begin(), lines_.end(), [&](const Line& l) { return l.stage == stage; });
  if (it == lines_.end()) {
    lines_.push_back({stage, message, current, total});
  } else {
    it->message = message;
    it->current = current;
    it->total = total;
  }
  Redraw();
}

void ProgressView::Redraw() {
  const int columns = TerminalColumns(out_);
  std::string text("\r");
  if (drawn_ > 1) text.append("\x1b[").append(std::to_string(drawn_ - 1)).append("A");
  for (std::size_t i = 0; i < lines_.size(); ++i) {
    const Line& l = lines_[i];
    char count[48];
    std::snprintf(count, sizeof count, "%4lld/%-4lld", static_cast<long long>(l.current),
                  static_cast<long long>(l.total));
    std::string line = l.stage;
    line.resize(std::max<std::size_t>(line.size(), 10), ' ');
    line.append(" ").append(Bar(l.current, l.total, 24)).append(" ");
    line.append(l.total > 0 ? count : "         ").append(" ").append(l.message);
    if (static_cast<int>(line.size()) > columns - 1)
      line.resize(static_cast<std::size_t>(columns - 1));
    text.append("\x1b[2K").append(line);
    if (i + 1 < lines_.size()) text.append("\n");
  }
  std::fputs(text.c_str(), out_);
  std::fflush(out_);
  drawn_ = static_cast<int>(lines_.size());
}

void ProgressView::Finish() {
  if (live_ && drawn_ > 0) {
    std::fputs("\n", out_);
    std::fflush(out_);
  }
  drawn_ = 0;
  lines_.clear();
}

}  // namespace craftscan::ctl
