// The nodelet ecar_device/Device: the same Device as device_node, in a manager.
#include <memory>

#include <nodelet/nodelet.h>
#include <pluginlib/class_list_macros.hpp>

#include "ecar_core/common/error.h"
#include "ecar_device/device.h"

namespace ecar_device {

class DeviceNodelet : public nodelet::Nodelet {
 private:
  void onInit() override {
    try {
      device_ = std::make_unique<Device>(
          getNodeHandle(), getPrivateNodeHandle(),
          loadDeviceConfig(getPrivateNodeHandle(), getNodeHandle().getNamespace()));
    } catch (const ecar::Error& e) {
      NODELET_FATAL("%s", e.what());
      throw;
    }
  }

  std::unique_ptr<Device> device_;
};

}  // namespace ecar_device

PLUGINLIB_EXPORT_CLASS(ecar_device::DeviceNodelet, nodelet::Nodelet)
