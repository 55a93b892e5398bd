// The edge server's devices: who is connected, with which sync mode and
// keyframe queue, each with a stable DeviceId and a session token, and who fell
// silent.
//
//   DeviceRegistry registry(config);
//   DeviceConnectResult r = registry.connect("device_0", "", 10, now, 0);
//   registry.touch("device_0", r.device.session, now);  // on every upload: kOk?
//   for (const auto& name : registry.removeSilent(now)) { ... }
//
// Sessions: a connection gets a random 64-bit token, which every upload,
// interaction and disconnect must carry. A live device's name cannot be taken
// by a connect without its token (until it is silent for device_timeout), so
// a rogue or mistaken node on the network cannot reset, disconnect or speak
// for another device. They protect against mistakes and rogue nodes, not
// against someone who reads the traffic (ROS 1 does not encrypt it).
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
  uint64_t session = 0;  ///< the connection's token (never 0)
};

struct DeviceRegistryConfig {
  SyncMode default_mode = SyncMode::kEcar;  ///< for a connect that names none
  size_t default_keyframe_queue = 10;       ///< for a connect that says 0
  double device_timeout = 10.0;             ///< s of silence before a device is dropped
  size_t max_devices = 64;                  ///< connected at once; more are refused
};

/// What a device's token says (DeviceRegistry::touch, check).
enum class SessionCheck {
  kOk,
  kNotConnected,  ///< no such device connected
  kWrongSession,  ///< connected under another token
};

/// Why a SessionCheck other than kOk refuses, for messages.
const char* toString(SessionCheck check);

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
  /// most 64) and not a reserved one (isReserved); a mode "", "ecar" or
  /// "edgeslam".
  static std::string refusal(const std::string& name, const std::string& sync_mode);
  /// Names of the server's own namespaces and users ("ecar", "rviz",
  /// "edge_server", ROS's "rosout", "tf", "tf_static", "clock"), never a device's.
  static bool isReserved(const std::string& name);

  /// Registers a device, or re-registers a connected one that gives its
  /// `session` token (keeping the token). Refused: as refusal() says; a
  /// connected name with another token (until device_timeout of silence);
  /// max_devices connected. `now` in seconds on any monotonic clock (the same
  /// as touch()'s). A new connection gets a new random token.
  DeviceConnectResult connect(const std::string& name, const std::string& sync_mode,
                              uint32_t keyframe_queue, double now, uint64_t session = 0);
  /// Unregisters a device whose token is `session`; its info when it was.
  std::optional<DeviceInfo> disconnect(const std::string& name, uint64_t session,
                                       SessionCheck* check = nullptr);
  /// Unregisters every device silent for more than device_timeout.
  std::vector<DeviceInfo> removeSilent(double now);
  /// Marks the device as heard from when `session` is its token.
  SessionCheck touch(const std::string& name, uint64_t session, double now);
  /// Whether `session` is the connected device's token, without touching it.
  SessionCheck check(const std::string& name, uint64_t session) const;

  std::optional<DeviceInfo> device(const std::string& name) const;
  std::vector<DeviceInfo> devices() const;
  /// Name of a device id ever registered (and not forgotten), empty when unknown.
  std::string name(DeviceId id) const;
  /// Drops the id of `name` while it is not connected (its device made no
  /// keyframe: nothing refers to the id); a later connect gets a new id.
  /// False when it is connected or unknown.
  bool forget(const std::string& name);
  /// Names with an id (connected or not): what the registry holds.
  size_t numKnownNames() const;
  const DeviceRegistryConfig& config() const { return config_; }

 private:
  struct Slot {
    DeviceInfo info;
    double last_seen = 0.0;
  };
  const DeviceRegistryConfig config_;
  mutable std::mutex mutex_;  // guards everything below
  std::map<std::string, Slot> devices_;
  std::map<std::string, DeviceId> ids_;  ///< names registered and not forgotten
  uint32_t next_id_ = 1;
};

}  // namespace ecar
