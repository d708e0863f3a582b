// Fuzz target: GrblReplyParser (drivers/serial_turntable), the serial
// turntable's reply parser. The first byte picks the line length limit and
// the next how the rest is cut into reads (as a serial port delivers it).
// Properties: memory stays bounded by the limit; replies do not depend on
// how the bytes were cut; each reply is consistent with its kind; positions
// are finite.
#include <cmath>
#include <string_view>
#include <vector>

#include "craftscan/drivers/serial_turntable/grbl_reply_parser.h"
#include "fuzz_target.h"

namespace {

using craftscan::serial_turntable::GrblReply;
using craftscan::serial_turntable::GrblReplyKind;

bool SameReplies(const std::vector<GrblReply>& a, const std::vector<GrblReply>& b) {
  if (a.size() != b.size()) return false;
  for (std::size_t i = 0; i < a.size(); ++i) {
    if (a[i].kind != b[i].kind || a[i].line != b[i].line || a[i].code != b[i].code ||
        a[i].version != b[i].version || a[i].dropped_bytes != b[i].dropped_bytes ||
        a[i].status.state != b[i].status.state || a[i].status.x != b[i].status.x ||
        a[i].status.x_is_work != b[i].status.x_is_work ||
        a[i].status.work_offset_x != b[i].status.work_offset_x) {
      return false;
    }
  }
  return true;
}

}  // namespace

CRAFTSCAN_FUZZ_TARGET(grbl) {
  FuzzInput in(data, size);
  const std::size_t max_line = 1 + in.Small(255);
  const std::size_t chunk = 1 + in.Small(63);
  const std::vector<std::uint8_t> rest = in.Rest();
  const std::string_view bytes(reinterpret_cast<const char*>(rest.data()), rest.size());

  serial_turntable::GrblReplyParser whole(max_line);
  std::vector<GrblReply> at_once;
  whole.Feed(bytes, &at_once);

  serial_turntable::GrblReplyParser pieces(max_line);
  std::vector<GrblReply> in_pieces;
  for (std::size_t pos = 0; pos < bytes.size(); pos += chunk) {
    pieces.Feed(bytes.substr(pos, chunk), &in_pieces);
    CRAFTSCAN_FUZZ_CHECK(pieces.pending_bytes() <= max_line);
  }
  for (const GrblReply& reply : at_once) {
    // Positions are numbers: "MPos:nan" must not become a NaN position.
    CRAFTSCAN_FUZZ_CHECK(!reply.status.x || std::isfinite(*reply.status.x));
    CRAFTSCAN_FUZZ_CHECK(!reply.status.work_offset_x || std::isfinite(*reply.status.work_offset_x));
    CRAFTSCAN_FUZZ_CHECK(reply.line.size() <= max_line);
    for (const char c : reply.line) CRAFTSCAN_FUZZ_CHECK(c >= 0x20 && c < 0x7f);
    CRAFTSCAN_FUZZ_CHECK(!reply.line.empty() || reply.kind == GrblReplyKind::kOverlong);
    if (reply.kind == GrblReplyKind::kOk) CRAFTSCAN_FUZZ_CHECK(reply.line == "ok");
    if (reply.kind == GrblReplyKind::kBanner) CRAFTSCAN_FUZZ_CHECK(!reply.version.empty());
    if (reply.kind != GrblReplyKind::kStatus) {
      CRAFTSCAN_FUZZ_CHECK(!reply.status.x.has_value());
    }
    // Classifying the kept line again gives the same answer.
    if (reply.kind != GrblReplyKind::kOverlong) {
      const GrblReply again = serial_turntable::ClassifyGrblLine(reply.line);
      CRAFTSCAN_FUZZ_CHECK(again.kind == reply.kind && again.code == reply.code);
    }
  }
  CRAFTSCAN_FUZZ_CHECK(whole.pending_bytes() == pieces.pending_bytes());
  CRAFTSCAN_FUZZ_CHECK(SameReplies(at_once, in_pieces));
  return 0;
}
