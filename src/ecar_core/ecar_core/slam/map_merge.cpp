#include "ecar_core/slam/map_merge.h"

#include <algorithm>
#include <unordered_set>

#include "ecar_core/common/error.h"
#include "ecar_core/slam/pose_graph.h"

namespace ecar {

MergeResult mergeMaps(Map* into, Map* from, const Sim3& S,
                      const std::vector<std::pair<MapPointId, MapPointId>>& duplicates) {
  MergeResult out;
  const std::vector<KeyFrameId> keyframes = from->keyframeIds();
  const std::vector<MapPointId> points = from->pointIds();
  for (const KeyFrameId id : keyframes) {
    if (into->keyframe(id)) {
      throw Error("mergeMaps: keyframe " + std::to_string(id.value) + " is in both maps");
    }
  }
  for (const MapPointId id : points) {
    if (into->point(id)) {
      throw Error("mergeMaps: point " + std::to_string(id.value) + " is in both maps");
    }
  }
  const Sim3 S_inverse = S.inverse();
  uint32_t next_keyframe = into->nextKeyFrameId().value, next_point = into->nextPointId().value;
  for (const KeyFrameId id : keyframes) {
    KeyFrame kf = *from->keyframe(id);
    kf.T_c_w = metricPose(similarityOf(kf.T_c_w) * S_inverse);
    kf.covisibility.clear();
    next_keyframe = std::max(next_keyframe, id.value + 1);
    into->insertKeyFrame(std::move(kf));
    out.correction.keyframes[id] = S;
  }
  for (const MapPointId id : points) {
    MapPoint p = *from->point(id);
    p.p_w = S * p.p_w;
    ++p.version;
    next_point = std::max(next_point, id.value + 1);
    into->insertPoint(std::move(p));
  }
  out.keyframes_moved = keyframes.size();
  out.points_moved = points.size();
  out.moved_points = points;
  out.correction.points_moved = points.size();
  into->setCounters(KeyFrameId(next_keyframe), MapPointId(next_point), into->epoch());
  into->adoptReplacements(from);
  from->clear();

  // The seam: one point per physical point, the better observed one kept.
  std::unordered_set<KeyFrameId> seam;
  for (const auto& [theirs, mine] : duplicates) {
    const MapPoint* a = into->point(theirs);
    const MapPoint* b = into->point(mine);
    if (!a || !b || theirs == mine) continue;
    for (const auto& obs : a->observations) seam.insert(obs.first);
    for (const auto& obs : b->observations) seam.insert(obs.first);
    if (a->observations.size() > b->observations.size()) {
      into->replacePoint(mine, theirs);
    } else {
      into->replacePoint(theirs, mine);
    }
    ++out.points_fused;
  }
  for (const MapPointId id : points) {
    if (into->point(id)) into->updatePointStatistics(id);
  }
  for (const KeyFrameId id : keyframes) into->updateCovisibility(id);
  for (const KeyFrameId id : seam) {
    if (into->keyframe(id)) into->updateCovisibility(id);
  }
  out.seam.assign(seam.begin(), seam.end());
  std::sort(out.seam.begin(), out.seam.end());
  into->bumpRevision();
  out.correction.revision = into->revision();
  out.correction.epoch = into->epoch();
  return out;
}

SeamRefit refitMerge(Map* map, MergeResult* r, Sim3* S, bool fix_scale) {
  std::unordered_set<KeyFrameId> keyframes;
  for (const auto& kv : r->correction.keyframes) keyframes.insert(kv.first);
  const std::unordered_set<MapPointId> points(r->moved_points.begin(), r->moved_points.end());
  const SeamRefit refit = refitSeam(map, keyframes, points, fix_scale);
  if (refit.applied) {
    *S = refit.D * *S;
    for (auto& kv : r->correction.keyframes) kv.second = *S;
    r->correction.revision = map->revision();
  }
  return refit;
}

}  // namespace ecar
