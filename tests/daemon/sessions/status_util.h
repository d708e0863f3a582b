// Test helpers for the craftscan::Status the session store returns: keep a
// test's "<< error" messages while the store speaks Status.
#pragma once

#include <string>

#include "craftscan/pipeline/common/status.h"

namespace craftscan::testing {

// status.ok(); on failure *error (may be null) gets its message. For
// ASSERT_TRUE(Ok(s->StoreCapture(...), &error)) << error.
inline bool Ok(const Status& status, std::string* error) {
  if (!status.ok() && error) *error = status.message();
  return status.ok();
}

// A Status* for SessionStore::Open / Create / OpenSession that, at the end of
// the full expression, copies a failure's message into *error (may be null):
//   auto s = store->OpenSession(id, StatusInto(&error));
class StatusInto {
 public:
  explicit StatusInto(std::string* error) : error_(error) {}
  ~StatusInto() {
    if (!status_.ok() && error_) *error_ = status_.message();
  }
  StatusInto(const StatusInto&) = delete;
  StatusInto& operator=(const StatusInto&) = delete;
  operator Status*() { return &status_; }

 private:
  std::string* error_;
  Status status_;
};

}  // namespace craftscan::testing
