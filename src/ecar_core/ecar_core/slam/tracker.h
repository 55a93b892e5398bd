// Alignment of one device's uploaded images against the shared map (the
// paper's coordinate alignment): ORB extraction, tracking by the motion model
// or the reference keyframe, the local-map search, relocalisation and joining,
// two-view initialisation of an empty map, and the keyframe decision.
//
//   Tracker tracker(device, &map, &place_index, &mapper, camera, config);
//   TrackResult r = tracker.track(gray, timestamp, frame_index, gravity_c, T_o_c);
//
// One tracker per device, used from one thread at a time; trackers of
// different devices run concurrently against the map (its lock contract in
// map.h). SlamSystem owns the trackers. The implementation is in three files:
// tracker.cpp (tracking), tracker_initialise.cpp, tracker_relocalise.cpp.
#pragma once

#include <cstdint>
#include <deque>
#include <optional>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "ecar_core/common/camera.h"
#include "ecar_core/common/types.h"
#include "ecar_core/slam/features.h"
#include "ecar_core/slam/frame.h"
#include "ecar_core/slam/loop_closer.h"
#include "ecar_core/slam/map.h"
#include "ecar_core/slam/matcher.h"
#include "ecar_core/slam/optimizer.h"
#include "ecar_core/slam/place_recognition.h"
#include "ecar_core/slam/slam_config.h"

namespace ecar {

enum class TrackingState { kNotInitialised = 0, kOk = 1, kLost = 2 };
const char* toString(TrackingState state);

struct TrackedPoint {
  MapPointId id;
  cv::KeyPoint keypoint;  ///< in the uploaded (distorted) image
  Eigen::Vector3d p_w;
};

struct TrackResult {
  TrackingState state = TrackingState::kNotInitialised;
  bool relocalised = false;  ///< this image was aligned by relocalisation / joining
  bool initialised = false;  ///< this image created the map
  SE3 T_w_c = SE3::Identity();
  std::vector<TrackedPoint> tracked;
  std::vector<KeyFrameId> local_keyframes;
  std::optional<KeyFrameId> new_keyframe;
  double orb_ms = 0.0, track_ms = 0.0;
  std::string message;  ///< why tracking failed, for logs
  /// The map's epoch when the image was aligned (SlamSystem::track): a result
  /// of an older epoch refers to a map that was replaced since.
  uint32_t map_epoch = 0;
  /// The atlas map the image was aligned in (set by Atlas::track; invalid for
  /// a lone SlamSystem and when nothing was tracked).
  MapId map;
  /// This image relocalised the device shortly after it was lost, and its
  /// odometry across the gap disagrees with the relocalised pose: the loop it
  /// closes (SlamSystem::track hands it to the LoopCloser).
  std::optional<OdometryLoop> odometry_loop;
};

class LocalMapper;

/// One image's ORB keypoints and descriptors, extracted once for several
/// trackers of the same device and extractor settings (the atlas tracks an
/// upload in several maps). The descriptors are shared, never written.
struct ImageFeatures {
  bool extracted = false;
  std::vector<cv::KeyPoint> keypoints;
  cv::Mat descriptors;
};

class Tracker {
 public:
  /// `keypoints` may be null (no relocalisation by keypoint matches).
  Tracker(DeviceId device, Map* map, PlaceIndex* index, LocalMapper* mapper, CameraPtr camera,
          const SlamConfig& config, KeypointIndex* keypoints = nullptr);
  /// Aligns one grey image. Bad images (empty, wrong size, blank) give a
  /// NOT_INITIALISED/LOST result with a message; nothing throws. `features`
  /// (optional): used instead of extracting when already extracted, else
  /// filled with this image's.
  TrackResult track(const cv::Mat& image, double timestamp, uint32_t frame_index,
                    const std::optional<Eigen::Vector3d>& gravity_c = std::nullopt,
                    const std::optional<SE3>& T_o_c = std::nullopt,
                    ImageFeatures* features = nullptr);
  TrackingState state() const { return state_; }
  int relocalisations() const { return relocalisations_; }
  /// Forgets the tracking state (last image, motion model, local keyframes,
  /// initialisation views): the next image relocalises against the map, or
  /// initialises an empty one. The relocalisation count stays. Not while
  /// track() runs.
  void reset();

 private:
  bool initialise(TrackResult* result);
  int trackFromLastFrame();  ///< inliers after the local-map search
  bool trackWithMotionModel();
  bool trackReferenceKeyFrame();
  bool relocalise();
  bool relocaliseByPlace();
  bool relocaliseByKeypoints();
  /// One gravity RANSAC over all keypoint matches (points, pixels, ids and
  /// keypoint rows alike indexed); verified against the points of the
  /// keyframes that observe its inliers.
  bool relocaliseByGravity(const std::vector<Eigen::Vector3d>& points_w,
                           const std::vector<Eigen::Vector2d>& pixels,
                           const std::vector<MapPointId>& ids, const std::vector<int>& rows,
                           KeyFrameId reference);
  /// Projection search of candidate points (no viewing-angle check: the map
  /// may have seen them from the other side), pose refinement and the checks
  /// of a relocalised pose.
  bool verifyRelocalisation(std::vector<PointSample> samples);
  bool gravityConsistent() const;
  /// After a relocalisation of a lost device: the loop its odometry closes
  /// from the last tracked image (LoopClosingConfig::by_odometry), if any.
  std::optional<OdometryLoop> odometryLoop() const;
  int trackLocalMap();
  bool needKeyFrame() const;
  KeyFrameId createKeyFrame();
  void fillResult(TrackResult* result) const;
  int optimiseCurrentPose();
  std::vector<PointSample> samplesOf(const std::vector<MapPointId>& ids) const;  // read lock held

  DeviceId device_;
  Map* map_;
  PlaceIndex* index_;
  KeypointIndex* keypoints_;
  LocalMapper* mapper_;
  CameraPtr camera_;  ///< the device's camera; its keyframes share it
  Intrinsics K_;
  SlamConfig config_;
  OrbExtractor extractor_;

  TrackingState state_ = TrackingState::kNotInitialised;
  Frame current_, last_;
  SE3 T_c_w_ = SE3::Identity(), last_T_c_w_ = SE3::Identity();
  std::vector<MapPointId> matches_, last_matches_;
  int last_inliers_ = 0;
  std::vector<bool> inliers_;
  std::optional<SE3> velocity_;  ///< T_c_last: motion from the last frame to the current
  KeyFrameId reference_kf_;
  /// The reference keyframe at the last image tracked (`last_`, last_T_c_w_):
  /// kept while lost, as relocalisation attempts change reference_kf_.
  KeyFrameId last_reference_kf_;
  /// The map revision and the reference keyframe's pose at the last image
  /// tracked (a loop correction in between moves the last pose with it).
  uint64_t seen_revision_ = 0;
  SE3 reference_pose_ = SE3::Identity();
  std::vector<KeyFrameId> local_keyframes_;
  uint32_t frames_since_keyframe_ = 0;
  int relocalisations_ = 0;
  // Initialisation.
  std::deque<Frame> init_candidates_;
};

}  // namespace ecar
