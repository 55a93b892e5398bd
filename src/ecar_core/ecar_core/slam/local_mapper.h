// Local mapping of the shared map (ORB-SLAM's local mapping, for keyframes of
// every device): new points by triangulation with covisible keyframes, fusion
// of duplicates, local bundle adjustment (Ceres) and culling of redundant
// points and keyframes.
//
//   LocalMapper mapper(&map, &place_index, config);
//   mapper.startThread();   // or processPending() after each insert (deterministic)
//   mapper.insert(keyframe_id);
//
// insert() is thread-safe; the mapping runs on the mapper's own thread and
// takes the map's write lock only for short updates (map.h).
#pragma once

#include <functional>
#include <mutex>
#include <vector>

#include "ecar_core/common/camera.h"
#include "ecar_core/common/types.h"
#include "ecar_core/slam/keyframe_worker.h"
#include "ecar_core/slam/map.h"
#include "ecar_core/slam/optimizer.h"
#include "ecar_core/slam/place_recognition.h"
#include "ecar_core/slam/slam_config.h"

namespace ecar {

class LoopCloser;

/// Odometry edges (SlamConfig::odometry_*) between consecutive keyframes of
/// each device among `ids` (indexed as in problem->keyframes). Hold the map's
/// read lock.
void addOdometryEdges(const Map& map, const SlamConfig& config, const std::vector<KeyFrameId>& ids,
                      BaProblem* problem);

class LocalMapper {
 public:
  /// `keypoints` may be null.
  /// Each keyframe is mapped with its own camera (KeyFrame::camera).
  LocalMapper(Map* map, PlaceIndex* index, const SlamConfig& config,
              KeypointIndex* keypoints = nullptr);
  ~LocalMapper();
  void insert(KeyFrameId kf);
  /// Bundle-adjusts `kf` and its covisible window now, on the caller's thread
  /// (ORB-SLAM's adjustment of a new two-view map: the tracker answers the
  /// initialising upload from the adjusted map, not from the raw two-view
  /// reconstruction that the mapper would move a moment later). Takes the
  /// map's locks; a no-op when the map changed while it solved.
  void adjustNow(KeyFrameId kf) { localBundleAdjustment(kf); }
  /// Maps every queued keyframe now (synchronous mode).
  void processPending();
  void startThread();
  /// Maps the keyframes still queued, then stops the thread.
  void stopThread();
  /// Drops the queued keyframes and the new points awaiting culling (the map
  /// was replaced): waits for the keyframe being mapped, and leaves the thread
  /// running if it was. Call while no tracker can insert keyframes.
  void reset();
  bool idle() const;
  /// Welds a seam (two maps merged, or the two ends of a loop): the points of
  /// `a` and its `window` best covisible keyframes are fused into the
  /// keyframes around `b`, and the other way round, where they project onto a
  /// matching keypoint. Returns how many were fused. Takes the write lock.
  int weld(KeyFrameId a, KeyFrameId b, size_t window);
  /// Times of the local bundle adjustments so far (ms).
  std::vector<double> baTimes() const;
  /// Called (on the mapping thread, or inside processPending()) after each
  /// keyframe was mapped, with its id; the keyframe may have been culled
  /// meanwhile. Set it before keyframes arrive; an empty function clears it.
  void setMappedCallback(std::function<void(KeyFrameId)> callback);
  /// Called (on the mapping thread, without the map lock) after a redundant
  /// keyframe was culled, with its id and its heir: the neighbour that shared
  /// the most points with it (invalid when it had none). Whatever hangs on
  /// the culled keyframe (plane and cell links, keyframe-attached objects)
  /// moves to the heir or goes. An empty function clears it.
  void setCulledCallback(std::function<void(KeyFrameId culled, KeyFrameId heir)> callback);
  /// Hands every mapped keyframe on to a loop closer (null: none). Set before
  /// keyframes arrive.
  void setLoopCloser(LoopCloser* closer) { loop_closer_ = closer; }

 private:
  void process(KeyFrameId kf);
  void cullRecentPoints(KeyFrameId kf);
  int triangulateNewPoints(KeyFrameId kf);
  int fuseDuplicates(KeyFrameId kf);
  int fuseInto(KeyFrameId target, const std::vector<MapPointId>& points);  // write lock held
  void localBundleAdjustment(KeyFrameId kf);

  void cullKeyFrames(KeyFrameId kf);

  Map* map_;
  PlaceIndex* index_;
  KeypointIndex* keypoints_;
  LoopCloser* loop_closer_ = nullptr;
  SlamConfig config_;
  mutable std::mutex mutex_;  // guards ba_ms_ and the callbacks
  std::vector<MapPointId> recent_points_;
  std::vector<double> ba_ms_;
  std::function<void(KeyFrameId)> mapped_callback_;              // guarded by mutex_
  std::function<void(KeyFrameId, KeyFrameId)> culled_callback_;  // guarded by mutex_
  /// Last: stopped (destroyed) before the members process() uses.
  KeyFrameWorker worker_{[this](KeyFrameId kf) { process(kf); }};
};

}  // namespace ecar
