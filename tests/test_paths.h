// Where the tests find the build's programs and plugins, the source tree's
// files and the shared test data (set at configure time).
//
// The paths are compiled into one object, test_paths.cc, rather than passed
// to every test file as -D...="/abs/path": ccache rewrites absolute paths in
// include options but not inside macro values, so a path on the command line
// made every test file miss the cache in a clone at another path (CI's clean
// clone rebuilt ~60 test files for each of its three builds).
#pragma once

namespace craftscan::testing {

const char* SharedDataDir();         // ../shared/data beside the source tree
const char* SourceDir();             // the source tree's root
const char* SystemdDir();            // <source>/systemd
const char* CycloneDdsXml();         // <source>/systemd/cyclonedds.xml
const char* UnitFilePath();          // <source>/systemd/craftscand.service
const char* FuzzDir();               // <source>/tests/fuzz (corpora, regressions)
const char* DdsSecuritySetupPath();  // <source>/scripts/dds-security-setup
const char* PluginDir();             // the built driver plugins
const char* BadPluginDir();          // the deliberately broken test plugins
const char* CraftscandPath();
const char* CraftscanctlPath();
const char* WorkerPath();           // craftscan-worker
const char* RecordPath();           // craftscan-record
const char* DdsPeerPath();          // tests/dds/craftscan_dds_peer
const char* DdsSecurityPeerPath();  // tests/dds/security/craftscan_dds_security_peer
const char* HardenedRunPath();      // tests/tools/hardened-run/hardened-run
const char* HardenedProbePath();    // tests/tools/hardened-run/hardened-probe

}  // namespace craftscan::testing
