// The 3D viewer's script (clients/web/viewer, bundled by esbuild: the global
// CraftscanViewer, clients/web/API.md "The 3D viewer"), compiled into the
// report library by embed_viewer_bundle.cmake.
#pragma once

#include <string_view>

namespace craftscan::daemon::internal {

// The bundle's text (ASCII, without "</script"); empty when the library was
// built without clients/web (report.html then has no 3D view).
std::string_view ViewerBundle();

}  // namespace craftscan::daemon::internal
