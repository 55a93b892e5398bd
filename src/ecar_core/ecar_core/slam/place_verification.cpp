#include "ecar_core/slam/place_verification.h"

#include <array>
#include <cstring>

#include "ecar_core/slam/descriptor_block.h"
#include "ecar_core/slam/features.h"
#include "ecar_core/slam/matcher.h"
#include "ecar_core/slam/sim3_solver.h"

namespace ecar {
namespace {

/// A match-side point as the matching sees it; copied out of the map (its
/// descriptor goes to the search block, at the same index).
struct Target {
  MapPointId id;
  Eigen::Vector3d p_w;
};

/// A query-side point with the descriptor of the keypoint that saw it.
struct Source {
  MapPointId id;
  Eigen::Vector3d p_w;
  std::array<uint8_t, 32> descriptor;
  KeyFrameId keyframe;
};

}  // namespace

std::optional<PlaceMatch> verifyPlace(const Map& query_map, KeyFrameId query, const Map& match_map,
                                      KeyFrameId candidate,
                                      const std::unordered_set<KeyFrameId>& excluded,
                                      const LoopClosingConfig& c, bool fix_scale, uint32_t seed) {
  std::vector<Target> targets;
  DescriptorBlock target_descriptors;
  size_t candidate_targets = 0;  // targets[0, candidate_targets): the candidate's own points
  std::unordered_set<MapPointId> target_ids;
  Eigen::Vector3d centre;
  {
    auto lock = match_map.readLock();
    const KeyFrame* m = match_map.keyframe(candidate);
    if (!m) return std::nullopt;
    centre = m->center();
    std::vector<KeyFrameId> side = {candidate};
    for (const KeyFrameId n : match_map.bestCovisible(candidate, c.candidate_neighbours)) {
      if (!excluded.count(n)) side.push_back(n);
    }
    for (const KeyFrameId id : side) {
      for (const MapPointId pid : match_map.keyframe(id)->points) {
        const MapPoint* p = match_map.point(pid);
        if (!p || p->descriptor.empty() || !target_ids.insert(pid).second) continue;
        targets.push_back({pid, p->p_w});
        target_descriptors.push_back(p->descriptor.ptr<uint8_t>(0));
      }
      if (id == candidate) candidate_targets = targets.size();
    }
  }
  std::vector<Source> sources;
  size_t query_sources = 0;  // sources[0, query_sources): the query keyframe's own points
  {
    auto lock = query_map.readLock();
    const KeyFrame* k = query_map.keyframe(query);
    if (!k) return std::nullopt;
    std::vector<KeyFrameId> side = {query};
    for (const KeyFrameId n : query_map.bestCovisible(query, c.query_neighbours)) side.push_back(n);
    std::unordered_set<MapPointId> seen;
    for (const KeyFrameId id : side) {
      const KeyFrame* q = query_map.keyframe(id);
      if (!q || q->features.descriptors.rows != static_cast<int>(q->points.size())) continue;
      for (size_t i = 0; i < q->points.size(); ++i) {
        const MapPoint* p = query_map.point(q->points[i]);
        // A point already on both sides needs no match.
        if (!p || target_ids.count(p->id) || !seen.insert(p->id).second) continue;
        Source s{p->id, p->p_w, {}, id};
        std::memcpy(s.descriptor.data(), q->features.descriptors.ptr<uint8_t>(static_cast<int>(i)),
                    32);
        sources.push_back(s);
      }
      if (id == query) query_sources = sources.size();
    }
  }
  // The nearest of targets[0, end) to a source passing the ratio test, or -1.
  const auto nearest = [&](const Source& source, size_t end) {
    const DescriptorBlock::Nearest n = target_descriptors.nearest(source.descriptor.data(), end);
    return n.index >= 0 && n.distance <= kDescriptorThresholdLow && n.distance < c.ratio * n.second
               ? n.index
               : -1;
  };
  if (c.min_candidate_matches > 0) {
    int matched = 0;
    for (size_t s = 0; s < query_sources && matched < c.min_candidate_matches; ++s) {
      matched += nearest(sources[s], candidate_targets) >= 0;
    }
    if (matched < c.min_candidate_matches) return std::nullopt;
  }
  std::vector<PointPair> pairs;
  std::vector<size_t> source_of;
  std::vector<size_t> target_of;
  for (size_t s = 0; s < sources.size(); ++s) {
    const int best_index = nearest(sources[s], targets.size());
    if (best_index < 0) continue;
    const Target& t = targets[best_index];
    pairs.push_back({sources[s].p_w, t.p_w, c.tolerance_fraction * (t.p_w - centre).norm() + 0.01});
    source_of.push_back(s);
    target_of.push_back(static_cast<size_t>(best_index));
  }
  if (static_cast<int>(pairs.size()) < c.min_inliers) return std::nullopt;
  Sim3EstimateConfig sc;
  sc.min_inliers = c.min_inliers;
  sc.fix_scale = fix_scale;
  sc.seed = seed;
  const Sim3Estimate e = estimateSim3(pairs, sc);
  if (!e.success) return std::nullopt;
  PlaceMatch out;
  std::unordered_set<KeyFrameId> seen_by;
  for (size_t i = 0; i < pairs.size(); ++i) {
    if (!e.inliers[i]) continue;
    seen_by.insert(sources[source_of[i]].keyframe);
    out.duplicates.emplace_back(sources[source_of[i]].id, targets[target_of[i]].id);
  }
  if (static_cast<int>(seen_by.size()) < c.min_inlier_keyframes) return std::nullopt;
  out.query = query;
  out.match = candidate;
  out.S = e.S;
  out.inliers = e.num_inliers;
  return out;
}

}  // namespace ecar
