// device_node: one eCAR device in its namespace (see ecar_device/device.h,
// launch/device.launch and config/device.yaml).
#include <ros/ros.h>

#include "ecar_core/common/error.h"
#include "ecar_device/device.h"

int main(int argc, char** argv) {
  ros::init(argc, argv, "device");
  ros::NodeHandle nh;
  ros::NodeHandle pnh("~");
  try {
    ecar_device::Device device(nh, pnh, ecar_device::loadDeviceConfig(pnh, nh.getNamespace()));
    ros::spin();
  } catch (const ecar::Error& e) {
    ROS_FATAL("%s: %s", ros::this_node::getName().c_str(), e.what());
    return 1;
  }
  return 0;
}
