// A minimal MCAP writer (https://mcap.dev/spec, format version 0), written
// here from the specification: Debian 12 packages no MCAP library. What it
// writes:
//
//   magic · Header(profile, library) · Schema/Channel/Message records as they
//   come (no chunks: messages are not compressed and not indexed) ·
//   DataEnd(data section CRC) · summary: every Schema and Channel again,
//   Statistics · a Summary Offset per group · Footer(summary CRC) · magic
//
// CRCs are CRC-32 (ISO-HDLC, zlib's) as the spec asks: the data section's
// over every byte from the leading magic to the DataEnd record, the
// summary's over the summary section and the footer up to its CRC field.
// Readers that seek (McapIndexedReader, `mcap info`) get the schemas,
// channels and per-channel counts from the summary; messages are read in
// order (McapStreamReader, Foxglove, rosbag2's MCAP plugin).
//
// Written straight to the final path and flushed after every message: a
// recording cut short (power, SIGKILL) keeps every complete record, which a
// streaming reader still reads (it only misses the summary). Close() writes
// the summary.
//
// Thread-safety: every method may be called from any thread (one mutex).
#pragma once

#include <cstdint>
#include <cstdio>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>
#include <vector>

namespace craftscan::record {

// CRC-32 (ISO-HDLC: reflected 0xEDB88320, init and final xor 0xFFFFFFFF).
// Continue a CRC by passing the previous result as `crc`.
uint32_t Crc32(const uint8_t* data, std::size_t size, uint32_t crc = 0);

class McapWriter {
 public:
  // Creates (truncates) `path` and writes the magic and Header record.
  // Null with *error (may be null) naming the path and the reason.
  static std::unique_ptr<McapWriter> Create(const std::string& path, std::string_view profile,
                                            std::string_view library, std::string* error);
  ~McapWriter();  // Close() if not done
  McapWriter(const McapWriter&) = delete;
  McapWriter& operator=(const McapWriter&) = delete;

  // Registers a schema (e.g. name "sensor_msgs/msg/Image", encoding
  // "ros2msg", the full message definition) and returns its id (≥ 1); the
  // same name, encoding and data twice give the same id. 0 with *error on
  // an I/O error or after Close().
  uint16_t AddSchema(std::string_view name, std::string_view encoding, std::string_view data,
                     std::string* error);
  // Registers a channel (topic, message encoding e.g. "cdr") of
  // `schema_id`; the same topic and schema twice give the same id. Returns
  // its id (≥ 1; the spec allows 0 but some tools treat it as unset);
  // 0 with *error on an I/O error, an unknown schema or after Close().
  uint16_t AddChannel(uint16_t schema_id, std::string_view topic, std::string_view encoding,
                      const std::map<std::string, std::string>& metadata, std::string* error);
  // Writes a Message record on `channel_id` (its sequence number counts per
  // channel from 0). Times in ns since the Unix epoch. False with *error on
  // an I/O error, an unknown channel or after Close().
  bool WriteMessage(uint16_t channel_id, uint64_t log_time_ns, uint64_t publish_time_ns,
                    const uint8_t* data, std::size_t size, std::string* error);

  // Writes DataEnd, the summary and the footer, and closes the file
  // (fsync'd). False with *error on an I/O error. Idempotent.
  bool Close(std::string* error);

  uint64_t message_count() const;

 private:
  struct Schema {
    uint16_t id;
    std::string name, encoding, data;
  };
  struct Channel {
    uint16_t id, schema_id;
    std::string topic, encoding;
    std::map<std::string, std::string> metadata;
    uint32_t next_sequence = 0;
    uint64_t messages = 0;
  };

  McapWriter() = default;
  // Appends a record (opcode, length, body) to the file, adding it to the
  // data section CRC while the data section is open. Caller holds mutex_.
  bool WriteRecord(uint8_t opcode, const std::string& body, std::string* error);
  bool WriteBytes(const void* data, std::size_t size, std::string* error);
  static std::string SchemaBody(const Schema& schema);
  static std::string ChannelBody(const Channel& channel);

  mutable std::mutex mutex_;
  std::string path_;
  std::FILE* file_ = nullptr;  // null once closed
  uint64_t offset_ = 0;        // bytes written
  uint32_t data_crc_ = 0;      // of the data section so far
  uint32_t summary_crc_ = 0;   // of the summary section so far
  bool in_summary_ = false;
  std::vector<Schema> schemas_;
  std::vector<Channel> channels_;
  uint64_t messages_ = 0;
  uint64_t first_time_ns_ = 0, last_time_ns_ = 0;
};

}  // namespace craftscan::record
