#include "ecar_core/server/device_registry.h"

#include <algorithm>
#include <cctype>

#include "ecar_core/common/error.h"

namespace ecar {
namespace {

// A ROS name component: a letter, then letters, digits and underscores.
bool validDeviceName(const std::string& name) {
  if (name.empty() || name.size() > 64 || !std::isalpha(static_cast<unsigned char>(name[0]))) {
    return false;
  }
  return std::all_of(name.begin(), name.end(), [](char c) {
    return std::isalnum(static_cast<unsigned char>(c)) || c == '_';
  });
}

}  // namespace

std::string DeviceRegistry::refusal(const std::string& name, const std::string& sync_mode) {
  if (!validDeviceName(name)) {
    return "device_id '" + name + "' is not a valid name (a letter, then letters, digits or '_')";
  }
  if (!sync_mode.empty()) {
    try {
      parseSyncMode(sync_mode);
    } catch (const Error& e) {
      return e.what();
    }
  }
  return {};
}

DeviceConnectResult DeviceRegistry::connect(const std::string& name, const std::string& sync_mode,
                                            uint32_t keyframe_queue, double now) {
  DeviceConnectResult result;
  result.message = refusal(name, sync_mode);
  if (!result.message.empty()) return result;
  const SyncMode mode = sync_mode.empty() ? config_.default_mode : parseSyncMode(sync_mode);
  const size_t queue = keyframe_queue > 0 ? keyframe_queue : config_.default_keyframe_queue;
  std::lock_guard<std::mutex> lock(mutex_);
  auto id_it = ids_.find(name);
  if (id_it == ids_.end()) id_it = ids_.emplace(name, DeviceId(next_id_++)).first;
  auto it = devices_.find(name);
  result.reconnected = it != devices_.end();
  if (!result.reconnected) it = devices_.emplace(name, Slot{}).first;
  Slot& slot = it->second;
  slot.info = DeviceInfo{name, id_it->second, mode, queue};
  slot.last_seen = now;
  result.accepted = true;
  result.device = slot.info;
  result.message = std::string(result.reconnected ? "reconnected" : "connected") + " as " + name +
                   " (sync_mode " + toString(mode) + ", keyframe queue " + std::to_string(queue) +
                   ")";
  return result;
}

std::optional<DeviceInfo> DeviceRegistry::disconnect(const std::string& name) {
  std::lock_guard<std::mutex> lock(mutex_);
  const auto it = devices_.find(name);
  if (it == devices_.end()) return std::nullopt;
  const DeviceInfo info = it->second.info;
  devices_.erase(it);
  return info;
}

std::vector<DeviceInfo> DeviceRegistry::removeSilent(double now) {
  std::lock_guard<std::mutex> lock(mutex_);
  std::vector<DeviceInfo> removed;
  for (auto it = devices_.begin(); it != devices_.end();) {
    if (now - it->second.last_seen > config_.device_timeout) {
      removed.push_back(it->second.info);
      it = devices_.erase(it);
    } else {
      ++it;
    }
  }
  return removed;
}

bool DeviceRegistry::touch(const std::string& name, double now) {
  std::lock_guard<std::mutex> lock(mutex_);
  const auto it = devices_.find(name);
  if (it == devices_.end()) return false;
  it->second.last_seen = std::max(it->second.last_seen, now);
  return true;
}

std::optional<DeviceInfo> DeviceRegistry::device(const std::string& name) const {
  std::lock_guard<std::mutex> lock(mutex_);
  const auto it = devices_.find(name);
  if (it == devices_.end()) return std::nullopt;
  return it->second.info;
}

std::vector<DeviceInfo> DeviceRegistry::devices() const {
  std::lock_guard<std::mutex> lock(mutex_);
  std::vector<DeviceInfo> out;
  for (const auto& kv : devices_) out.push_back(kv.second.info);
  return out;
}

std::string DeviceRegistry::name(DeviceId id) const {
  std::lock_guard<std::mutex> lock(mutex_);
  for (const auto& [name, known] : ids_) {
    if (known == id) return name;
  }
  return {};
}

}  // namespace ecar
