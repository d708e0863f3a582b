// A test shared object that is not a driver: it lacks craftscan_driver_info_v1.
extern "C" __attribute__((visibility("default"))) int craftscan_not_a_driver() { return 42; }
