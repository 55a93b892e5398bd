// The device's local map in ecar mode: the last `capacity` keyframes built
// from local graphs (the server's keypoints of each aligned upload, with the
// device's own descriptors at them), with per-point observation counts and
// the positions the graphs brought. The server mirrors the same rule
// (sync/device_mirror.h) to know which positions the device holds.
//
//   DeviceKeyFrameQueue queue(10);
//   QueueInsertResult r = queue.insert(keyframe, graph.positions);
//   if (!r.missing.empty()) { /* ask the server for every position (Upload.reset) */ }
//
// Not thread-safe.
#pragma once

#include <cstdint>
#include <deque>
#include <unordered_map>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "ecar_core/common/geometry.h"
#include "ecar_core/common/types.h"
#include "ecar_core/sync/local_graph.h"

namespace ecar {

/// One keyframe of the device's queue (ecar mode): the server's keypoints of
/// the aligned image with the device's own descriptors at them.
struct DeviceKeyFrame {
  uint32_t frame_index = 0;
  SE3 T_w_c = SE3::Identity();          ///< server pose
  std::vector<MapPointId> point_ids;    ///< one per keypoint
  std::vector<cv::KeyPoint> keypoints;  ///< as the server sent them
  cv::Mat descriptors;                  ///< N x 32, CV_8U, from the device's image
  std::vector<uint8_t> valid;           ///< 1 where a descriptor could be computed
};

/// What one insertion changed.
struct QueueInsertResult {
  int evicted_keyframes = 0;  ///< oldest keyframes pushed out of the queue
  int deleted_points = 0;     ///< points no keyframe held any more
  int new_positions = 0;      ///< positions stored or updated
  /// Points the keyframe names whose position the device does not hold (a
  /// missed graph, or a server mirror out of step): the device must ask the
  /// server for every position again (Upload.reset).
  std::vector<MapPointId> missing;
};

/// The last `capacity` keyframes with per-point observation counts and
/// positions. A point lives while at least one queued keyframe holds it.
class DeviceKeyFrameQueue {
 public:
  /// Throws ecar::Error when capacity < 1.
  explicit DeviceKeyFrameQueue(int capacity = 10);

  /// Stores the positions (new or newer), appends the keyframe (each of its
  /// points' observation count + 1), then evicts the oldest keyframes beyond
  /// the capacity (their points' counts - 1; a point at zero is deleted with
  /// its position). Positions of points that no queued keyframe holds are not
  /// kept. Insert-then-evict: a point the new keyframe shares with the evicted
  /// one keeps its position.
  QueueInsertResult insert(DeviceKeyFrame keyframe, const std::vector<GraphPosition>& positions);
  /// Drops every keyframe and point (map epoch changed).
  void clear();

  int capacity() const { return capacity_; }
  size_t size() const { return keyframes_.size(); }
  bool empty() const { return keyframes_.empty(); }
  /// Points held (with or without a position).
  size_t numPoints() const { return points_.size(); }
  /// Oldest first.
  const std::deque<DeviceKeyFrame>& keyframes() const { return keyframes_; }
  /// Queued keyframes holding the point (0: not held).
  int observations(MapPointId id) const;
  /// The point's position, or null when the device does not hold one.
  const Eigen::Vector3d* position(MapPointId id) const;

 private:
  struct PointEntry {
    Eigen::Vector3d p_w = Eigen::Vector3d::Zero();
    bool has_position = false;
    int observations = 0;
  };
  void evictOldest(QueueInsertResult* result);

  int capacity_;
  std::deque<DeviceKeyFrame> keyframes_;
  std::unordered_map<MapPointId, PointEntry> points_;
};

}  // namespace ecar
