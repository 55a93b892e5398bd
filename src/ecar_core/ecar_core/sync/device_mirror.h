// The server's mirror of one device's keyframe queue (ecar mode): which map
// points the device holds, at which version and position. The server cannot
// see the device's map, so it mirrors it: each local graph with a tracked pose
// becomes one keyframe on the device holding all its points; the device keeps
// the last `queue_length` such keyframes; a point leaves the device when no
// queued keyframe holds it any more (device/device_keyframe_queue.h is the
// device's side of the same rule).
//
//   DeviceMirror mirror(10);
//   if (!mirror.holds(id)) { send its position; mirror.setHeld(id, version, p_w); }
//   mirror.pushKeyFrame(ids_of_the_graph);
//
// Not thread-safe: the caller serialises the calls for one device.
#pragma once

#include <cstddef>
#include <cstdint>
#include <deque>
#include <unordered_map>
#include <vector>

#include <Eigen/Core>

#include "ecar_core/common/types.h"

namespace ecar {

class DeviceMirror {
 public:
  /// `queue_length` keyframes (0 = 10).
  explicit DeviceMirror(size_t queue_length = 10);

  /// Forgets everything (the device reset or reconnected): all positions are sent again.
  void reset();
  /// Whether the device holds `id`; `version` and `p_w` receive the version
  /// and position it holds.
  bool holds(MapPointId id, uint32_t* version = nullptr, Eigen::Vector3f* p_w = nullptr) const;
  /// Records that the device now holds `id` at `version`, position `p_w` (it was sent).
  void setHeld(MapPointId id, uint32_t version,
               const Eigen::Vector3f& p_w = Eigen::Vector3f::Zero());
  /// One keyframe on the device holding `points`; evicts the oldest keyframe
  /// beyond the queue length, and with it the points no queued keyframe holds.
  /// Every point must have been recorded with setHeld() (others are ignored).
  void pushKeyFrame(const std::vector<MapPointId>& points);

  size_t queueLength() const { return queue_length_; }
  size_t numKeyFrames() const { return queue_.size(); }
  size_t numPoints() const { return held_.size(); }

 private:
  struct Held {
    Eigen::Vector3f p_w = Eigen::Vector3f::Zero();
    uint32_t version = 0;
    int keyframes = 0;  ///< queued keyframes holding the point
  };
  size_t queue_length_;
  std::deque<std::vector<MapPointId>> queue_;
  std::unordered_map<MapPointId, Held> held_;
};

}  // namespace ecar
