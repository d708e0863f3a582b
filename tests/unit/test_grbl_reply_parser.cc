// The serial turntable driver's GRBL reply parser without a device: reply
// kinds, status reports, line splitting across reads, garbage and overlong
// lines, error/alarm messages, and random bytes.
#include "craftscan/drivers/serial_turntable/grbl_reply_parser.h"

#include <random>
#include <string>
#include <vector>

#include <gtest/gtest.h>

namespace craftscan::serial_turntable {
namespace {

std::vector<GrblReply> ParseAll(std::string_view bytes, std::size_t max_line = 256) {
  GrblReplyParser parser(max_line);
  std::vector<GrblReply> replies;
  parser.Feed(bytes, &replies);
  return replies;
}

TEST(GrblReplyParser, ClassifiesEveryReplyKind) {
  auto r = ParseAll(
      "ok\r\nerror:9\r\nALARM:1\r\nGrbl 1.1h ['$' for help]\r\n"
      "<Idle|MPos:12.000,0.000,0.000|FS:0,0>\r\n[MSG:'$H'|'$X' to unlock]\r\nhello\r\n");
  ASSERT_EQ(r.size(), 7u);
  EXPECT_EQ(r[0].kind, GrblReplyKind::kOk);
  EXPECT_EQ(r[1].kind, GrblReplyKind::kError);
  EXPECT_EQ(r[1].code, 9);
  EXPECT_EQ(r[2].kind, GrblReplyKind::kAlarm);
  EXPECT_EQ(r[2].code, 1);
  EXPECT_EQ(r[3].kind, GrblReplyKind::kBanner);
  EXPECT_EQ(r[3].version, "1.1h");
  EXPECT_EQ(r[4].kind, GrblReplyKind::kStatus);
  EXPECT_EQ(r[4].status.state, GrblState::kIdle);
  ASSERT_TRUE(r[4].status.x.has_value());
  EXPECT_DOUBLE_EQ(*r[4].status.x, 12.0);
  EXPECT_FALSE(r[4].status.x_is_work);
  EXPECT_EQ(r[5].kind, GrblReplyKind::kFeedback);
  EXPECT_EQ(r[6].kind, GrblReplyKind::kUnknown);
  EXPECT_EQ(r[6].line, "hello");
}

TEST(GrblReplyParser, StatusReportStatesAndPositions) {
  struct Case {
    const char* line;
    GrblState state;
    double x;
  };
  const Case cases[] = {
      {"<Run|MPos:-3.250,0.000,0.000|FS:3600,0>", GrblState::kRun, -3.25},
      {"<Alarm|MPos:0.000,0.000,0.000|FS:0,0>", GrblState::kAlarm, 0},
      {"<Home|MPos:1.5,0,0|FS:0,0>", GrblState::kHome, 1.5},
      {"<Hold:0|MPos:90.000,0.000,0.000|FS:0,0|WCO:10.000,0.000,0.000>", GrblState::kHold, 90},
      {"<Jog|MPos:7,0,0>", GrblState::kJog, 7},
      {"<Door:1|MPos:7,0,0>", GrblState::kDoor, 7},
  };
  for (const Case& c : cases) {
    GrblReply r = ClassifyGrblLine(c.line);
    ASSERT_EQ(r.kind, GrblReplyKind::kStatus) << c.line;
    EXPECT_EQ(r.status.state, c.state) << c.line;
    ASSERT_TRUE(r.status.x) << c.line;
    EXPECT_DOUBLE_EQ(*r.status.x, c.x) << c.line;
  }
  GrblReply hold = ClassifyGrblLine(cases[3].line);
  EXPECT_EQ(hold.status.state_text, "Hold:0");
  ASSERT_TRUE(hold.status.work_offset_x);
  EXPECT_DOUBLE_EQ(*hold.status.work_offset_x, 10.0);

  GrblReply work = ClassifyGrblLine("<Idle|WPos:45.000,0.000,0.000|FS:0,0>");
  ASSERT_EQ(work.kind, GrblReplyKind::kStatus);
  EXPECT_TRUE(work.status.x_is_work);
  EXPECT_DOUBLE_EQ(*work.status.x, 45.0);

  // A report without a position is still a status report; the driver decides.
  GrblReply bare = ClassifyGrblLine("<Idle|FS:0,0>");
  EXPECT_EQ(bare.kind, GrblReplyKind::kStatus);
  EXPECT_FALSE(bare.status.x);
  // Malformed position: the field is ignored, not misread.
  EXPECT_FALSE(ClassifyGrblLine("<Idle|MPos:abc,0,0>").status.x);
}

TEST(GrblReplyParser, MalformedRepliesAreUnknown) {
  for (const char* line :
       {"ok ", "oK", "error:", "error:x", "error:9x", "ALARM:", "ALARM:-", "<Bogus|MPos:1,0,0>",
        "<Idle", "Grbl", "Grbl x", "okay", "<>", "[", "error:99999999999999999999"}) {
    EXPECT_EQ(ClassifyGrblLine(line).kind, GrblReplyKind::kUnknown) << line;
  }
}

TEST(GrblReplyParser, SplitsLinesAcrossFeedsAndLineEndings) {
  GrblReplyParser parser;
  std::vector<GrblReply> r;
  parser.Feed("o", &r);
  EXPECT_TRUE(r.empty());
  EXPECT_EQ(parser.pending_bytes(), 1u);
  parser.Feed("k\rerr", &r);
  ASSERT_EQ(r.size(), 1u);
  EXPECT_EQ(r[0].kind, GrblReplyKind::kOk);
  parser.Feed("or:2\n\n\r\n<Idle|MPos:1.000,0.000,0.000|F", &r);
  ASSERT_EQ(r.size(), 2u);
  EXPECT_EQ(r[1].kind, GrblReplyKind::kError);
  EXPECT_EQ(r[1].code, 2);
  parser.Feed("S:0,0>\r\n", &r);
  ASSERT_EQ(r.size(), 3u);
  EXPECT_EQ(r[2].kind, GrblReplyKind::kStatus);
  // Byte by byte gives the same replies.
  const std::string stream = "ok\r\nALARM:9\r\nGrbl 1.1f ['$' for help]\n";
  GrblReplyParser one;
  std::vector<GrblReply> bytewise;
  for (char c : stream) one.Feed(std::string_view(&c, 1), &bytewise);
  ASSERT_EQ(bytewise.size(), 3u);
  EXPECT_EQ(bytewise[1].kind, GrblReplyKind::kAlarm);
  EXPECT_EQ(bytewise[2].version, "1.1f");
  parser.Reset();
  EXPECT_EQ(parser.pending_bytes(), 0u);
}

TEST(GrblReplyParser, DropsNonPrintableGarbage) {
  static const char kNoisy[] = "\xff\xfe\x00ok\r\n\x01\x02\x80\r\nerror:1\x7f\r\n";
  auto r = ParseAll(std::string(kNoisy, sizeof(kNoisy) - 1));
  ASSERT_EQ(r.size(), 2u);  // the line of pure noise produces nothing
  EXPECT_EQ(r[0].kind, GrblReplyKind::kOk);
  EXPECT_EQ(r[0].dropped_bytes, 3u);
  EXPECT_EQ(r[1].kind, GrblReplyKind::kError);
  EXPECT_EQ(r[1].dropped_bytes, 1u);
  // Printable garbage stays one unknown line and does not hide the next reply.
  r = ParseAll("#$%&garbage!!\r\nok\r\n");
  ASSERT_EQ(r.size(), 2u);
  EXPECT_EQ(r[0].kind, GrblReplyKind::kUnknown);
  EXPECT_EQ(r[1].kind, GrblReplyKind::kOk);
}

TEST(GrblReplyParser, OverlongLineIsBoundedAndReported) {
  GrblReplyParser parser(16);
  std::vector<GrblReply> r;
  parser.Feed(std::string(10000, 'A'), &r);
  EXPECT_TRUE(r.empty());
  EXPECT_LE(parser.pending_bytes(), 16u);  // bounded, whatever comes
  parser.Feed(std::string(10000, 'B') + "\nok\n", &r);
  ASSERT_EQ(r.size(), 2u);
  EXPECT_EQ(r[0].kind, GrblReplyKind::kOverlong);
  EXPECT_EQ(r[0].line.size(), 16u);
  EXPECT_EQ(r[1].kind, GrblReplyKind::kOk);
  // Exactly the limit is fine.
  r = ParseAll(std::string(16, 'x') + "\n", 16);
  ASSERT_EQ(r.size(), 1u);
  EXPECT_EQ(r[0].kind, GrblReplyKind::kUnknown);
}

TEST(GrblReplyParser, MessagesForCommonCodes) {
  EXPECT_EQ(GrblErrorMessage(9), "G-code locked out during alarm or jog state");
  EXPECT_EQ(GrblErrorMessage(22), "feed rate has not yet been set or is undefined");
  EXPECT_EQ(GrblErrorMessage(0), "unknown error");
  EXPECT_EQ(GrblErrorMessage(1000), "unknown error");
  EXPECT_NE(GrblAlarmMessage(1).find("hard limit triggered"), std::string_view::npos);
  EXPECT_NE(GrblAlarmMessage(2).find("soft limit"), std::string_view::npos);
  EXPECT_EQ(GrblAlarmMessage(9), "homing fail: could not find limit switch");
  EXPECT_EQ(GrblAlarmMessage(-1), "unknown alarm");
}

// Random bytes (with many line ends and reply fragments): no crash, bounded
// memory, every line accounted for.
TEST(GrblReplyParser, SurvivesRandomBytes) {
  std::mt19937 rng(5);
  const std::string alphabet = "ok\r\nerror:ALARM:<>|MPos,.0123456789-Grbl []\xff\x00";
  GrblReplyParser parser(64);
  std::vector<GrblReply> r;
  for (int round = 0; round < 2000; ++round) {
    std::string chunk;
    const int n = static_cast<int>(rng() % 200);
    for (int i = 0; i < n; ++i) {
      chunk.push_back(rng() % 4 == 0 ? static_cast<char>(rng() & 0xff)
                                     : alphabet[rng() % alphabet.size()]);
    }
    parser.Feed(chunk, &r);
    ASSERT_LE(parser.pending_bytes(), 64u);
  }
  for (const GrblReply& reply : r) EXPECT_LE(reply.line.size(), 64u);
  EXPECT_FALSE(r.empty());
}

}  // namespace
}  // namespace craftscan::serial_turntable
