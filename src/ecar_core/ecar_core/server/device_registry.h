// The edge server's devices: who is connected, with which sync mode and
// keyframe queue, each with a stable DeviceId, and who fell silent.
//
//   DeviceRegistry registry(config);
//   DeviceConnectResult r = registry.connect("device_0", "", 10, now);
//   registry.touch("device_0", now);                    // on every upload
//   for (const auto& name : registry.removeSilent(now)) { ... }
//
// Cameras (each device's own, given to the SLAM) and the creation of the SLAM
// system are the global graph's (GlobalGraph::connect). Thread-safe: one mutex.
#pragma once

#include <cstddef>
#include <cstdint>
#include <map>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "ecar_core/common/types.h"
#include "ecar_core/sync/local_graph.h"

namespace ecar {

/// A registered device.
struct DeviceInfo {
  std::string name;  ///< also its topic namespace
  DeviceId id;       ///< stable for the name over the server's lifetime
  SyncMode mode = SyncMode::kEcar;
  size_t keyframe_queue = 10;
};

struct DeviceRegistryConfig {
  SyncMode default_mode = SyncMode::kEcar;  ///< for a connect that names none
  size_t default_keyframe_queue = 10;       ///< for a connect that says 0
  double device_timeout = 10.0;             ///< s of silence before a device is dropped
};

struct DeviceConnectResult {
  bool accepted = false;
  bool reconnected = false;  ///< it was connected already
  std::string message;       ///< what happened, or why it was refused
  DeviceInfo device;
};

class DeviceRegistry {
 public:
  explicit DeviceRegistry(const DeviceRegistryConfig& config) : config_(config) {}

  /// Why `name` or `sync_mode` cannot connect (empty when they can): a name
  /// must be a ROS name component (a letter, then letters, digits or '_', at
  /// most 64); a mode "", "ecar" or "edgeslam".
  static std::string refusal(const std::string& name, const std::string& sync_mode);

  /// Registers (or re-registers) a device; refused as refusal() says. `now` in
  /// seconds on any monotonic clock (the same as touch()'s).
  DeviceConnectResult connect(const std::string& name, const std::string& sync_mode,
                              uint32_t keyframe_queue, double now);
  /// Unregisters a device; its info when it was registered.
  std::optional<DeviceInfo> disconnect(const std::string& name);
  /// Unregisters every device silent for more than device_timeout.
  std::vector<DeviceInfo> removeSilent(double now);
  /// Marks the device as heard from; false when it is not registered.
  bool touch(const std::string& name, double now);

  std::optional<DeviceInfo> device(const std::string& name) const;
  std::vector<DeviceInfo> devices() const;
  /// Name of a device id ever registered, empty when unknown.
  std::string name(DeviceId id) const;
  const DeviceRegistryConfig& config() const { return config_; }

 private:
  struct Slot {
    DeviceInfo info;
    double last_seen = 0.0;
  };
  const DeviceRegistryConfig config_;
  mutable std::mutex mutex_;  // guards everything below
  std::map<std::string, Slot> devices_;
  std::map<std::string, DeviceId> ids_;  ///< every name ever registered
  uint32_t next_id_ = 1;
};

}  // namespace ecar
