#include "ecar_core/device/device_keyframe_queue.h"

#include <string>

#include "ecar_core/common/error.h"

namespace ecar {

DeviceKeyFrameQueue::DeviceKeyFrameQueue(int capacity) : capacity_(capacity) {
  if (capacity < 1) throw Error("keyframe_queue: must be >= 1, got " + std::to_string(capacity));
}

QueueInsertResult DeviceKeyFrameQueue::insert(DeviceKeyFrame keyframe,
                                              const std::vector<GraphPosition>& positions) {
  QueueInsertResult result;
  for (const MapPointId& id : keyframe.point_ids) {
    if (id.valid()) ++points_[id].observations;
  }
  for (const GraphPosition& p : positions) {
    auto it = points_.find(p.id);
    if (it == points_.end()) continue;  // no keyframe holds it
    it->second.p_w = p.p_w.cast<double>();
    it->second.has_position = true;
    ++result.new_positions;
  }
  for (const MapPointId& id : keyframe.point_ids) {
    if (!id.valid()) continue;
    if (!points_[id].has_position) result.missing.push_back(id);
  }
  keyframes_.push_back(std::move(keyframe));
  while (static_cast<int>(keyframes_.size()) > capacity_) evictOldest(&result);
  return result;
}

void DeviceKeyFrameQueue::evictOldest(QueueInsertResult* result) {
  for (const MapPointId& id : keyframes_.front().point_ids) {
    auto it = points_.find(id);
    if (it == points_.end()) continue;
    if (--it->second.observations <= 0) {
      points_.erase(it);
      ++result->deleted_points;
    }
  }
  keyframes_.pop_front();
  ++result->evicted_keyframes;
}

void DeviceKeyFrameQueue::clear() {
  keyframes_.clear();
  points_.clear();
}

int DeviceKeyFrameQueue::observations(MapPointId id) const {
  const auto it = points_.find(id);
  return it == points_.end() ? 0 : it->second.observations;
}

const Eigen::Vector3d* DeviceKeyFrameQueue::position(MapPointId id) const {
  const auto it = points_.find(id);
  return it == points_.end() || !it->second.has_position ? nullptr : &it->second.p_w;
}

}  // namespace ecar
