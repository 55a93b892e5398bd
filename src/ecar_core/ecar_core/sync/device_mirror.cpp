#include "ecar_core/sync/device_mirror.h"

namespace ecar {

DeviceMirror::DeviceMirror(size_t queue_length)
    : queue_length_(queue_length == 0 ? 10 : queue_length) {}

void DeviceMirror::reset() {
  queue_.clear();
  held_.clear();
}

bool DeviceMirror::holds(MapPointId id, uint32_t* version, Eigen::Vector3f* p_w) const {
  const auto it = held_.find(id);
  if (it == held_.end()) return false;
  if (version) *version = it->second.version;
  if (p_w) *p_w = it->second.p_w;
  return true;
}

void DeviceMirror::setHeld(MapPointId id, uint32_t version, const Eigen::Vector3f& p_w) {
  Held& h = held_[id];
  h.version = version;
  h.p_w = p_w;
}

void DeviceMirror::pushKeyFrame(const std::vector<MapPointId>& points) {
  std::vector<MapPointId> kept;
  kept.reserve(points.size());
  for (const auto& id : points) {
    const auto it = held_.find(id);
    if (it == held_.end()) continue;
    ++it->second.keyframes;
    kept.push_back(id);
  }
  queue_.push_back(std::move(kept));
  while (queue_.size() > queue_length_) {
    for (const auto& id : queue_.front()) {
      const auto it = held_.find(id);
      if (it != held_.end() && --it->second.keyframes <= 0) held_.erase(it);
    }
    queue_.pop_front();
  }
  // Points recorded by setHeld() but in no keyframe (a graph that was not
  // pushed) are not on the device either.
  for (auto it = held_.begin(); it != held_.end();) {
    it = it->second.keyframes <= 0 ? held_.erase(it) : std::next(it);
  }
}

}  // namespace ecar
