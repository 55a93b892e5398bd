// Private to the Device implementation (device.cpp, device_connection.cpp,
// device_interaction.cpp, device_light.cpp).
#pragma once

#include <cstddef>

namespace ecar_device::device_internal {

constexpr double kWarnPeriod = 2.0;   ///< s between repeated warnings of one kind
constexpr size_t kOdometryKept = 64;  ///< recent odometry poses kept by stamp

}  // namespace ecar_device::device_internal
