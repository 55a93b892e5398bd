#include "ecar_core/slam/map_correction.h"

#include "ecar_core/slam/pose_graph.h"

namespace ecar {

Sim3 MapCorrection::of(KeyFrameId id) const {
  const auto it = keyframes.find(id);
  return it == keyframes.end() ? Sim3() : it->second;
}

MapCorrection applyCorrection(Map* map, const std::unordered_map<KeyFrameId, Sim3>& S_old,
                              const std::unordered_map<KeyFrameId, Sim3>& S_new) {
  MapCorrection out;
  // Corrected keyframes.
  for (const auto& [id, S] : S_new) {
    const auto old = S_old.find(id);
    KeyFrame* kf = map->mutableKeyFrame(id);
    if (old == S_old.end() || !kf) continue;
    out.keyframes[id] = S.inverse() * old->second;
    kf->T_c_w = metricPose(S);
  }
  // Keyframes made since: with their best corrected neighbour.
  for (const KeyFrameId id : map->keyframeIds()) {
    if (out.keyframes.count(id) || S_new.count(id)) continue;
    for (const KeyFrameId n : map->bestCovisible(id, 20)) {
      const auto c = out.keyframes.find(n);
      if (c == out.keyframes.end()) continue;
      KeyFrame* kf = map->mutableKeyFrame(id);
      kf->T_c_w = metricPose(similarityOf(kf->T_c_w) * c->second.inverse());
      out.keyframes[id] = c->second;
      break;
    }
  }
  // Points with their reference keyframe, or the first corrected observer.
  for (const MapPointId pid : map->pointIds()) {
    MapPoint* p = map->mutablePoint(pid);
    auto c = out.keyframes.find(p->reference);
    if (c == out.keyframes.end()) {
      for (const auto& obs : p->observations) {
        c = out.keyframes.find(obs.first);
        if (c != out.keyframes.end()) break;
      }
    }
    if (c == out.keyframes.end()) continue;
    p->p_w = c->second * p->p_w;
    ++p->version;
    ++out.points_moved;
  }
  for (const MapPointId pid : map->pointIds()) map->updatePointStatistics(pid);
  map->bumpRevision();
  out.revision = map->revision();
  out.epoch = map->epoch();
  return out;
}

}  // namespace ecar
