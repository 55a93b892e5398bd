// The device side of eCAR: a small local map built from the server's local
// graphs, and tracking of every camera frame against it (DESIGN.md section 1,
// steps 2-3).
//
//   DeviceTracker tracker(camera, config);
//   tracker.addLocalGraph(own_gray_image_of_that_frame, graph);  // ecar mode
//   tracker.replaceLocalMap(graph);                             // edgeslam mode
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

#include "ecar_core/common/camera.h"
#include "ecar_core/common/geometry.h"
#include "ecar_core/common/types.h"
#include "ecar_core/device/device_keyframe_queue.h"
#include "ecar_core/slam/features.h"
#include "ecar_core/slam/frame.h"
#include "ecar_core/slam/matcher.h"
#include "ecar_core/slam/optimizer.h"
#include "ecar_core/slam/tracker.h"
#include "ecar_core/sync/local_graph.h"

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

/// The result of tracking one camera frame. Its vectors are reused between frames.
struct DeviceTrackResult {
  uint32_t frame_index = 0;
  TrackingState state = TrackingState::kNotInitialised;
  SE3 T_w_c = SE3::Identity();  ///< valid when state is kOk
  int matches = 0;              ///< projection matches before the final optimisation
  int inliers = 0;              ///< inliers of the final pose
  bool from_keyframe = false;   ///< predicted from the latest keyframe, not the motion model
  double orb_ms = 0.0, track_ms = 0.0, total_ms = 0.0;
  double cpu_ms = 0.0;  ///< the calling thread's CPU time for the whole call (total_ms is wall)
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
  GraphUpdate addLocalGraph(const cv::Mat& image, const LocalGraph& graph);
  /// edgeslam mode: replaces the whole local map by the graph's keyframes and
  /// map points (with their descriptors).
  GraphUpdate replaceLocalMap(const LocalGraph& graph);
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
