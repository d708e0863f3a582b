// The exported entry point of craftscan-driver-aravis.so.
#include "aravis_camera.h"

CRAFTSCAN_DRIVER_PLUGIN("aravis", kCraftscanDriverCamera,
                        "GigE Vision stereo pair over Aravis, software-triggered (camera only)",
                        craftscan::aravis::CreateAravisInstance)
