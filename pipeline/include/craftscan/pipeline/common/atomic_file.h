// Crash-safe file replacement, shared by every writer in craftscan.
#pragma once

#include <string>
#include <string_view>

#include "craftscan/pipeline/common/status.h"

namespace craftscan {

// Writes `bytes` to `path` atomically: a hidden temporary beside `path` (same
// file system) is written, given mode 0666 less the process umask (0644
// under the usual 022, 0640 under craftscand.service's UMask=0027), fsync'ed
// and renamed over `path`;
// then the folder is fsync'ed so the rename is durable. On failure the
// temporary is removed and any previous file at `path` is untouched. Returns
// a failed Status with the message "'<path or temporary>': <what>:
// <strerror>" with the code of the errno of the failing call (kDiskFull,
// kReadOnly, kPermissionDenied, kNotFound, kIoError...; kInvalidArgument for
// an empty path, kInternal for an escaping exception). Never throws.
// Thread-safe for distinct paths.
Status WriteFileAtomically(const std::string& path, std::string_view bytes);

// The same, for callers that need only the text: false with *error (may be
// null) set to the Status's message.
bool WriteFileAtomically(const std::string& path, std::string_view bytes, std::string* error);

// The process umask, read without changing it (umask() would, racing other
// threads that create files): the "Umask:" line of /proc/self/status; 022
// where that is missing (Linux < 4.7). For code that creates a file or
// folder with a restrictive mode first (mkstemp, mkdtemp) and then widens
// it: widen to 0666 / 0777 less this. Read once per process (craftscan sets
// no umask of its own; the service manager's UMask= is in place before
// exec), so calling it for every file costs nothing. Thread-safe.
unsigned ProcessUmask();

}  // namespace craftscan
