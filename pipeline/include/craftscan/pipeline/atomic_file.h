// Crash-safe file replacement, shared by every writer in craftscan.
#pragma once

#include <string>
#include <string_view>

namespace craftscan {

// Writes `bytes` to `path` atomically: a hidden temporary beside `path` (same
// file system) is written, given mode 0644, fsync'ed and renamed over `path`;
// then the folder is fsync'ed so the rename is durable. On failure the
// temporary is removed and any previous file at `path` is untouched. Returns
// false and sets *error (may be null) to "'<path or temporary>': <what>:
// <strerror>". Never throws. Thread-safe for distinct paths.
bool WriteFileAtomically(const std::string& path, std::string_view bytes, std::string* error);

}  // namespace craftscan
