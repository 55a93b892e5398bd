// GlobalGraph's devices: connecting (each with its own camera), disconnecting,
// the timeout, and forgetting a device that is gone without a keyframe, so that
// what the server holds per device name stays bounded.
#include <string>
#include <vector>

#include "ecar_core/server/global_graph.h"

namespace ecar {

DeviceConnectResult GlobalGraph::connect(const std::string& name, const PinholeCamera& camera,
                                         const std::string& sync_mode, uint32_t keyframe_queue,
                                         double now, uint64_t session) {
  DeviceConnectResult result;
  result.message = DeviceRegistry::refusal(name, sync_mode);
  if (!result.message.empty()) return result;
  const std::shared_ptr<Atlas> atlas = atlasFor(camera);
  std::lock_guard<std::mutex> events(events_mutex_);
  result = devices_.connect(name, sync_mode, keyframe_queue, now, session);
  if (result.accepted) {
    // Each device tracks with its own camera; its keyframes carry it.
    atlas->setCamera(result.device.id, camera, config_.camera_tolerance);
    std::lock_guard<std::mutex> lock(mutex_);
    CameraPtr shared;
    for (const auto& [id, c] : cameras_) {
      if (!shared && c->difference(camera, config_.camera_tolerance).empty()) shared = c;
    }
    cameras_[result.device.id] = shared ? shared : std::make_shared<const PinholeCamera>(camera);
  }
  if (result.accepted && !result.reconnected) {
    for (GraphListener* l : listeners_) l->onDeviceAdded(result.device);
  }
  return result;
}

SessionCheck GlobalGraph::disconnect(const std::string& name, uint64_t session) {
  std::lock_guard<std::mutex> events(events_mutex_);
  SessionCheck check = SessionCheck::kOk;
  const std::optional<DeviceInfo> removed = devices_.disconnect(name, session, &check);
  if (removed) {
    for (GraphListener* l : listeners_) l->onDeviceRemoved(*removed);
  }
  return check;
}

std::vector<std::string> GlobalGraph::removeSilent(double now) {
  std::lock_guard<std::mutex> events(events_mutex_);
  std::vector<std::string> names;
  for (const DeviceInfo& d : devices_.removeSilent(now)) {
    names.push_back(d.name);
    for (GraphListener* l : listeners_) l->onDeviceRemoved(d);
  }
  return names;
}

void GlobalGraph::removeDevice(DeviceId device) {
  // Called from onDeviceRemoved listeners (under events_mutex_): no lock of
  // this class but mutex_ is taken here.
  const std::shared_ptr<Atlas> atlas = this->atlas();
  if (atlas) atlas->removeDevice(device);
  const std::string name = devices_.name(device);
  if (name.empty() || (atlas && atlas->hasKeyFramesOf(device))) return;  // its keyframes name it
  // Atomically "not connected (again)": from here on a connect of the name
  // gets a new id, so nothing uses this one's cameras.
  if (!devices_.forget(name)) return;
  if (atlas) atlas->forgetDevice(device);
  std::lock_guard<std::mutex> lock(mutex_);
  cameras_.erase(device);
}

CameraPtr GlobalGraph::camera(const std::string& device) const {
  const std::optional<DeviceInfo> info = devices_.device(device);
  std::lock_guard<std::mutex> lock(mutex_);
  if (info) {
    const auto it = cameras_.find(info->id);
    if (it != cameras_.end()) return it->second;
  }
  return first_camera_;
}

}  // namespace ecar
