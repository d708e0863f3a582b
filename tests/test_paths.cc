// The one translation unit that carries the absolute paths (test_paths.h).
#include "test_paths.h"

namespace craftscan::testing {

const char* SharedDataDir() { return CRAFTSCAN_SHARED_DATA; }
const char* SourceDir() { return CRAFTSCAN_SOURCE_DIR; }
const char* SystemdDir() { return CRAFTSCAN_SOURCE_DIR "/systemd"; }
const char* CycloneDdsXml() { return CRAFTSCAN_SOURCE_DIR "/systemd/cyclonedds.xml"; }
const char* UnitFilePath() { return CRAFTSCAN_SOURCE_DIR "/systemd/craftscand.service"; }
const char* FuzzDir() { return CRAFTSCAN_SOURCE_DIR "/tests/fuzz"; }
const char* DdsSecuritySetupPath() { return CRAFTSCAN_SOURCE_DIR "/scripts/dds-security-setup"; }
const char* PluginDir() { return CRAFTSCAN_PLUGIN_DIR; }
const char* BadPluginDir() { return CRAFTSCAN_BAD_PLUGIN_DIR; }
const char* CraftscandPath() { return CRAFTSCAND_PATH; }
const char* CraftscanctlPath() { return CRAFTSCANCTL_PATH; }
const char* WorkerPath() { return CRAFTSCAN_WORKER_PATH; }
const char* RecordPath() { return CRAFTSCAN_RECORD_PATH; }
const char* DdsPeerPath() { return CRAFTSCAN_DDS_PEER; }
const char* DdsSecurityPeerPath() { return CRAFTSCAN_DDS_SECURITY_PEER; }
const char* HardenedRunPath() { return HARDENED_RUN_PATH; }
const char* HardenedProbePath() { return HARDENED_PROBE_PATH; }

}  // namespace craftscan::testing
