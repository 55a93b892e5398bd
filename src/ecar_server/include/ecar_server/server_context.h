// What the nodelets of one edge server share (they run in one process): the
// SLAM system (the global graph), the device registry and each device's
// mirror. ROS-free, so the registry logic is tested without roscore.
//
//   auto ctx = ServerContext::get("/edge_server", config);  // one per key and process
//   ctx->addListener(this);                                 // device and SLAM events
//   ConnectResult r = ctx->connect("device_0", camera, "", 10, now);
//
// The SLAM system is created by the first accepted connect, with that
// device's camera; later devices must have the same camera.
#pragma once

#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "ecar_core/common/camera.h"
#include "ecar_core/sync/local_graph.h"
#include "ecar_core/slam/slam_system.h"
#include "ecar_core/common/types.h"
#include "ecar_server/config.h"
#include "ecar_server/structure.h"

namespace ecar_server {

/// A registered device.
struct DeviceInfo {
  std::string name;   ///< also its topic namespace
  ecar::DeviceId id;  ///< stable for the name over the server's lifetime
  ecar::SyncMode mode = ecar::SyncMode::kEcar;
  size_t keyframe_queue = 10;
};

/// Receives registry events. Calls are serialised (one event at a time) and
/// made without the context's data lock, so handlers may query the context;
/// they must not connect or remove devices.
class ContextListener {
 public:
  virtual ~ContextListener() = default;
  /// The SLAM system was created (before the first device is added).
  virtual void onSlamCreated(const std::shared_ptr<ecar::SlamSystem>& /*slam*/) {}
  virtual void onDeviceAdded(const DeviceInfo& /*device*/) {}
  virtual void onDeviceRemoved(const DeviceInfo& /*device*/) {}
};

struct ConnectResult {
  bool accepted = false;
  bool reconnected = false;  ///< it was connected already: its mirror was reset
  std::string message;
  DeviceInfo device;
};

class ServerContext {
 public:
  /// `start_epoch`: the map epoch before any reset; make it differ between
  /// server starts (e.g. from the wall clock).
  ServerContext(const ServerConfig& config, uint32_t start_epoch);
  ServerContext(const ServerContext&) = delete;
  ServerContext& operator=(const ServerContext&) = delete;

  /// The process-wide context of `key` (e.g. the manager's namespace),
  /// created with `config` by the first caller; later callers share it (their
  /// config is ignored). It lives while someone holds it.
  static std::shared_ptr<ServerContext> get(const std::string& key, const ServerConfig& config);

  const ServerConfig& config() const { return config_; }

  /// Registers (or re-registers, which resets its mirror) a device. Refused:
  /// an invalid name, an unknown sync mode, a camera unlike the SLAM's.
  /// `now` in seconds on any monotonic clock (the same as touch()'s).
  ConnectResult connect(const std::string& name, const ecar::PinholeCamera& camera,
                        const std::string& sync_mode, uint32_t keyframe_queue, double now);
  /// Unregisters a device; false when it was not registered.
  bool disconnect(const std::string& name);
  /// Unregisters every device silent for more than config().device_timeout;
  /// returns their names.
  std::vector<std::string> removeSilent(double now);
  /// Marks the device as heard from; false when it is not registered.
  bool touch(const std::string& name, double now);

  std::optional<DeviceInfo> device(const std::string& name) const;
  std::vector<DeviceInfo> devices() const;
  /// Name of a device id ever registered, empty when unknown.
  std::string deviceName(ecar::DeviceId id) const;

  /// Null until the first device connected (or a map was loaded).
  std::shared_ptr<ecar::SlamSystem> slam() const;
  /// The SLAM system, created with `camera` (listeners get onSlamCreated) when
  /// there is none yet, e.g. to load a map before any device connected. Throws
  /// ecar::Error when it exists with another camera.
  std::shared_ptr<ecar::SlamSystem> slamFor(const ecar::PinholeCamera& camera);
  /// Differs on every server start and every map reset.
  uint32_t mapEpoch() const;

  /// Planes, grid links and virtual objects (thread-safe on its own).
  Structure& structure() { return *structure_; }

  /// Runs `f` on the device's mirror under its lock; false when the device
  /// is not registered.
  bool withMirror(const std::string& name, const std::function<void(ecar::DeviceMirror&)>& f);
  /// Forgets what the device holds (Upload.reset); false when not registered.
  bool resetMirror(const std::string& name);
  /// Forgets what every device holds (a map was loaded: its ids mean other points).
  void resetMirrors();

  // ---- map replacement (MapStorage) and the graphs in flight
  /// A map load begins: until mapReplaced() or mapReplaceFailed(), every
  /// tracked frame's graph is dropped (mapStale).
  void beginMapReplace();
  /// The load finished at `now` (the clock of TrackedFrame.server_received, s).
  void mapReplaced(double now);
  /// The load failed: nothing was replaced.
  void mapReplaceFailed();
  /// True when a graph for an upload received at `received` (s) must not be
  /// published: a load is running, or the upload arrived before the last
  /// load finished (it may have been tracked in the old map, whose ids and
  /// coordinates the new epoch does not share). Its device gets the next one.
  bool mapStale(double received) const;

  /// Adds a listener and replays the current state to it (onSlamCreated,
  /// onDeviceAdded for each device). The listener must outlive its registration.
  void addListener(ContextListener* listener);
  void removeListener(ContextListener* listener);

 private:
  struct Slot {
    DeviceInfo info;
    double last_seen = 0.0;
    std::shared_ptr<std::mutex> mirror_mutex = std::make_shared<std::mutex>();
    std::shared_ptr<ecar::DeviceMirror> mirror;
  };
  /// Camera check against the SLAM's; empty when compatible.
  std::string cameraMismatch(const ecar::PinholeCamera& camera) const;  // mutex_ held
  void removeLocked(const std::string& name, std::vector<DeviceInfo>* removed);

  const ServerConfig config_;
  const uint32_t start_epoch_;
  const std::unique_ptr<Structure> structure_;

  mutable std::mutex mutex_;  // guards everything below but listeners_
  std::shared_ptr<ecar::SlamSystem> slam_;
  std::map<std::string, Slot> devices_;
  std::map<std::string, ecar::DeviceId> ids_;  ///< every name ever registered
  uint32_t next_id_ = 1;
  int replacing_ = 0;              ///< loads running
  double replaced_at_ = -1.0e300;  ///< when the last load finished

  std::mutex events_mutex_;  // serialises event delivery; guards listeners_
  std::vector<ContextListener*> listeners_;
};

}  // namespace ecar_server
