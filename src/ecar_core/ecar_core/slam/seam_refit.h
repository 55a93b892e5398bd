// Refitting a merge's similarity on the welded seam (issue 12). Place
// recognition verifies a merge on the 3D positions of the few dozen points one
// view's neighbourhood shares with the other map; a rotation error of a degree
// there puts what the merged map holds ten metres away 17 cm off. Once the seam
// is welded (mergeMaps' duplicates and LocalMapper::weld), hundreds of points
// of one side are observed by keyframes of the other: their reprojections fix
// the similarity far better. refitSeam finds the correction D (a similarity
// in the merged world) that, applied to everything that moved in the merge,
// best reprojects those cross observations (Huber, then inliers only), and
// applies it.
//
//   auto lock = map.writeLock();
//   SeamRefit r = refitSeam(&map, moved_keyframes, moved_points, fix_scale);
//   if (r.applied) S = r.D * S;  // the merge's similarity, refined
#pragma once

#include <unordered_set>

#include "ecar_core/common/geometry.h"
#include "ecar_core/common/types.h"
#include "ecar_core/slam/map.h"

namespace ecar {

struct SeamRefitConfig {
  double chi2_threshold = 5.991;  ///< inliers: error^2 * inv_sigma2 below this
  double huber_delta = 2.4477;    ///< sqrt(5.991)
  int rounds = 2;                 ///< optimise with all, then with the inliers
  int iterations = 15;
  /// Fewer inlier cross observations (or fewer keyframes seeing the other
  /// side's points): nothing is applied.
  int min_inliers = 40;
  int min_keyframes = 3;
  /// A correction larger than this is not a refinement: nothing is applied.
  double max_rotation_deg = 5.0;
  double max_scale_change = 0.05;
};

struct SeamRefit {
  bool applied = false;
  Sim3 D;  ///< merged world -> merged world, applied to the moved side
  int observations = 0, inliers = 0;
  double rms_before_px = 0.0, rms_after_px = 0.0;  ///< over the final inliers
};

/// Cross observations: a keyframe of `moved_keyframes` seeing a point not in
/// `moved_points`, or the other way round. Optimises D (7 degrees of freedom;
/// 6 with fix_scale), and when enough inliers remain and D is small, moves
/// every moved keyframe (T_c_w -> metricPose(sim(T_c_w) D^-1)) and point
/// (p -> D p, new version). Hold the map's write lock.
SeamRefit refitSeam(Map* map, const std::unordered_set<KeyFrameId>& moved_keyframes,
                    const std::unordered_set<MapPointId>& moved_points, bool fix_scale,
                    const SeamRefitConfig& config = SeamRefitConfig());

}  // namespace ecar
