#include "craftscan/record/mcap_writer.h"

#include <unistd.h>

#include <array>
#include <cerrno>
#include <cstring>

namespace craftscan::record {
namespace {

constexpr uint8_t kMagic[] = {0x89, 'M', 'C', 'A', 'P', '0', '\r', '\n'};

// Opcodes (spec, "Records").
enum Op : uint8_t {
  kHeader = 0x01,
  kFooter = 0x02,
  kSchema = 0x03,
  kChannel = 0x04,
  kMessage = 0x05,
  kStatistics = 0x0B,
  kSummaryOffset = 0x0E,
  kDataEnd = 0x0F,
};

bool Fail(std::string* error, std::string message) {
  if (error) *error = std::move(message);
  return false;
}

// Little-endian serialisation of the spec's field types, into a string
// (std::string rather than std::vector<uint8_t>: GCC 12 warns falsely,
// -Wstringop-overflow, on the vector's inserts here).
class Body {
 public:
  template <typename T>
  Body& Int(T value) {
    for (std::size_t i = 0; i < sizeof(T); ++i) {
      bytes_.push_back(static_cast<char>(static_cast<uint64_t>(value) >> (8 * i)));
    }
    return *this;
  }
  Body& Raw(std::string_view data) {
    bytes_.append(data);
    return *this;
  }
  // string and bytes: uint32 length prefix.
  Body& Str(std::string_view text) { return Int(static_cast<uint32_t>(text.size())).Raw(text); }
  Body& Map(const std::map<std::string, std::string>& map) {
    Body entries;
    for (const auto& [key, value] : map) entries.Str(key).Str(value);
    return Str(entries.bytes_);
  }
  const std::string& bytes() const { return bytes_; }

 private:
  std::string bytes_;
};

std::array<uint32_t, 256> MakeCrcTable() {
  std::array<uint32_t, 256> table{};
  for (uint32_t i = 0; i < 256; ++i) {
    uint32_t c = i;
    for (int k = 0; k < 8; ++k) c = (c & 1) ? 0xEDB88320u ^ (c >> 1) : c >> 1;
    table[i] = c;
  }
  return table;
}

}  // namespace

uint32_t Crc32(const uint8_t* data, std::size_t size, uint32_t crc) {
  static const std::array<uint32_t, 256> table = MakeCrcTable();
  crc = ~crc;
  for (std::size_t i = 0; i < size; ++i) crc = table[(crc ^ data[i]) & 0xFF] ^ (crc >> 8);
  return ~crc;
}

std::unique_ptr<McapWriter> McapWriter::Create(const std::string& path, std::string_view profile,
                                               std::string_view library, std::string* error) {
  std::unique_ptr<McapWriter> writer(new McapWriter());
  writer->path_ = path;
  writer->file_ = std::fopen(path.c_str(), "wbe");
  if (writer->file_ == nullptr) {
    Fail(error, "cannot create '" + path + "': " + std::strerror(errno));
    return nullptr;
  }
  std::lock_guard lock(writer->mutex_);
  if (!writer->WriteBytes(kMagic, sizeof(kMagic), error) ||
      !writer->WriteRecord(kHeader, Body().Str(profile).Str(library).bytes(), error)) {
    return nullptr;
  }
  return writer;
}

McapWriter::~McapWriter() {
  std::string ignored;
  Close(&ignored);
}

bool McapWriter::WriteBytes(const void* bytes, std::size_t size, std::string* error) {
  const auto* data = static_cast<const uint8_t*>(bytes);
  if (size > 0 && std::fwrite(data, 1, size, file_) != size) {
    return Fail(error, "writing '" + path_ + "': " + std::strerror(errno));
  }
  if (in_summary_) {
    summary_crc_ = Crc32(data, size, summary_crc_);
  } else {
    data_crc_ = Crc32(data, size, data_crc_);
  }
  offset_ += size;
  return true;
}

bool McapWriter::WriteRecord(uint8_t opcode, const std::string& body, std::string* error) {
  const std::string prefix = Body().Int(opcode).Int(static_cast<uint64_t>(body.size())).bytes();
  return WriteBytes(prefix.data(), prefix.size(), error) &&
         WriteBytes(body.data(), body.size(), error);
}

std::string McapWriter::SchemaBody(const Schema& s) {
  return Body().Int(s.id).Str(s.name).Str(s.encoding).Str(s.data).bytes();
}

std::string McapWriter::ChannelBody(const Channel& c) {
  return Body().Int(c.id).Int(c.schema_id).Str(c.topic).Str(c.encoding).Map(c.metadata).bytes();
}

uint16_t McapWriter::AddSchema(std::string_view name, std::string_view encoding,
                               std::string_view data, std::string* error) {
  std::lock_guard lock(mutex_);
  if (file_ == nullptr) return Fail(error, "'" + path_ + "' is closed"), 0;
  for (const Schema& s : schemas_) {
    if (s.name == name && s.encoding == encoding && s.data == data) return s.id;
  }
  if (schemas_.size() >= 0xFFFE) return Fail(error, "too many schemas"), 0;
  Schema schema{static_cast<uint16_t>(schemas_.size() + 1), std::string(name),
                std::string(encoding), std::string(data)};
  if (!WriteRecord(kSchema, SchemaBody(schema), error)) return 0;
  schemas_.push_back(std::move(schema));
  return schemas_.back().id;
}

uint16_t McapWriter::AddChannel(uint16_t schema_id, std::string_view topic,
                                std::string_view encoding,
                                const std::map<std::string, std::string>& metadata,
                                std::string* error) {
  std::lock_guard lock(mutex_);
  if (file_ == nullptr) return Fail(error, "'" + path_ + "' is closed"), 0;
  if (schema_id == 0 || schema_id > schemas_.size()) {
    return Fail(error, "unknown schema id " + std::to_string(schema_id)), 0;
  }
  for (const Channel& c : channels_) {
    if (c.topic == topic && c.schema_id == schema_id) return c.id;
  }
  if (channels_.size() >= 0xFFFE) return Fail(error, "too many channels"), 0;
  Channel channel{static_cast<uint16_t>(channels_.size() + 1), schema_id, std::string(topic),
                  std::string(encoding), metadata};
  if (!WriteRecord(kChannel, ChannelBody(channel), error)) return 0;
  channels_.push_back(std::move(channel));
  return channels_.back().id;
}

bool McapWriter::WriteMessage(uint16_t channel_id, uint64_t log_time_ns, uint64_t publish_time_ns,
                              const uint8_t* data, std::size_t size, std::string* error) {
  std::lock_guard lock(mutex_);
  if (file_ == nullptr) return Fail(error, "'" + path_ + "' is closed");
  if (channel_id == 0 || channel_id > channels_.size()) {
    return Fail(error, "unknown channel id " + std::to_string(channel_id));
  }
  Channel& channel = channels_[channel_id - 1];
  const std::string head = Body()
                               .Int(channel_id)
                               .Int(channel.next_sequence)
                               .Int(log_time_ns)
                               .Int(publish_time_ns)
                               .bytes();
  const std::string prefix = Body()
                                 .Int(static_cast<uint8_t>(kMessage))
                                 .Int(static_cast<uint64_t>(head.size() + size))
                                 .bytes();
  if (!WriteBytes(prefix.data(), prefix.size(), error) ||
      !WriteBytes(head.data(), head.size(), error) || !WriteBytes(data, size, error)) {
    return false;
  }
  if (std::fflush(file_) != 0)
    return Fail(error, "writing '" + path_ + "': " + std::strerror(errno));
  channel.next_sequence += 1;
  channel.messages += 1;
  if (messages_ == 0 || log_time_ns < first_time_ns_) first_time_ns_ = log_time_ns;
  if (messages_ == 0 || log_time_ns > last_time_ns_) last_time_ns_ = log_time_ns;
  messages_ += 1;
  return true;
}

bool McapWriter::Close(std::string* error) {
  std::lock_guard lock(mutex_);
  if (file_ == nullptr) return true;
  const auto finish = [&](bool ok) {
    if (std::fflush(file_) != 0 || ::fsync(::fileno(file_)) != 0) {
      ok = ok && Fail(error, "writing '" + path_ + "': " + std::strerror(errno));
    }
    if (std::fclose(file_) != 0) ok = ok && Fail(error, "closing '" + path_ + "'");
    file_ = nullptr;
    return ok;
  };
  // DataEnd: the CRC covers everything before this record.
  if (!WriteRecord(kDataEnd, Body().Int(data_crc_).bytes(), error)) return finish(false);
  in_summary_ = true;
  summary_crc_ = 0;
  const uint64_t summary_start = offset_;
  struct Group {
    uint8_t opcode;
    uint64_t start, length;
  };
  std::vector<Group> groups;
  // One group of the summary: a record of `opcode` per body; its offset
  // and length go into a Summary Offset record.
  const auto group = [&](uint8_t opcode, const std::vector<std::string>& bodies) {
    const uint64_t start = offset_;
    for (const std::string& body : bodies) {
      if (!WriteRecord(opcode, body, error)) return false;
    }
    if (offset_ > start) groups.push_back({opcode, start, offset_ - start});
    return true;
  };
  std::vector<std::string> schema_bodies, channel_bodies;
  for (const Schema& s : schemas_) schema_bodies.push_back(SchemaBody(s));
  for (const Channel& c : channels_) channel_bodies.push_back(ChannelBody(c));
  std::map<uint16_t, uint64_t> per_channel;
  for (const Channel& c : channels_) per_channel[c.id] = c.messages;
  Body statistics;
  statistics.Int(messages_)
      .Int(static_cast<uint16_t>(schemas_.size()))
      .Int(static_cast<uint32_t>(channels_.size()))
      .Int(uint32_t{0})  // attachments
      .Int(uint32_t{0})  // metadata
      .Int(uint32_t{0})  // chunks
      .Int(first_time_ns_)
      .Int(last_time_ns_);
  Body counts;
  for (const auto& [id, n] : per_channel) counts.Int(id).Int(n);
  statistics.Str(counts.bytes());  // a map: uint32 byte length, entries
  const bool summary_ok = group(kSchema, schema_bodies) && group(kChannel, channel_bodies) &&
                          group(kStatistics, {statistics.bytes()});
  if (!summary_ok) return finish(false);
  const uint64_t summary_offset_start = offset_;
  for (const Group& g : groups) {
    if (!WriteRecord(kSummaryOffset, Body().Int(g.opcode).Int(g.start).Int(g.length).bytes(),
                     error)) {
      return finish(false);
    }
  }
  // Footer: its CRC covers the summary section and the footer up to the CRC.
  const std::string footer_head = Body()
                                      .Int(static_cast<uint8_t>(kFooter))
                                      .Int(uint64_t{8 + 8 + 4})
                                      .Int(summary_start)
                                      .Int(summary_offset_start)
                                      .bytes();
  if (!WriteBytes(footer_head.data(), footer_head.size(), error)) return finish(false);
  const std::string tail =
      Body().Int(summary_crc_).Raw({reinterpret_cast<const char*>(kMagic), sizeof(kMagic)}).bytes();
  return finish(WriteBytes(tail.data(), tail.size(), error));
}

uint64_t McapWriter::message_count() const {
  std::lock_guard lock(mutex_);
  return messages_;
}

}  // namespace craftscan::record
