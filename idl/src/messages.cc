// Sample memory and the Command limits.
#include "craftscan/dds/messages.h"

#include <dds/dds.h>

namespace craftscan::dds {

namespace internal {
void FreeSampleContents(void* sample, const dds_topic_descriptor_t* descriptor) {
  dds_sample_free(sample, descriptor, DDS_FREE_CONTENTS);
  std::memset(sample, 0, descriptor->m_size);
}
}  // namespace internal

char* MessageStorage::Keep(std::string_view text) {
  strings_.emplace_back(text);
  return strings_.back().data();
}

bool IsValidCommand(const msg::Command& command, std::string* why) {
  auto fail = [why](std::string message) {
    if (why) *why = std::move(message);
    return false;
  };
  struct Field {
    const char* name;
    std::string_view value;
    std::size_t max_bytes;
    bool required;
  };
  const Field fields[] = {
      {"request_id", View(command.request_id), kMaxShortStringBytes, true},
      {"client", View(command.client), kMaxShortStringBytes, true},
      {"verb", View(command.verb), kMaxShortStringBytes, true},
      {"token", View(command.token), kMaxShortStringBytes, false},
      {"arguments", View(command.arguments), kMaxCommandArgumentsBytes, false},
  };
  for (const Field& field : fields) {
    if (field.required && field.value.empty()) {
      return fail(std::string("command: ") + field.name + " is empty");
    }
    if (field.value.size() > field.max_bytes) {
      return fail(std::string("command: ") + field.name + " is " +
                  std::to_string(field.value.size()) + " bytes, more than the " +
                  std::to_string(field.max_bytes) + " allowed");
    }
  }
  return true;
}

}  // namespace craftscan::dds
