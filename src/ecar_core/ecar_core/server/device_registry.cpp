#include "ecar_core/server/device_registry.h"

#include <algorithm>
#include <array>
#include <cctype>
#include <random>

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

/// A random non-zero token from the system's entropy source.
uint64_t newSession() {
  thread_local std::random_device source;  // getrandom() on Linux
  uint64_t token = 0;
  while (token == 0) {
    token = (static_cast<uint64_t>(source()) << 32) ^ static_cast<uint64_t>(source());
  }
  return token;
}

}  // namespace

const char* toString(SessionCheck check) {
  switch (check) {
    case SessionCheck::kOk:
      return "ok";
    case SessionCheck::kNotConnected:
      return "not connected";
    case SessionCheck::kWrongSession:
      return "wrong session token";
  }
  return "?";
}

bool DeviceRegistry::isReserved(const std::string& name) {
  static const std::array<const char*, 7> kReserved = {"ecar", "rviz",      "edge_server", "rosout",
                                                       "tf",   "tf_static", "clock"};
  return std::any_of(kReserved.begin(), kReserved.end(), [&](const char* r) { return name == r; });
}

std::string DeviceRegistry::refusal(const std::string& name, const std::string& sync_mode) {
  if (!validDeviceName(name)) {
    return "device_id '" + name.substr(0, 80) +
           "' is not a valid name (a letter, then letters, digits or '_', at most 64)";
  }
  if (isReserved(name)) {
    return "device_id '" + name + "' is reserved (a server namespace or user)";
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
                                            uint32_t keyframe_queue, double now, uint64_t session) {
  DeviceConnectResult result;
  result.message = refusal(name, sync_mode);
  if (!result.message.empty()) return result;
  const SyncMode mode = sync_mode.empty() ? config_.default_mode : parseSyncMode(sync_mode);
  const size_t queue = keyframe_queue > 0 ? keyframe_queue : config_.default_keyframe_queue;
  std::lock_guard<std::mutex> lock(mutex_);
  auto it = devices_.find(name);
  result.reconnected = it != devices_.end();
  if (result.reconnected && it->second.info.session != session &&
      now - it->second.last_seen <= config_.device_timeout) {
    result.message = "device '" + name +
                     "' is connected in another session: connect with its session token, or "
                     "after it has been silent for device_timeout (" +
                     std::to_string(static_cast<int>(config_.device_timeout)) + " s)";
    return result;
  }
  if (!result.reconnected && devices_.size() >= config_.max_devices) {
    result.message = std::to_string(devices_.size()) +
                     " devices are connected, the most the server takes (max_devices)";
    return result;
  }
  auto id_it = ids_.find(name);
  if (id_it == ids_.end()) id_it = ids_.emplace(name, DeviceId(next_id_++)).first;
  if (!result.reconnected) it = devices_.emplace(name, Slot{}).first;
  Slot& slot = it->second;
  // A silent device's name taken over (its token unknown): a new session.
  const bool same_session = result.reconnected && slot.info.session == session;
  slot.info = DeviceInfo{name, id_it->second, mode, queue, same_session ? session : newSession()};
  slot.last_seen = now;
  result.accepted = true;
  result.device = slot.info;
  result.message = std::string(result.reconnected ? "reconnected" : "connected") + " as " + name +
                   " (sync_mode " + toString(mode) + ", keyframe queue " + std::to_string(queue) +
                   ")";
  return result;
}

std::optional<DeviceInfo> DeviceRegistry::disconnect(const std::string& name, uint64_t session,
                                                     SessionCheck* check) {
  std::lock_guard<std::mutex> lock(mutex_);
  const auto it = devices_.find(name);
  SessionCheck result = SessionCheck::kOk;
  if (it == devices_.end()) {
    result = SessionCheck::kNotConnected;
  } else if (it->second.info.session != session) {
    result = SessionCheck::kWrongSession;
  }
  if (check != nullptr) *check = result;
  if (result != SessionCheck::kOk) return std::nullopt;
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

SessionCheck DeviceRegistry::touch(const std::string& name, uint64_t session, double now) {
  std::lock_guard<std::mutex> lock(mutex_);
  const auto it = devices_.find(name);
  if (it == devices_.end()) return SessionCheck::kNotConnected;
  if (it->second.info.session != session) return SessionCheck::kWrongSession;
  it->second.last_seen = std::max(it->second.last_seen, now);
  return SessionCheck::kOk;
}

SessionCheck DeviceRegistry::check(const std::string& name, uint64_t session) const {
  std::lock_guard<std::mutex> lock(mutex_);
  const auto it = devices_.find(name);
  if (it == devices_.end()) return SessionCheck::kNotConnected;
  return it->second.info.session == session ? SessionCheck::kOk : SessionCheck::kWrongSession;
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

bool DeviceRegistry::forget(const std::string& name) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (devices_.count(name)) return false;
  return ids_.erase(name) > 0;
}

size_t DeviceRegistry::numKnownNames() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return ids_.size();
}

std::string DeviceRegistry::name(DeviceId id) const {
  std::lock_guard<std::mutex> lock(mutex_);
  for (const auto& [name, known] : ids_) {
    if (known == id) return name;
  }
  return {};
}

}  // namespace ecar
