// The global SLAM map shared by every device's tracker and the local mapper:
// keyframes, map points, observations and the covisibility graph.
//
// Concurrency (DESIGN.md section 3): the map has one shared_mutex. Readers
// (trackers, graph publishers) hold readLock() while they look things up and
// copy what they need; writers (local mapping, initialisation) hold
// writeLock() for short updates (bundle adjustment runs on a copy, without the
// lock). Every accessor below requires the caller to hold the lock it names;
// pointers it returns are valid only while that lock is held.
#pragma once

#include <atomic>
#include <cstdint>
#include <deque>
#include <map>
#include <mutex>
#include <optional>
#include <shared_mutex>
#include <string>
#include <unordered_map>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "ecar_core/common/geometry.h"
#include "ecar_core/common/types.h"
#include "ecar_core/slam/frame.h"
#include "ecar_core/slam/optimizer.h"

namespace ecar {

struct KeyFrame {
  KeyFrameId id;
  DeviceId device;
  uint32_t frame_index = 0;
  double timestamp = 0.0;
  SE3 T_c_w = SE3::Identity();                       ///< world to camera
  CameraPtr camera;                                  ///< the device's camera (never null in a map)
  Frame features;                                    ///< keypoints, undistorted, descriptors, grid
  std::vector<MapPointId> points;                    ///< per keypoint; invalid id = none
  std::unordered_map<KeyFrameId, int> covisibility;  ///< shared map points per neighbour
  bool bad = false;

  Eigen::Vector3d center() const { return T_c_w.inverse().translation(); }
  SE3 T_w_c() const { return T_c_w.inverse(); }
  /// Intrinsics of the keyframe's (undistorted) camera.
  Intrinsics K() const { return camera->intrinsics(); }
  int numTrackedPoints(int min_observations = 1) const;
  /// The keyframe's measured up direction (its gravity reading, normalised, in
  /// the camera frame) when its pose agrees with it within tol_deg, i.e. the
  /// map's z axis is up here (the map was initialised with gravity); otherwise
  /// none.
  std::optional<Eigen::Vector3d> alignedUp(double tol_deg) const;
};

struct MapPoint {
  MapPointId id;
  Eigen::Vector3d p_w = Eigen::Vector3d::Zero();
  std::map<KeyFrameId, int> observations;             ///< keyframe -> keypoint index
  cv::Mat descriptor;                                 ///< 1 x 32, the most representative one
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();  ///< mean viewing direction
  float min_distance = 0.0f, max_distance = 0.0f;     ///< scale-invariance range (m)
  KeyFrameId reference;                               ///< keyframe that created it
  KeyFrameId first_keyframe;
  int visible = 1;       ///< times it was in a frame's view
  int found = 1;         ///< times it was matched there
  uint32_t version = 1;  ///< increments when the position changes
  bool bad = false;

  float foundRatio() const { return static_cast<float>(found) / std::max(1, visible); }
  /// Pyramid level expected at distance `dist` (ORB-SLAM's scale prediction).
  int predictScale(double dist, const ScaleInfo& scale) const;
};

class Map {
 public:
  explicit Map(const ScaleInfo& scale) : scale_(scale) {}

  std::shared_lock<std::shared_mutex> readLock() const {
    return std::shared_lock<std::shared_mutex>(mutex_);
  }
  std::unique_lock<std::shared_mutex> writeLock() {
    return std::unique_lock<std::shared_mutex>(mutex_);
  }

  const ScaleInfo& scale() const { return scale_; }

  // ---- read access (hold readLock or writeLock)
  const KeyFrame* keyframe(KeyFrameId id) const;
  const MapPoint* point(MapPointId id) const;
  size_t numKeyFrames() const { return keyframes_.size(); }
  size_t numPoints() const { return points_.size(); }
  std::vector<KeyFrameId> keyframeIds() const;
  std::vector<MapPointId> pointIds() const;
  /// The live point that `id` became: itself when live, the point it was
  /// fused into (replacePoint, followed through later fusions) when it was
  /// one of the last kMaxReplacements fused, otherwise invalid (culled,
  /// or fused too long ago). Lets what refers to map points by id (planes)
  /// follow a fusion instead of losing the point.
  MapPointId livePoint(MapPointId id) const;
  static constexpr size_t kMaxReplacements = 1 << 16;
  /// The `n` neighbours sharing the most points (at least `min_weight`), best first.
  std::vector<KeyFrameId> bestCovisible(KeyFrameId id, size_t n, int min_weight = 1) const;
  /// The fewest covisibility links (keyframes sharing points) from `a` to
  /// `b`: 0 when they are one, 1 when they share points; max_hops + 1 when
  /// farther (or either is missing). Breadth-first, at most max_hops deep.
  int covisibilityHops(KeyFrameId a, KeyFrameId b, int max_hops) const;
  /// Epoch of the map: changes on reset/load (devices drop what they hold).
  uint32_t epoch() const { return epoch_; }
  bool initialized() const { return !keyframes_.empty(); }
  /// Metric: initialised with odometry (metres); otherwise scaled by the
  /// first views' median depth.
  bool metric() const { return metric_; }
  /// Moves on whenever keyframes and points were moved together by a
  /// correction (loop closing, global BA, a merge): work on a copy taken in an
  /// older revision (a local BA) must not be written back.
  uint64_t revision() const { return revision_; }
  /// Checks the map's invariants: every observation is recorded on both sides
  /// (point -> keyframe keypoint and back), and ids refer to live entries.
  /// Returns the first violation found, empty when consistent.
  std::string checkConsistency() const;

  // ---- write access (hold writeLock)
  KeyFrame* mutableKeyFrame(KeyFrameId id);
  void setMetric(bool metric) { metric_ = metric; }
  void bumpRevision() { ++revision_; }
  MapPoint* mutablePoint(MapPointId id);
  /// Assigns the id. Throws ecar::Error when the keyframe has no camera.
  KeyFrameId addKeyFrame(KeyFrame kf);
  MapPointId addPoint(const Eigen::Vector3d& p_w, KeyFrameId reference);
  /// Observation of point `pid` by keypoint `idx` of keyframe `kid` (both ways).
  void addObservation(MapPointId pid, KeyFrameId kid, int idx);
  void eraseObservation(MapPointId pid, KeyFrameId kid);
  /// Marks a point bad and removes all its observations.
  void erasePoint(MapPointId pid);
  /// Marks a keyframe bad: removes its observations and covisibility links.
  void eraseKeyFrame(KeyFrameId kid);
  /// Replaces `old_id` by `new_id` in every keyframe that observes it, and
  /// records the replacement for livePoint().
  void replacePoint(MapPointId old_id, MapPointId new_id);
  /// Recomputes the representative descriptor, normal and distance range.
  void updatePointStatistics(MapPointId pid);
  /// Recomputes the covisibility links of a keyframe (and its neighbours' links to it).
  void updateCovisibility(KeyFrameId kid);
  void clear();

  // ---- loading a saved map (io/map_file.h, io/slam_map_codec.h)
  /// The id the next addKeyFrame() / addPoint() assigns (hold readLock).
  KeyFrameId nextKeyFrameId() const { return KeyFrameId(next_keyframe_); }
  MapPointId nextPointId() const { return MapPointId(next_point_); }
  /// Inserts a keyframe under its own id, as it was saved; its point slots must
  /// match its keypoints. Throws ecar::Error for an invalid or present id, a
  /// slot count unlike the keypoints or a missing camera. Hold writeLock (or own an unshared map).
  void insertKeyFrame(KeyFrame kf);
  /// Inserts a point under its own id; its observations are taken as they are
  /// (the keyframes' slots must already hold it). Throws ecar::Error for an
  /// invalid or present id.
  void insertPoint(MapPoint p);
  /// Sets the id counters and the epoch of a loaded map. Throws ecar::Error
  /// when a counter is not above every id present (ids would be reused).
  void setCounters(KeyFrameId next_keyframe, MapPointId next_point, uint32_t epoch);
  /// Takes `other`'s keyframes, points and id counters (leaving it empty) and
  /// moves the epoch past both maps' epochs, so devices drop what they hold.
  /// Hold writeLock on this map; `other` must not be shared.
  void replaceWith(Map&& other);
  /// Takes `other`'s record of fused points (a merge moving its points here).
  void adoptReplacements(Map* other);

 private:
  void recordReplacement(MapPointId old_id, MapPointId new_id);

  ScaleInfo scale_;
  mutable std::shared_mutex mutex_;
  std::unordered_map<KeyFrameId, KeyFrame> keyframes_;
  std::unordered_map<MapPointId, MapPoint> points_;
  // Fused point -> the point it was fused into; the oldest forgotten first
  // (bounded: fusions go on as long as the map is mapped).
  std::unordered_map<MapPointId, MapPointId> replaced_;
  std::deque<MapPointId> replaced_order_;
  uint32_t next_keyframe_ = 1, next_point_ = 1;
  uint32_t epoch_ = 1;
  bool metric_ = false;
  uint64_t revision_ = 0;
};

}  // namespace ecar
