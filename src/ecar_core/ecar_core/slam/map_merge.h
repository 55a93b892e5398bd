// Merging one map into another (the atlas's merge, issue 12): every keyframe
// and point of `from` moves into `into` through the similarity that place
// recognition verified (from's world -> into's world), the duplicate points on
// both sides of the seam become one, and the covisibility graph is welded
// across the seam. What hangs on the merged keyframes outside the map (planes,
// grid links, VOs) moves with the returned correction
// (GlobalGraph::applyMapCorrection), as with a loop.
//
//   auto a = into.writeLock(); auto b = from.writeLock();
//   MergeResult r = mergeMaps(&into, &from, S_into_from, duplicates);
#pragma once

#include <utility>
#include <vector>

#include "ecar_core/common/geometry.h"
#include "ecar_core/common/types.h"
#include "ecar_core/slam/map.h"
#include "ecar_core/slam/map_correction.h"
#include "ecar_core/slam/seam_refit.h"

namespace ecar {

struct MergeResult {
  size_t keyframes_moved = 0, points_moved = 0, points_fused = 0;
  /// The keyframes of the seam: those holding a fused point (a bundle
  /// adjustment around them settles the merge).
  std::vector<KeyFrameId> seam;
  /// The points that came from `from` (some fused away since).
  std::vector<MapPointId> moved_points;
  /// Every moved keyframe with the similarity (from's world -> into's world).
  MapCorrection correction;
};

/// Moves everything of `from` into `into` (S: from's world -> into's world):
/// keyframe poses become metricPose(S_c_w S^-1) (a scaled map keeps its
/// cameras where they were in it), points S p (new versions). Ids are kept, so
/// the maps must not share any (the maps of an atlas draw ids from disjoint
/// ranges); the id counters of `into` move past both. Then each pair of
/// `duplicates` (a point of `from`, a point of `into`: the same physical point)
/// becomes one point, the one with more observations surviving, and the
/// covisibility of the moved keyframes and of the seam's is recomputed.
/// `from` is left empty; the epoch of `into` stays (nothing of it moved: its
/// devices keep what they hold, and the devices of `from` are moved by the
/// caller with the correction). Hold both maps' write locks. Throws
/// ecar::Error naming the id when the maps share a keyframe or point id
/// (nothing moved then).
MergeResult mergeMaps(Map* into, Map* from, const Sim3& S,
                      const std::vector<std::pair<MapPointId, MapPointId>>& duplicates);

/// After mergeMaps (and the seam's welding): refits the merge's similarity on
/// the reprojections across the seam (refitSeam over r's moved keyframes and
/// points) and, when applied, composes it into *S and r's correction. Hold the
/// map's write lock.
SeamRefit refitMerge(Map* map, MergeResult* r, Sim3* S, bool fix_scale);

}  // namespace ecar
