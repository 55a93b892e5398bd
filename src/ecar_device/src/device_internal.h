// Private to the Device implementation (device.cpp, device_interaction.cpp).
#pragma once

namespace ecar_device::device_internal {

constexpr double kWarnPeriod = 2.0;  ///< s between repeated warnings of one kind

}  // namespace ecar_device::device_internal
