// Loop closing within a map (ORB-SLAM's loop closing, for keyframes of every
// device): each mapped keyframe is looked up in the place index among the
// keyframes outside its covisible neighbourhood; a candidate is verified by a
// robust similarity between the map points of the keyframe's neighbourhood
// and the candidate's (descriptor matches, RANSAC, enough inliers over at
// least two keyframes); the correction is spread over the map by a pose graph
// on the essential graph (spanning tree, strong covisibility, loop edges),
// applied to keyframes and points (map_correction.h), duplicates on both
// sides of the seam fused, and a global bundle adjustment refines it all.
// Loops that place recognition cannot see (a corridor walked back facing the
// other way: no view in common until the device turns round, is lost and
// relocalises in the older part of the map) are closed the same way from the
// device's odometry across the short tracking gap (closeByOdometry).
//
//   LoopCloser loops(&map, &place_index, config);
//   loops.startThread();        // or processPending() after each keyframe
//   loops.insert(keyframe);     // from the local mapper, once mapped
//
// Tracking and local mapping go on while a loop is detected and optimised:
// the closer works on copies, and takes the map's write lock only to apply
// the result (which moves the map's revision on, so work on older copies is
// not written back).
#pragma once

#include <deque>
#include <functional>
#include <mutex>
#include <vector>

#include "ecar_core/common/geometry.h"
#include "ecar_core/common/types.h"
#include "ecar_core/slam/keyframe_worker.h"
#include "ecar_core/slam/map.h"
#include "ecar_core/slam/map_correction.h"
#include "ecar_core/slam/place_recognition.h"
#include "ecar_core/slam/slam_config.h"

namespace ecar {

/// A loop that a relocalisation found through the device's odometry
/// (Tracker, LoopClosingConfig::by_odometry): the device was tracked near
/// `before`, lost briefly, and relocalised near `after`, and its odometry
/// across the gap disagrees with the relocalised pose by `drift_m`.
struct OdometryLoop {
  DeviceId device;
  KeyFrameId before;  ///< the reference keyframe of the device's last tracked image
  KeyFrameId after;   ///< its reference keyframe once relocalised
  /// World to world: moves the map around `before` to agree with `after`
  /// (X_after = G * X_before), from the last tracked pose, the odometry step
  /// and the relocalised pose.
  SE3 G = SE3::Identity();
  double drift_m = 0.0;  ///< odometry-predicted to relocalised camera centre
  double gap_s = 0.0;    ///< from the last tracked image to the relocalised one
  int inliers = 0;       ///< points tracked in the relocalised image
};

/// One closed loop (or a global BA pass): what was found and what it cost.
struct LoopClosure {
  KeyFrameId query;      ///< the new keyframe
  KeyFrameId match;      ///< the older keyframe it closed with
  DeviceId device;       ///< the device of the new keyframe
  int inliers = 0;       ///< similarity inliers (map point pairs)
  double scale = 1.0;    ///< of the similarity (scale drift around the loop)
  double drift_m = 0.0;  ///< how far the new keyframe's camera moved
  double detect_ms = 0.0, correct_ms = 0.0, global_ba_ms = 0.0;
  size_t keyframes_moved = 0, points_moved = 0, points_fused = 0;
  /// Closed through the device's odometry across a tracking gap
  /// (closeByOdometry), not by place recognition; `inliers` are then the
  /// relocalised image's tracked points.
  bool by_odometry = false;
  /// Odometry loops: how far the odometry put the device from where it
  /// relocalised (OdometryLoop::drift_m), and the covisibility links between
  /// the two keyframes (Map::covisibilityHops, counted up to kCountedLinks).
  double odometry_disagreement_m = 0.0;
  int links = 0;
  static constexpr int kCountedLinks = 50;
};

class LoopCloser {
 public:
  LoopCloser(Map* map, PlaceIndex* index, const SlamConfig& config);
  ~LoopCloser();
  LoopCloser(const LoopCloser&) = delete;
  LoopCloser& operator=(const LoopCloser&) = delete;

  void insert(KeyFrameId kf);
  /// Closes a loop that a relocalisation found through the device's odometry:
  /// queued like a keyframe (on the closer's thread; at once, on the caller's,
  /// without one). Dropped when `after` is in `before`'s covisible
  /// neighbourhood (then it is no loop) or the keyframes are gone.
  void closeByOdometry(const OdometryLoop& loop);
  /// Handles every queued keyframe now (synchronous mode).
  void processPending();
  void startThread();
  /// Handles the keyframes still queued, then stops the thread.
  void stopThread();
  /// Drops the queue and the loop edges (the map was replaced). Does not wait
  /// for a loop being closed: work on the old map is dropped by its epoch.
  void reset();
  bool idle() const;
  std::vector<LoopClosure> closures() const;
  /// Called (on the closer's thread, without the map lock) after a loop was
  /// closed and after each global BA, with what moved. Set before keyframes
  /// arrive; an empty function clears it.
  void setCorrectedCallback(std::function<void(const MapCorrection&)> callback);
  /// A global bundle adjustment of the whole map now, on the caller's thread;
  /// returns its time (ms; 0 when nothing was adjusted).
  double bundleAdjustAll();
  /// Queues a global bundle adjustment of the whole map (after a merge): on
  /// the closer's thread, after the keyframes queued before it, so tracking
  /// goes on meanwhile; at once, on the caller's thread, without a thread
  /// (synchronous mode). Its correction is announced like a loop's.
  void requestBundleAdjustAll();
  /// Global bundle adjustments run by requestBundleAdjustAll, with their times.
  std::vector<double> requestedBundleAdjustmentsMs() const;

 private:
  struct Candidate;
  void process(KeyFrameId kf);
  void processOdometryLoop();
  /// Corrects the map with a verified loop, records it, announces the
  /// correction and runs the global BA; false when nothing was applied.
  bool close(const Candidate& candidate, LoopClosure* report);
  bool detect(KeyFrameId kf, Candidate* out, LoopClosure* report);
  /// Empty when nothing was applied (the map changed meanwhile).
  MapCorrection correct(const Candidate& c, LoopClosure* report);
  void globalBundleAdjustment(LoopClosure* report);
  void notify(const MapCorrection& correction);

  Map* map_;
  PlaceIndex* index_;
  SlamConfig config_;
  mutable std::mutex
      mutex_;  // guards closures_, loop_edges_, callback_, last_loop_keyframe_, odometry_loops_
  std::vector<LoopClosure> closures_;
  std::vector<double> requested_ba_ms_;
  std::deque<OdometryLoop> odometry_loops_;  ///< queued by closeByOdometry
  /// Loop edges kept for later pose graphs: (a, b, S_a_w S_b_w^-1 when closed).
  struct LoopEdge {
    KeyFrameId a, b;
    Sim3 S_a_b;
  };
  std::vector<LoopEdge> loop_edges_;
  std::function<void(const MapCorrection&)> callback_;
  KeyFrameId last_loop_keyframe_;
  /// Last: stopped (destroyed) before the members process() uses.
  KeyFrameWorker worker_{[this](KeyFrameId kf) { process(kf); }};
};

}  // namespace ecar
