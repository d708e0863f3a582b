// File-system helpers of the session store: whole-file reads, durable folder
// creation, folder locks, UTC timestamps and the clean-up of temporaries left
// by a crash. Errors name the path and carry strerror, with the errno's code
// (ErrorCodeFromErrno); nothing throws.
#pragma once

#include <chrono>
#include <string>

#include "craftscan/pipeline/common/status.h"

namespace craftscan::daemon::internal {

// Reads the whole file. A failed Status "'<path>': cannot read: <strerror>".
Status ReadFileBytes(const std::string& path, std::string* bytes);

// Creates the folder `path` (mode 0755) if it does not exist and fsyncs its
// parent so the entry is durable (also when it existed: another thread may
// have created it and not yet synced). Its parent must exist.
Status MakeDurableDir(const std::string& path);

// fsyncs a folder (makes renames and new entries in it durable).
Status FsyncDir(const std::string& path);

// An exclusive, non-blocking flock on a folder, released on destruction (and
// by the kernel when the process dies).
class DirLock {
 public:
  // A failed Status with kFailedPrecondition when another open file
  // description holds the lock, else the errno's code (an I/O error).
  Status Acquire(const std::string& path);
  ~DirLock();
  DirLock() = default;
  DirLock(const DirLock&) = delete;
  DirLock& operator=(const DirLock&) = delete;

 private:
  int fd_ = -1;
};

// "2024-05-01T09:30:00.123Z".
std::string IsoUtc(std::chrono::system_clock::time_point t);
// "20240501-093000" (UTC).
std::string IdTimeUtc(std::chrono::system_clock::time_point t);

// Whether a file name is a WriteFileAtomically/Create temporary:
// ".<name>.tmp-XXXXXX".
bool IsTemporaryName(const std::string& file_name);

// Removes temporaries (IsTemporaryName) anywhere below `dir`; returns how many.
int RemoveTemporaries(const std::string& dir);

}  // namespace craftscan::daemon::internal
