// Options of the server's monocular SLAM (Tracker, LocalMapper, SlamSystem),
// one struct with in-class defaults; ecar_server fills it from rosparam.
#pragma once

#include <algorithm>
#include <cmath>

#include "ecar_core/slam/features.h"
#include "ecar_core/slam/optimizer.h"
#include "ecar_core/slam/place_recognition.h"
#include "ecar_core/slam/pnp.h"
#include "ecar_core/slam/two_view.h"

namespace ecar {

/// Loop closing (loop_closer.h).
struct LoopClosingConfig {
  bool enabled = true;
  /// The new keyframe's best covisible neighbours (the "current side") are no
  /// candidates; their points join its own when the loop is verified.
  int covisible_excluded = 30;
  int query_neighbours = 5;
  /// A candidate's id is at least this much below the new keyframe's.
  int min_keyframe_gap = 20;
  size_t candidates = 3;          ///< place-recognition candidates checked
  int candidate_neighbours = 10;  ///< the candidate's neighbours whose points are matched
  double ratio = 0.8;             ///< descriptor ratio test
  /// Quick rejection before the neighbourhoods are matched: the new
  /// keyframe's own points must match at least this many of the candidate
  /// keyframe's own points (same ratio test). Nearly every candidate fails
  /// verification; this costs about a fifth of matching both sides. On the
  /// six-device corridor and the small ring (1440 verifications) the accepted
  /// candidates had 79 and 131 such matches, and 10 rejected 1239 candidates
  /// of which none would have been verified (0: match both sides at once).
  int min_candidate_matches = 10;
  /// Similarity inliers needed, from at least min_inlier_keyframes keyframes
  /// of the current side (checked with the neighbours).
  int min_inliers = 40;
  int min_inlier_keyframes = 2;
  /// 3D inlier tolerance: this fraction of the point's distance from the
  /// candidate keyframe's camera, plus 1 cm (map units).
  double tolerance_fraction = 0.03;
  int strong_covisibility = 100;  ///< covisibility edges of the pose graph
  int pose_graph_iterations = 20;
  /// A global bundle adjustment after each closed loop.
  bool global_ba = true;
  int global_ba_iterations = 10;
  /// After a loop, the next one is looked for this many keyframes later.
  int keyframes_between_loops = 5;
  /// Loops closed through a device's odometry (LoopCloser::closeByOdometry):
  /// a device lost for at most `odometry_max_gap` s relocalises elsewhere in a
  /// metric map, and its odometry across the gap puts it more than
  /// `odometry_min_drift` (m, and 3 odometry sigmas) and at most
  /// `odometry_max_drift` from where it relocalised: the map between the two
  /// places drifted (e.g. a corridor walked back in the other direction, which
  /// place recognition cannot match), and the odometry's short step is the loop
  /// edge. The relocalised pose needs `odometry_min_inliers` tracked points.
  bool by_odometry = true;
  double odometry_max_gap = 3.0;
  double odometry_min_drift = 0.03;
  double odometry_max_drift = 1.0;
  int odometry_min_inliers = 50;
  /// ... and the keyframes before and after the gap are at least
  /// odometry_min_hops covisibility links apart (Map::covisibilityHops),
  /// with the disagreement at most odometry_max_drift_per_link per link.
  /// Drift accumulates along the map between the two places: keyframes a few
  /// links apart are held together by shared points, and a large
  /// disagreement there is a wrong relocalisation, not drift. With twenty
  /// devices in the corridor and the atlas (E2's 20-device point,
  /// 2026-12-08), devices relocalised at their walk's last turn 0.5-0.9 m
  /// off and "closed" loops 3-5 links apart (0.88 m at
  /// 3, 0.71 at 4, 0.52 and 0.55 at 5), moving a map whose every trajectory
  /// fitted the truth within 0.7 cm by up to 1.3 m under every device; the
  /// corridor walked back (six corridor devices offline) closes its real
  /// loop, 5.1 cm across 5 links, and three corridor devices with one map
  /// theirs, 16.7 cm across 9 (1.0 and 1.9 cm per link against 10-29 for
  /// the wrong ones; the threshold sits between, 2x from either).
  int odometry_min_hops = 3;
  double odometry_max_drift_per_link = 0.04;
};

struct SlamConfig {
  OrbConfig orb;
  TwoViewConfig two_view;
  PnpConfig pnp;
  PoseOptimizerConfig pose;
  BaConfig ba;
  PlaceIndexConfig place;
  KeypointIndexConfig keypoints;
  int init_min_matches = 100;  ///< correspondences needed to try two-view
  double init_window = 100.0;  ///< px search window between the two views
  int init_candidates = 10;    ///< recent views kept as first-view candidates
  int init_attempts = 5;       ///< two-view reconstructions tried per image
  /// A candidate view is skipped when 90% of the keypoints moved less (px).
  double init_min_displacement_px = 3.0;
  /// With gravity in both views: two-view motions whose rotation moves the up
  /// direction by more than this (degrees) are ruled out (TwoViewGravity).
  /// Generous: a walking phone's accelerometer reads several degrees off.
  double init_gravity_tolerance_deg = 20.0;
  int min_inliers = 30;  ///< tracking OK needs this many inliers
  /// Below this fraction of the last image's inliers, the motion-model result
  /// is checked against tracking from the reference keyframe.
  double weak_tracking_ratio = 0.5;
  double projection_radius = 15.0;  ///< px (x pyramid scale) for motion-model search
  double local_map_radius = 4.0;    ///< px (x scale) for the local-map search
  int local_keyframes = 25;         ///< keyframes in the tracking local map
  int ba_keyframes = 10;            ///< free keyframes in local BA
  /// A metric map of at most this many keyframes is bundle-adjusted whole
  /// (only its first keyframe fixed), so that all devices' odometry sets its
  /// scale together. A young map's windows of ba_keyframes otherwise take
  /// their scale from the few keyframes fixed around them, whose poses the
  /// first short baselines set: E8's windows jumped 8% between anchors, and
  /// its devices' poses by up to 27 cm (the map 11-25% too large) in 1 run
  /// of 6. 0: always windows.
  int ba_whole_map_keyframes = 30;
  double keyframe_ratio = 0.75;      ///< new keyframe when tracked < ratio x reference's
  int keyframe_max_gap = 4;          ///< frames (uploads) after which a keyframe is due
  int covisible_triangulation = 10;  ///< neighbours searched for new points
  double relocalisation_ratio = 0.75;
  int relocalisation_candidates = 5;
  /// Relocalisation / joining by keypoint matches (when the whole-image
  /// candidates fail, e.g. a view from the opposite direction): ratio test
  /// between the two nearest distinct map points, and the neighbours of a
  /// candidate keyframe whose points are matched with it.
  double keypoint_ratio = 0.8;
  int keypoint_group = 15;
  /// With gravity in a gravity-aligned map: inliers a 2-point (yaw and
  /// translation) RANSAC over all keypoint matches at once needs before the
  /// pose is verified by projection (a view from the opposite direction has
  /// only about 10 correct matches among 60-90 when it first joins).
  int keypoint_gravity_min_inliers = 10;
  /// A relocalised pose must agree with the upload's gravity within this
  /// (degrees) where the map is gravity-aligned.
  double gravity_tolerance_deg = 5.0;
  /// Odometry in local bundle adjustment (metric maps only): consecutive
  /// keyframes of one device with odometry at most `odometry_max_gap` s
  /// apart are tied by the odometry's relative translation, with standard
  /// deviation odometrySigma(distance). This keeps the map's scale to all
  /// devices' odometry over time (monocular scale drifts; the first baseline
  /// alone sets it to about 1%). The model: a floor, a random walk
  /// (odometry_sigma_walk m per sqrt(m) travelled, off by default) and a
  /// fraction of the distance. A VIO's error is partly a scale bias that does
  /// not average out over edges: sigmas near the simulated odometry's own
  /// (min 0.001, walk 0.01, fraction 0.01) made the corridor's map follow its
  /// +1% bias (scale error -0.72% instead of -0.29%). odometry_sigma_walk and
  /// odometry_sigma_fraction both 0 disable it.
  double odometry_sigma_fraction = 0.02;
  double odometry_sigma_walk = 0.0;  ///< m per sqrt(m)
  double odometry_sigma_min = 0.01;  ///< m
  double odometry_max_gap = 10.0;    ///< s
  /// Standard deviation (m) of a device's odometry over `distance` m.
  double odometrySigma(double distance) const {
    return odometry_sigma_min + odometry_sigma_walk * std::sqrt(std::max(0.0, distance)) +
           odometry_sigma_fraction * distance;
  }
  /// Odometry ties keyframes in bundle adjustment.
  bool odometryEdges() const { return odometry_sigma_fraction > 0.0 || odometry_sigma_walk > 0.0; }
  LoopClosingConfig loops;
  /// Map each keyframe (and look for loops) inside track(); otherwise the
  /// mapper and the loop closer have their own threads.
  bool synchronous_mapping = true;
  /// Niceness added to the local-mapping and loop-closing threads (0..19, Linux;
  /// 0: the priority of the tracking threads). Tracking answers a device that
  /// waits for its graph; mapping a keyframe can wait a few milliseconds.
  int background_nice = 5;
  /// Epoch of the first map (Map::epoch); a server makes it differ between
  /// its starts so that devices notice a restarted server. >= 1.
  uint32_t first_epoch = 1;
};

}  // namespace ecar
