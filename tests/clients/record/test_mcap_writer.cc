// The MCAP writer of craftscan-record on its own: the CRC, the record
// layout a reader relies on (byte offsets from the spec), and clear errors.
// Reading the files back with an independent reader (@mcap/core) is the
// ros_mcap test (tests/dds).
#include <gtest/gtest.h>

#include <cstring>
#include <string>
#include <vector>

#include "craftscan/record/mcap_writer.h"
#include "file_util.h"

namespace craftscan::record {
namespace {

uint64_t U64(const std::string& bytes, std::size_t at) {
  uint64_t v = 0;
  for (int i = 7; i >= 0; --i) v = (v << 8) | static_cast<uint8_t>(bytes[at + i]);
  return v;
}
uint32_t U32(const std::string& bytes, std::size_t at) {
  return static_cast<uint32_t>(U64(bytes.substr(at, 4) + std::string(4, '\0'), 0));
}

TEST(McapWriter, Crc32IsIsoHdlc) {
  const std::string check = "123456789";
  const auto* data = reinterpret_cast<const uint8_t*>(check.data());
  EXPECT_EQ(Crc32(data, check.size()), 0xCBF43926u);  // the catalogue's check value
  // Continued over two parts: the same.
  EXPECT_EQ(Crc32(data + 4, 5, Crc32(data, 4)), 0xCBF43926u);
  EXPECT_EQ(Crc32(nullptr, 0), 0u);
}

TEST(McapWriter, WritesMagicHeaderRecordsSummaryAndFooter) {
  testing::TempDir dir("craftscan-mcap-test");
  const std::string path = dir.path() + "/a.mcap";
  std::string error;
  auto writer = McapWriter::Create(path, "ros2", "test", &error);
  ASSERT_TRUE(writer) << error;
  const uint16_t schema = writer->AddSchema("pkg/msg/T", "ros2msg", "int32 a\n", &error);
  ASSERT_EQ(schema, 1) << error;
  EXPECT_EQ(writer->AddSchema("pkg/msg/T", "ros2msg", "int32 a\n", &error), schema);
  const uint16_t channel = writer->AddChannel(schema, "/t", "cdr", {{"k", "v"}}, &error);
  ASSERT_EQ(channel, 1) << error;
  const uint8_t payload[] = {0, 1, 0, 0, 7, 0, 0, 0};
  ASSERT_TRUE(writer->WriteMessage(channel, 5, 4, payload, sizeof(payload), &error)) << error;
  ASSERT_TRUE(writer->WriteMessage(channel, 9, 8, payload, sizeof(payload), &error)) << error;
  EXPECT_FALSE(writer->WriteMessage(7, 1, 1, payload, sizeof(payload), &error));
  EXPECT_NE(error.find("unknown channel id 7"), std::string::npos) << error;
  EXPECT_EQ(writer->AddChannel(9, "/u", "cdr", {}, &error), 0);
  EXPECT_NE(error.find("unknown schema id 9"), std::string::npos) << error;
  ASSERT_TRUE(writer->Close(&error)) << error;
  EXPECT_TRUE(writer->Close(&error));  // idempotent
  EXPECT_FALSE(writer->WriteMessage(channel, 1, 1, payload, sizeof(payload), &error));
  EXPECT_NE(error.find("is closed"), std::string::npos) << error;
  EXPECT_EQ(writer->message_count(), 2u);

  const std::string bytes = testing::ReadFile(path);
  const std::string magic = "\x89MCAP0\r\n";
  ASSERT_GT(bytes.size(), 2 * magic.size() + 29);
  EXPECT_EQ(bytes.substr(0, 8), magic);
  EXPECT_EQ(bytes.substr(bytes.size() - 8), magic);
  EXPECT_EQ(bytes[8], 0x01);                 // Header
  EXPECT_EQ(U64(bytes, 9), 4u + 4 + 4 + 4);  // "ros2", "test"
  EXPECT_EQ(bytes.substr(21, 4), "ros2");
  // Footer: opcode, length 20, summary start, summary offset start, CRC.
  const std::size_t footer = bytes.size() - 8 - 29;
  EXPECT_EQ(bytes[footer], 0x02);
  EXPECT_EQ(U64(bytes, footer + 1), 20u);
  const uint64_t summary_start = U64(bytes, footer + 9);
  const uint64_t summary_offset_start = U64(bytes, footer + 17);
  ASSERT_LT(summary_start, summary_offset_start);
  ASSERT_LT(summary_offset_start, footer);
  // DataEnd right before the summary, with the data section's CRC.
  const std::size_t data_end = summary_start - 13;
  EXPECT_EQ(bytes[data_end], 0x0F);
  const auto* data = reinterpret_cast<const uint8_t*>(bytes.data());
  EXPECT_EQ(U32(bytes, data_end + 9), Crc32(data, data_end));
  EXPECT_EQ(U32(bytes, footer + 25), Crc32(data + summary_start, footer + 25 - summary_start));
  // The summary opens with the schema again; offsets point at its groups.
  EXPECT_EQ(bytes[summary_start], 0x03);
  EXPECT_EQ(bytes[summary_offset_start], 0x0E);
  EXPECT_EQ(static_cast<uint64_t>(bytes[summary_offset_start + 9]), 0x03u);
  EXPECT_EQ(U64(bytes, summary_offset_start + 10), summary_start);
}

// A recording cut short (the writer never closed, as after SIGKILL): the
// file is the magic and whole records up to the last message, which a
// streaming reader reads.
TEST(McapWriter, EveryMessageIsWholeOnDiskBeforeClose) {
  testing::TempDir dir("craftscan-mcap-test");
  const std::string path = dir.path() + "/cut.mcap";
  std::string error;
  auto writer = McapWriter::Create(path, "ros2", "test", &error);
  ASSERT_TRUE(writer) << error;
  const uint16_t channel = writer->AddChannel(
      writer->AddSchema("pkg/msg/T", "ros2msg", "int32 a\n", &error), "/t", "cdr", {}, &error);
  ASSERT_NE(channel, 0) << error;
  const uint8_t payload[] = {0, 1, 0, 0, 42, 0, 0, 0};
  for (int i = 0; i < 3; ++i) {
    ASSERT_TRUE(writer->WriteMessage(channel, 1, 1, payload, sizeof(payload), &error)) << error;
  }
  const std::string bytes = testing::ReadFile(path);  // before Close
  std::size_t at = 8;
  std::vector<int> opcodes;
  while (at + 9 <= bytes.size()) {
    opcodes.push_back(static_cast<uint8_t>(bytes[at]));
    at += 9 + U64(bytes, at + 1);
  }
  EXPECT_EQ(at, bytes.size()) << "a record cut in the middle";
  EXPECT_EQ(opcodes, (std::vector<int>{0x01, 0x03, 0x04, 0x05, 0x05, 0x05}));
  EXPECT_EQ(bytes.substr(bytes.size() - 4), std::string("\x2a\0\0\0", 4));
}

TEST(McapWriter, AFileThatCannotBeCreatedIsNamed) {
  std::string error;
  EXPECT_FALSE(McapWriter::Create("/nonexistent-dir/x.mcap", "ros2", "test", &error));
  EXPECT_NE(error.find("cannot create '/nonexistent-dir/x.mcap'"), std::string::npos) << error;
}

}  // namespace
}  // namespace craftscan::record
