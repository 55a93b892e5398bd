// Moving a whole map consistently: new poses for some keyframes (from a pose
// graph or a global bundle adjustment), and everything else carried along.
// Loop closing uses it, and so will map merging.
//
// Each corrected keyframe i gets the similarity C_i = S_i_new^-1 S_i_old that
// takes world coordinates as the keyframe saw them to the corrected ones.
// Keyframes without a new pose (made after the snapshot the correction was
// computed on) follow their best covisible corrected neighbour; map points
// follow their reference keyframe (or any corrected observer). Moved points
// get a new version, so devices receive their new positions; the map's
// revision moves on. Whatever hangs on keyframes outside the map (planes, grid
// links, VOs) is moved with MapCorrection::of().
#pragma once

#include <cstdint>
#include <unordered_map>

#include "ecar_core/common/geometry.h"
#include "ecar_core/common/types.h"
#include "ecar_core/slam/map.h"

namespace ecar {

struct MapCorrection {
  /// Per keyframe that moved: old world coordinates -> corrected ones.
  std::unordered_map<KeyFrameId, Sim3> keyframes;
  uint64_t revision = 0;  ///< the map's revision after the correction
  uint32_t epoch = 0;     ///< the map's epoch (a correction of a replaced map is stale)
  size_t points_moved = 0;
  /// The correction of a keyframe (identity when it did not move).
  Sim3 of(KeyFrameId id) const;
  bool empty() const { return keyframes.empty(); }
};

/// Applies new world-to-camera similarities (`S_new`) to keyframes whose pose
/// when they were computed was `S_old` (both by keyframe id; a keyframe
/// missing from the map is skipped). Keyframe poses become metricPose(S_new)
/// (a similarity with scale s places the camera at its corrected position
/// with the rotation R). Hold map->writeLock().
MapCorrection applyCorrection(Map* map, const std::unordered_map<KeyFrameId, Sim3>& S_old,
                              const std::unordered_map<KeyFrameId, Sim3>& S_new);

}  // namespace ecar
