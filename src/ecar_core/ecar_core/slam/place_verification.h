// Verifying that two parts of maps show the same place: the map points of a
// keyframe and its best covisible neighbours (the query side) are matched by
// descriptor (ratio test) to the points of a candidate keyframe and its
// neighbours (the match side, in the same map for a loop, in another for a
// merge), and a robust similarity between the matched positions must have
// enough inliers seen from at least two keyframes of the query side.
#pragma once

#include <optional>
#include <unordered_set>
#include <utility>
#include <vector>

#include "ecar_core/common/geometry.h"
#include "ecar_core/common/types.h"
#include "ecar_core/slam/map.h"
#include "ecar_core/slam/slam_config.h"

namespace ecar {

struct PlaceMatch {
  KeyFrameId query, match;
  Sim3 S;  ///< query side's world -> match side's world
  int inliers = 0;
  /// The inlier pairs: (query-side point, match-side point), the same physical point.
  std::vector<std::pair<MapPointId, MapPointId>> duplicates;
};

/// Matches the query side (`query` and its query_neighbours best covisible
/// keyframes in `query_map`) to the match side (`candidate` and its
/// candidate_neighbours in `match_map`, without the keyframes of `excluded`)
/// and verifies the similarity (LoopClosingConfig: ratio, tolerance_fraction,
/// min_inliers, min_inlier_keyframes; fix_scale for SE(3)). A candidate whose
/// own points match fewer than min_candidate_matches of `query`'s own is
/// rejected before the neighbourhoods are matched. Holds each map's
/// read lock while it reads it (the maps may be one). `seed` makes RANSAC
/// reproducible.
std::optional<PlaceMatch> verifyPlace(const Map& query_map, KeyFrameId query, const Map& match_map,
                                      KeyFrameId candidate,
                                      const std::unordered_set<KeyFrameId>& excluded,
                                      const LoopClosingConfig& config, bool fix_scale,
                                      uint32_t seed);

}  // namespace ecar
