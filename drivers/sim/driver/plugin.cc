// The exported entry point of craftscan-driver-sim.so.
#include "devices.h"

CRAFTSCAN_DRIVER_PLUGIN("sim", kCraftscanDriverCamera | kCraftscanDriverTurntable,
                        "simulated stereo rig and turntable (ray-cast, with fault knobs)",
                        craftscan::sim::CreateSimInstance)
