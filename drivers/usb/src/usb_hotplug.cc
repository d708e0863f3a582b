#include "craftscan/drivers/usb_hotplug.h"

#include <atomic>
#include <thread>

#include <libusb.h>

namespace craftscan::drivers {
namespace {

constexpr std::uint8_t kMiscClass = 0xEF;  // USB3 Vision control interface
constexpr std::uint8_t kU3vSubclass = 0x05;
constexpr std::uint8_t kU3vProtocol = 0x00;

bool HasUsb3VisionInterface(libusb_device* device) {
  libusb_config_descriptor* config = nullptr;
  if (libusb_get_active_config_descriptor(device, &config) != LIBUSB_SUCCESS || !config) {
    if (libusb_get_config_descriptor(device, 0, &config) != LIBUSB_SUCCESS || !config) return false;
  }
  bool found = false;
  for (int i = 0; i < config->bNumInterfaces && !found; ++i) {
    const libusb_interface& interface = config->interface[i];
    for (int a = 0; a < interface.num_altsetting && !found; ++a) {
      const libusb_interface_descriptor& d = interface.altsetting[a];
      found = d.bInterfaceClass == kMiscClass && d.bInterfaceSubClass == kU3vSubclass &&
              d.bInterfaceProtocol == kU3vProtocol;
    }
  }
  libusb_free_config_descriptor(config);
  return found;
}

class LibusbEventSource : public UsbEventSource {
 public:
  ~LibusbEventSource() override { Stop(); }

  DriverStatus Start(std::function<void(const UsbDeviceEvent&)> sink) override {
    if (context_)
      return DriverStatus::Error(StatusCode::kWrongState, "USB hot-plug: already started");
    sink_ = std::move(sink);
    const int rc = libusb_init(&context_);
    if (rc != LIBUSB_SUCCESS) {
      context_ = nullptr;
      return DriverStatus::Error(
          StatusCode::kUnsupported,
          std::string("USB hot-plug: libusb_init failed: ") + libusb_error_name(rc));
    }
    if (!libusb_has_capability(LIBUSB_CAP_HAS_HOTPLUG)) {
      libusb_exit(context_);
      context_ = nullptr;
      return DriverStatus::Error(StatusCode::kUnsupported,
                                 "USB hot-plug: libusb has no hot-plug support on this platform");
    }
    const int reg = libusb_hotplug_register_callback(
        context_,
        static_cast<libusb_hotplug_event>(LIBUSB_HOTPLUG_EVENT_DEVICE_ARRIVED |
                                          LIBUSB_HOTPLUG_EVENT_DEVICE_LEFT),
        LIBUSB_HOTPLUG_ENUMERATE, LIBUSB_HOTPLUG_MATCH_ANY, LIBUSB_HOTPLUG_MATCH_ANY,
        LIBUSB_HOTPLUG_MATCH_ANY, &LibusbEventSource::Callback, this, &handle_);
    if (reg != LIBUSB_SUCCESS) {
      libusb_exit(context_);
      context_ = nullptr;
      return DriverStatus::Error(
          StatusCode::kUnsupported,
          std::string("USB hot-plug: cannot register a callback: ") + libusb_error_name(reg));
    }
    running_ = true;
    thread_ = std::thread([this] {
      while (running_) {
        timeval tv{1, 0};
        libusb_handle_events_timeout_completed(context_, &tv, nullptr);
      }
    });
    return DriverStatus::Ok();
  }

  void Stop() override {
    if (!context_) return;
    running_ = false;
    // Deregistering wakes the event thread (libusb signals its event pipe).
    libusb_hotplug_deregister_callback(context_, handle_);
    if (thread_.joinable()) thread_.join();
    libusb_exit(context_);
    context_ = nullptr;
  }

 private:
  static int LIBUSB_CALL Callback(libusb_context*, libusb_device* device,
                                  libusb_hotplug_event event, void* self) {
    static_cast<LibusbEventSource*>(self)->Deliver(device, event);
    return 0;  // stay registered
  }

  void Deliver(libusb_device* device, libusb_hotplug_event event) {
    UsbDeviceEvent e;
    e.kind = event == LIBUSB_HOTPLUG_EVENT_DEVICE_ARRIVED ? UsbDeviceEvent::Kind::kArrived
                                                          : UsbDeviceEvent::Kind::kLeft;
    e.bus = libusb_get_bus_number(device);
    e.address = libusb_get_device_address(device);
    libusb_device_descriptor d{};
    if (libusb_get_device_descriptor(device, &d) == LIBUSB_SUCCESS) {
      e.vendor_id = d.idVendor;
      e.product_id = d.idProduct;
      if (e.kind == UsbDeviceEvent::Kind::kArrived) {
        e.is_usb3_vision = HasUsb3VisionInterface(device);
        libusb_device_handle* handle = nullptr;
        if (e.is_usb3_vision && d.iSerialNumber != 0 &&
            libusb_open(device, &handle) == LIBUSB_SUCCESS) {
          unsigned char text[256] = {};
          const int n =
              libusb_get_string_descriptor_ascii(handle, d.iSerialNumber, text, sizeof(text) - 1);
          if (n > 0)
            e.serial.assign(reinterpret_cast<const char*>(text), static_cast<std::size_t>(n));
          libusb_close(handle);
        }
      }
    }
    if (sink_) sink_(e);
  }

  libusb_context* context_ = nullptr;
  libusb_hotplug_callback_handle handle_ = 0;
  std::function<void(const UsbDeviceEvent&)> sink_;
  std::atomic<bool> running_{false};
  std::thread thread_;
};

}  // namespace

std::unique_ptr<UsbEventSource> MakeLibusbEventSource() {
  return std::make_unique<LibusbEventSource>();
}

UsbHotplugMonitor::UsbHotplugMonitor(std::unique_ptr<UsbEventSource> source, Listener listener)
    : source_(std::move(source)), listener_(std::move(listener)) {}

UsbHotplugMonitor::~UsbHotplugMonitor() { Stop(); }

DriverStatus UsbHotplugMonitor::Start() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (started_)
      return DriverStatus::Error(StatusCode::kWrongState, "USB hot-plug monitor already started");
    if (!source_)
      return DriverStatus::Error(StatusCode::kInvalidArgument,
                                 "USB hot-plug monitor has no event source");
    started_ = true;
    stopped_ = false;
  }
  DriverStatus s = source_->Start([this](const UsbDeviceEvent& e) { OnEvent(e); });
  if (!s.ok()) {
    std::lock_guard<std::mutex> lock(mutex_);
    started_ = false;
  }
  return s;
}

void UsbHotplugMonitor::Stop() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (!started_) return;
    stopped_ = true;
    started_ = false;
  }
  changed_.notify_all();
  if (source_) source_->Stop();
}

void UsbHotplugMonitor::OnEvent(const UsbDeviceEvent& event) {
  UsbDeviceEvent report = event;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    const std::pair<int, int> port(event.bus, event.address);
    if (event.kind == UsbDeviceEvent::Kind::kArrived) {
      if (!event.is_usb3_vision) return;
      // A device without a readable serial is tracked by its port.
      const std::string key = event.serial.empty() ? "usb:" + std::to_string(event.bus) + ":" +
                                                         std::to_string(event.address)
                                                   : event.serial;
      by_port_[port] = key;
      if (!present_.insert(key).second) return;  // already known
      report.serial = key;
    } else {
      // Departures carry no descriptor strings: match by port.
      const auto it = by_port_.find(port);
      if (it == by_port_.end()) return;  // not a USB3 Vision device we saw
      report.serial = it->second;
      report.is_usb3_vision = true;
      present_.erase(it->second);
      by_port_.erase(it);
    }
  }
  changed_.notify_all();
  if (listener_) listener_(report);
}

std::vector<std::string> UsbHotplugMonitor::Present() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return {present_.begin(), present_.end()};
}

bool UsbHotplugMonitor::IsPresent(const std::string& serial) const {
  std::lock_guard<std::mutex> lock(mutex_);
  return present_.count(serial) > 0;
}

bool UsbHotplugMonitor::WaitForArrival(const std::string& serial,
                                       std::chrono::milliseconds timeout) {
  std::unique_lock<std::mutex> lock(mutex_);
  changed_.wait_for(lock, timeout, [&] { return stopped_ || present_.count(serial) > 0; });
  return !stopped_ && present_.count(serial) > 0;
}

}  // namespace craftscan::drivers
