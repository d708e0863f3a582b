// Fuzz target: ManifestFromJson (daemon/session_manifest.h), a session's
// manifest.json as found on disk. Properties: a failure names the problem;
// an accepted manifest writes (ManifestToJson) to text that parses back to
// the same manifest.
#include <string>
#include <string_view>

#include "craftscan/daemon/session_manifest.h"
#include "fuzz_target.h"

CRAFTSCAN_FUZZ_TARGET(manifest) {
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  daemon::Manifest manifest;
  std::string error;
  if (!Outcome(daemon::ManifestFromJson(text, &manifest, &error), error)) return 0;
  CRAFTSCAN_FUZZ_CHECK(daemon::IsValidSessionId(manifest.id));
  std::string json;
  try {
    json = daemon::ManifestToJson(manifest);
  } catch (const std::exception& e) {
    CheckFailed((std::string("an accepted manifest can be written: ") + e.what()).c_str(), __FILE__,
                __LINE__);
  }
  daemon::Manifest again;
  if (!daemon::ManifestFromJson(json, &again, &error)) {
    CheckFailed(("the written manifest parses back (" + error + ")").c_str(), __FILE__, __LINE__);
  }
  CRAFTSCAN_FUZZ_CHECK(daemon::ManifestToJson(again) == json);
  return 0;
}
