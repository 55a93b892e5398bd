// The device side of eCAR: a small local map built from the server's local
// graphs, and tracking of every camera frame against it (DESIGN.md section 1,
// steps 2-3).
//
//   DeviceTracker tracker(camera, config);
//   tracker.addLocalGraph(own_gray_image_of_that_frame, graph);  // ecar mode
//   tracker.replaceLocalMap(full_map);                          // edgeslam mode
//   const DeviceTrackResult& r = tracker.track(gray, timestamp, frame_index);
//
// In ecar mode the server sends, per aligned upload, the map points it tracked
// in that image (id, keypoint, angle, octave) and positions only for points the
// device does not hold yet or whose position changed. The device computes the
// descriptors itself on its own uncompressed image at those keypoints, keeps
// the last `keyframe_queue` such keyframes (DeviceKeyFrameQueue) and tracks
// every frame by projection of the queue's points and a pose-only optimisation.
// Not thread-safe: one thread (or one lock) per tracker.
#pragma once

#include <cstdint>
#include <deque>
#include <string>
#include <unordered_map>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "ecar_core/camera.h"
#include "ecar_core/features.h"
#include "ecar_core/frame.h"
#include "ecar_core/geometry.h"
#include "ecar_core/matcher.h"
#include "ecar_core/optimizer.h"
#include "ecar_core/slam.h"
#include "ecar_core/types.h"

namespace ecar {

struct DeviceTrackerConfig {
  OrbConfig orb;  ///< extraction on the device's own images (and its descriptors)
  PoseOptimizerConfig pose;
  int keyframe_queue = 10;          ///< keyframes kept in ecar mode (> 0)
  double projection_radius = 15.0;  ///< px (x pyramid scale): search around the motion-model pose
  /// px (x pyramid scale): search around the latest keyframe's server pose, when
  /// there is no motion model (first frame, lost) or it failed.
  double keyframe_radius = 30.0;
  double refine_radius = 4.0;  ///< px (x pyramid scale): second search after the first pose
  int min_matches = 20;        ///< projection matches needed to attempt a pose
  int min_inliers = 25;        ///< inliers of the final pose for OK

  /// Throws ecar::Error naming the first invalid key (e.g. "keyframe_queue").
  void validate() const;
};

/// A map point of an ecar-mode local graph as the server tracked it in the
/// aligned image.
struct ReceivedPoint {
  MapPointId id;
  cv::KeyPoint keypoint;  ///< pt in level-0 px (distorted image), angle (deg), octave
};

/// A map point position sent in a local graph.
struct ReceivedPosition {
  MapPointId id;
  Eigen::Vector3d p_w = Eigen::Vector3d::Zero();  ///< map frame, m
};

/// An ecar-mode local graph: the aligned frame's pose, its tracked points, and
/// the positions the device does not hold yet (or that changed).
struct LocalGraphInput {
  uint32_t frame_index = 0;
  SE3 T_w_c = SE3::Identity();  ///< server pose of the aligned frame
  std::vector<ReceivedPoint> points;
  std::vector<ReceivedPosition> positions;
};

/// An edgeslam-mode local map: the aligned frame's local keyframes and every
/// point they observe, with descriptors, normals and distance ranges.
struct FullLocalMap {
  struct KeyFrame {
    KeyFrameId id;
    SE3 T_w_c = SE3::Identity();
    std::vector<MapPointId> point_ids;
  };
  uint32_t frame_index = 0;
  SE3 T_w_c = SE3::Identity();  ///< server pose of the aligned frame
  std::vector<KeyFrame> keyframes;
  std::vector<PointSample> points;
};

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
  QueueInsertResult insert(DeviceKeyFrame keyframe, const std::vector<ReceivedPosition>& positions);
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

/// The result of tracking one camera frame. Its vectors are reused between frames.
struct DeviceTrackResult {
  uint32_t frame_index = 0;
  TrackingState state = TrackingState::kNotInitialised;
  SE3 T_w_c = SE3::Identity();  ///< valid when state is kOk
  int matches = 0;              ///< projection matches before the final optimisation
  int inliers = 0;              ///< inliers of the final pose
  bool from_keyframe = false;   ///< predicted from the latest keyframe, not the motion model
  double orb_ms = 0.0, track_ms = 0.0, total_ms = 0.0;
  std::vector<cv::Point2f> tracked_pixels;  ///< inlier keypoints (distorted px), for drawing
  const char* message = "";                 ///< why tracking failed
};

/// What a local graph changed on the device.
struct GraphUpdate {
  QueueInsertResult queue;  ///< ecar mode
  int descriptors = 0;      ///< descriptors computed at the graph's keypoints (ecar mode)
  int points = 0;           ///< points the tracker can now use
  double ms = 0.0;          ///< time spent building the keyframe and the local map
};

class DeviceTracker {
 public:
  /// Throws ecar::Error on an invalid config.
  explicit DeviceTracker(const PinholeCamera& camera,
                         const DeviceTrackerConfig& config = DeviceTrackerConfig());

  /// ecar mode: builds a keyframe from the device's own grey (or colour) image of
  /// the graph's frame and the graph (descriptors computed at its keypoints),
  /// queues it and rebuilds the local map. An image of the wrong size gives no
  /// descriptors (the keyframe still counts, its points are not tracked).
  GraphUpdate addLocalGraph(const cv::Mat& image, const LocalGraphInput& graph);
  /// edgeslam mode: replaces the whole local map by the server's.
  GraphUpdate replaceLocalMap(const FullLocalMap& map);
  /// Drops the local map (map epoch changed, reconnection); the next frames are
  /// NOT_INITIALISED until a graph arrives.
  void clear();

  /// Tracks one camera frame (grey or colour, the camera's size) against the
  /// local map. The reference stays valid until the next call.
  const DeviceTrackResult& track(const cv::Mat& image, double timestamp, uint32_t frame_index);

  TrackingState state() const { return state_; }
  const DeviceKeyFrameQueue& queue() const { return queue_; }
  /// Keyframes of the local map (queued in ecar mode, sent in edgeslam mode).
  size_t numKeyFrames() const;
  /// Points the tracker matches against (with a position and a descriptor).
  size_t numPoints() const { return samples_.size(); }
  const DeviceTrackerConfig& config() const { return config_; }

 private:
  /// Local-map samples from the queue: descriptor and octave of the newest
  /// keyframe holding each point, normal and distance range from the keyframes.
  void rebuildSamples();
  /// Search around T_c_w (first radius, then refine_radius) and optimise.
  bool trackFrom(const SE3& T_c_w, double radius);
  /// Pose-only optimisation of the current matches; drops outliers, returns inliers.
  int optimise();

  PinholeCamera camera_;
  Intrinsics K_;
  DeviceTrackerConfig config_;
  ScaleInfo scale_;
  OrbExtractor extractor_;
  DeviceKeyFrameQueue queue_;
  size_t edgeslam_keyframes_ = 0;

  std::vector<PointSample> samples_;  ///< the local map as matched
  bool has_anchor_ = false;
  SE3 anchor_T_c_w_ = SE3::Identity();  ///< latest keyframe / aligned pose

  TrackingState state_ = TrackingState::kNotInitialised;
  bool has_velocity_ = false;
  SE3 velocity_ = SE3::Identity();  ///< T_c_last per frame
  SE3 last_T_c_w_ = SE3::Identity();
  uint32_t last_frame_index_ = 0;

  // Buffers reused between frames.
  Frame current_;
  SE3 T_c_w_ = SE3::Identity();
  std::vector<MapPointId> matches_;
  std::vector<int> match_index_;
  std::vector<PoseObservation> observations_;
  std::vector<int> observation_rows_;
  std::vector<bool> inliers_;
  std::unordered_map<MapPointId, int> sample_of_;
  std::vector<int> normal_count_;
  DeviceTrackResult result_;
};

}  // namespace ecar
