// The exported entry point of craftscan-driver-aravis.so.
#include "aravis_camera.h"

CRAFTSCAN_DRIVER_PLUGIN("aravis", kCraftscanDriverCamera,
                        "GigE Vision / USB3 Vision stereo pair over Aravis (camera only)",
                        craftscan::aravis::CreateAravisInstance)
