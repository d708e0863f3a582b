// The exported entry point of craftscan-driver-serial_turntable.so.
#include "adapter.h"

CRAFTSCAN_DRIVER_PLUGIN("serial_turntable", kCraftscanDriverTurntable,
                        "GRBL 1.1 turntable on a serial port (turntable only)",
                        craftscan::serial_turntable::CreateSerialTurntableInstance)
