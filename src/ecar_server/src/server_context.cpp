#include "ecar_server/server_context.h"

#include <algorithm>
#include <cctype>
#include <chrono>
#include <cmath>
#include <sstream>

#include "ecar_core/common/error.h"

namespace ecar_server {
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

const char* toString(VoShareMode mode) { return mode == VoShareMode::kDirect ? "direct" : "graph"; }

VoShareMode parseVoShareMode(const std::string& text) {
  if (text == "graph") return VoShareMode::kGraph;
  if (text == "direct") return VoShareMode::kDirect;
  throw ecar::Error("unknown vo share mode '" + text + "' (expected 'graph' or 'direct')");
}

void ServerConfig::validate() const {
  const auto fail = [](const std::string& key, const std::string& why) {
    throw ecar::Error("server parameter '" + key + "' " + why);
  };
  try {
    ecar::parseSyncMode(sync_mode);
  } catch (const ecar::Error&) {
    fail("sync_mode", "must be 'ecar' or 'edgeslam' (got '" + sync_mode + "')");
  }
  if (workers < 1 || workers > 64) fail("workers", "must be in [1, 64]");
  if (!(device_timeout > 0.0)) fail("device_timeout", "must be > 0 s");
  if (max_upload_bytes < 1000) fail("max_upload_bytes", "must be >= 1000");
  if (upload_queue_size < 1) fail("upload_queue_size", "must be >= 1");
  if (device_queue_size < 1) fail("device_queue_size", "must be >= 1");
  if (graph_queue_size < 1) fail("graph_queue_size", "must be >= 1");
  if (keyframe_queue < 1) fail("keyframe_queue", "must be >= 1");
  if (!(marker_rate >= 0.0) || marker_rate > 100.0) fail("marker_rate", "must be in [0, 100] Hz");
  if (!(position_tolerance >= 0.0) || position_tolerance > 0.1) {
    fail("position_tolerance", "must be in [0, 0.1] m");
  }
  if (!(position_tolerance_deg >= 0.0) || position_tolerance_deg > 10.0) {
    fail("position_tolerance_deg", "must be in [0, 10] degrees");
  }
  if (!(position_tolerance_depth >= 0.0) || position_tolerance_depth > 1.0) {
    fail("position_tolerance_depth", "must be in [0, 1]");
  }
  if (edgeslam_keyframes < 0) fail("edgeslam_keyframes", "must be >= 0");
  if (orb_features < 100 || orb_features > 100000) fail("orb_features", "must be in [100, 100000]");
  if (local_keyframes < 2) fail("local_keyframes", "must be >= 2");
  if (!(gravity_sigma_deg >= 0.0) || gravity_sigma_deg > 90.0) {
    fail("gravity_sigma_deg", "must be in [0, 90] degrees");
  }
  if (!(camera_tolerance >= 0.0)) fail("camera_tolerance", "must be >= 0");
  if (graph_plane_refresh < 1) throw ecar::Error("planes/graph_plane_refresh must be >= 1");
  planes.validate();
  grid.validate();
  try {
    vo.validate();
  } catch (const ecar::Error& e) {
    fail("vo", e.what());
  }
  if (vo.database_path.empty()) fail("vo.database", "must not be empty");
  if (!(vo_map_margin >= 0.0)) fail("vo.map_margin", "must be >= 0 m");
  try {
    parseVoShareMode(vo_share);
  } catch (const ecar::Error&) {
    fail("vo.share", "must be 'graph' or 'direct' (got '" + vo_share + "')");
  }
  if (!(vo_marker_drag_rate >= 0.0) || vo_marker_drag_rate > 100.0) {
    fail("vo.marker_drag_rate", "must be in [0, 100] Hz");
  }
}

ecar::SlamConfig ServerConfig::slamConfig() const {
  ecar::SlamConfig c;
  c.orb.num_features = orb_features;
  c.local_keyframes = local_keyframes;
  c.ba.gravity_sigma_deg = gravity_sigma_deg;
  c.synchronous_mapping = false;
  return c;
}

ecar::LocalGraphConfig ServerConfig::localGraphConfig() const {
  ecar::LocalGraphConfig c;
  c.edgeslam_keyframes = edgeslam_keyframes;
  c.position_tolerance = position_tolerance;
  c.position_tolerance_deg = position_tolerance_deg;
  c.position_tolerance_depth = position_tolerance_depth;
  return c;
}

ServerContext::ServerContext(const ServerConfig& config, uint32_t start_epoch)
    : config_(config), start_epoch_(start_epoch), structure_(std::make_unique<Structure>(config)) {
  config_.validate();
}

std::shared_ptr<ServerContext> ServerContext::get(const std::string& key,
                                                  const ServerConfig& config) {
  static std::mutex registry_mutex;
  static std::map<std::string, std::weak_ptr<ServerContext>> registry;
  std::lock_guard<std::mutex> lock(registry_mutex);
  std::shared_ptr<ServerContext> ctx = registry[key].lock();
  if (!ctx) {
    // Milliseconds of the wall clock: a restarted server has another epoch.
    const auto ms = std::chrono::duration_cast<std::chrono::milliseconds>(
                        std::chrono::system_clock::now().time_since_epoch())
                        .count();
    ctx = std::make_shared<ServerContext>(config, static_cast<uint32_t>(ms));
    registry[key] = ctx;
  }
  return ctx;
}

std::string ServerContext::cameraMismatch(const ecar::PinholeCamera& camera) const {
  const ecar::CameraParams& a = slam_->camera().params();
  const ecar::CameraParams& b = camera.params();
  std::ostringstream os;
  if (a.width != b.width || a.height != b.height) {
    os << "image size " << b.width << "x" << b.height << " differs from the SLAM camera's "
       << a.width << "x" << a.height;
    return os.str();
  }
  const double tol = config_.camera_tolerance;
  const auto off = [tol](double x, double y) { return std::abs(x - y) > tol * std::abs(y); };
  if (off(b.fx, a.fx) || off(b.fy, a.fy) || off(b.cx, a.cx) || off(b.cy, a.cy)) {
    os << "intrinsics fx " << b.fx << " fy " << b.fy << " cx " << b.cx << " cy " << b.cy
       << " differ from the SLAM camera's (fx " << a.fx << " fy " << a.fy << " cx " << a.cx
       << " cy " << a.cy << ")";
    return os.str();
  }
  for (size_t i = 0; i < a.dist.size(); ++i) {
    if (std::abs(a.dist[i] - b.dist[i]) > std::max(tol, 1e-9)) {
      os << "distortion coefficient " << i << " (" << b.dist[i] << ") differs from the SLAM "
         << "camera's (" << a.dist[i] << ")";
      return os.str();
    }
  }
  return {};
}

ConnectResult ServerContext::connect(const std::string& name, const ecar::PinholeCamera& camera,
                                     const std::string& sync_mode, uint32_t keyframe_queue,
                                     double now) {
  ConnectResult result;
  std::lock_guard<std::mutex> events(events_mutex_);
  std::shared_ptr<ecar::SlamSystem> created;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (!validDeviceName(name)) {
      result.message =
          "device_id '" + name + "' is not a valid name (a letter, then letters, digits or '_')";
      return result;
    }
    ecar::SyncMode mode = config_.syncMode();
    if (!sync_mode.empty()) {
      try {
        mode = ecar::parseSyncMode(sync_mode);
      } catch (const ecar::Error& e) {
        result.message = e.what();
        return result;
      }
    }
    if (slam_) {
      const std::string why = cameraMismatch(camera);
      if (!why.empty()) {
        result.message = "camera refused: " + why + " (all devices share one SLAM camera)";
        return result;
      }
    } else {
      slam_ = std::make_shared<ecar::SlamSystem>(camera, config_.slamConfig());
      created = slam_;
    }
    auto id_it = ids_.find(name);
    if (id_it == ids_.end()) id_it = ids_.emplace(name, ecar::DeviceId(next_id_++)).first;
    const size_t queue = keyframe_queue > 0 ? keyframe_queue : config_.keyframe_queue;
    auto it = devices_.find(name);
    if (it != devices_.end()) {
      Slot& slot = it->second;
      slot.info.mode = mode;
      slot.info.keyframe_queue = queue;
      slot.mirror = std::make_shared<ecar::DeviceMirror>(queue);
      slot.last_seen = now;
      result.reconnected = true;
      result.device = slot.info;
    } else {
      Slot slot;
      slot.info = DeviceInfo{name, id_it->second, mode, queue};
      slot.mirror = std::make_shared<ecar::DeviceMirror>(queue);
      slot.last_seen = now;
      result.device = slot.info;
      devices_.emplace(name, std::move(slot));
    }
    result.accepted = true;
    result.message = std::string(result.reconnected ? "reconnected" : "connected") + " as " + name +
                     " (sync_mode " + ecar::toString(mode) + ", keyframe queue " +
                     std::to_string(queue) + ")";
  }
  if (created) {
    for (ContextListener* l : listeners_) l->onSlamCreated(created);
  }
  if (!result.reconnected) {
    for (ContextListener* l : listeners_) l->onDeviceAdded(result.device);
  }
  return result;
}

void ServerContext::removeLocked(const std::string& name, std::vector<DeviceInfo>* removed) {
  const auto it = devices_.find(name);
  if (it == devices_.end()) return;
  removed->push_back(it->second.info);
  devices_.erase(it);
}

bool ServerContext::disconnect(const std::string& name) {
  std::lock_guard<std::mutex> events(events_mutex_);
  std::vector<DeviceInfo> removed;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    removeLocked(name, &removed);
  }
  for (const auto& d : removed) {
    for (ContextListener* l : listeners_) l->onDeviceRemoved(d);
  }
  return !removed.empty();
}

std::vector<std::string> ServerContext::removeSilent(double now) {
  std::lock_guard<std::mutex> events(events_mutex_);
  std::vector<DeviceInfo> removed;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    std::vector<std::string> silent;
    for (const auto& [name, slot] : devices_) {
      if (now - slot.last_seen > config_.device_timeout) silent.push_back(name);
    }
    for (const auto& name : silent) removeLocked(name, &removed);
  }
  std::vector<std::string> names;
  for (const auto& d : removed) {
    names.push_back(d.name);
    for (ContextListener* l : listeners_) l->onDeviceRemoved(d);
  }
  return names;
}

bool ServerContext::touch(const std::string& name, double now) {
  std::lock_guard<std::mutex> lock(mutex_);
  const auto it = devices_.find(name);
  if (it == devices_.end()) return false;
  it->second.last_seen = std::max(it->second.last_seen, now);
  return true;
}

std::optional<DeviceInfo> ServerContext::device(const std::string& name) const {
  std::lock_guard<std::mutex> lock(mutex_);
  const auto it = devices_.find(name);
  if (it == devices_.end()) return std::nullopt;
  return it->second.info;
}

std::vector<DeviceInfo> ServerContext::devices() const {
  std::lock_guard<std::mutex> lock(mutex_);
  std::vector<DeviceInfo> out;
  for (const auto& kv : devices_) out.push_back(kv.second.info);
  return out;
}

std::string ServerContext::deviceName(ecar::DeviceId id) const {
  std::lock_guard<std::mutex> lock(mutex_);
  for (const auto& [name, known] : ids_) {
    if (known == id) return name;
  }
  return {};
}

std::shared_ptr<ecar::SlamSystem> ServerContext::slam() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return slam_;
}

std::shared_ptr<ecar::SlamSystem> ServerContext::slamFor(const ecar::PinholeCamera& camera) {
  std::lock_guard<std::mutex> events(events_mutex_);
  std::shared_ptr<ecar::SlamSystem> created;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (slam_) {
      const std::string why = cameraMismatch(camera);
      if (!why.empty()) throw ecar::Error("the map's camera differs from the server's: " + why);
      return slam_;
    }
    slam_ = std::make_shared<ecar::SlamSystem>(camera, config_.slamConfig());
    created = slam_;
  }
  for (ContextListener* l : listeners_) l->onSlamCreated(created);
  return created;
}

uint32_t ServerContext::mapEpoch() const {
  std::shared_ptr<ecar::SlamSystem> slam = this->slam();
  if (!slam) return start_epoch_;
  auto lock = slam->map().readLock();
  return start_epoch_ + slam->map().epoch() - 1;
}

bool ServerContext::withMirror(const std::string& name,
                               const std::function<void(ecar::DeviceMirror&)>& f) {
  std::shared_ptr<std::mutex> mirror_mutex;
  std::shared_ptr<ecar::DeviceMirror> mirror;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    const auto it = devices_.find(name);
    if (it == devices_.end()) return false;
    mirror_mutex = it->second.mirror_mutex;
    mirror = it->second.mirror;  // a reconnect replaces it; this call finishes on the old one
  }
  std::lock_guard<std::mutex> mirror_lock(*mirror_mutex);
  f(*mirror);
  return true;
}

bool ServerContext::resetMirror(const std::string& name) {
  return withMirror(name, [](ecar::DeviceMirror& m) { m.reset(); });
}

void ServerContext::resetMirrors() {
  std::vector<std::string> names;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    for (const auto& kv : devices_) names.push_back(kv.first);
  }
  for (const auto& name : names) resetMirror(name);
}

void ServerContext::beginMapReplace() {
  std::lock_guard<std::mutex> lock(mutex_);
  ++replacing_;
}

void ServerContext::mapReplaced(double now) {
  std::lock_guard<std::mutex> lock(mutex_);
  --replacing_;
  replaced_at_ = std::max(replaced_at_, now);
}

void ServerContext::mapReplaceFailed() {
  std::lock_guard<std::mutex> lock(mutex_);
  --replacing_;
}

bool ServerContext::mapStale(double received) const {
  std::lock_guard<std::mutex> lock(mutex_);
  return replacing_ > 0 || received < replaced_at_;
}

void ServerContext::addListener(ContextListener* listener) {
  std::lock_guard<std::mutex> events(events_mutex_);
  listeners_.push_back(listener);
  std::shared_ptr<ecar::SlamSystem> slam;
  std::vector<DeviceInfo> devices;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    slam = slam_;
    for (const auto& kv : devices_) devices.push_back(kv.second.info);
  }
  if (slam) listener->onSlamCreated(slam);
  for (const auto& d : devices) listener->onDeviceAdded(d);
}

void ServerContext::removeListener(ContextListener* listener) {
  std::lock_guard<std::mutex> events(events_mutex_);
  listeners_.erase(std::remove(listeners_.begin(), listeners_.end(), listener), listeners_.end());
}

}  // namespace ecar_server
