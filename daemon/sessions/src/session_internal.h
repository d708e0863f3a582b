// Pieces shared by Session and SessionStore: the folder lock a Session holds,
// manifest reading, file verification and the resume computation.
#pragma once

#include <set>
#include <string>

#include "craftscan/daemon/session_store.h"
#include "fs_util.h"

namespace craftscan::daemon {

struct Session::Lock {
  internal::DirLock dir;
};

namespace internal {

using daemon::kCalibrationYaml;
using daemon::kManifestJson;

// "views/003".
std::string ViewFolder(int view);

// Reads and validates <dir>/manifest.json and checks that its id is `id`.
// A failed Status with the errno's code when it cannot be read, kCorrupt
// when it is invalid or names another id.
Status ReadManifest(const std::string& dir, const std::string& id, Manifest* manifest);

// Checks every file `manifest` lists under `dir`; damaged files are added to
// result->problems ("<relative path>: <what>") and, if `damaged` is not null,
// their relative paths to *damaged.
void VerifyFiles(const std::string& dir, const Manifest& manifest, VerifyResult* result,
                 std::set<std::string>* damaged);

}  // namespace internal
}  // namespace craftscan::daemon
