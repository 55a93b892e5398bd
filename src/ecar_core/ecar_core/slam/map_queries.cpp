#include "ecar_core/slam/map_queries.h"

#include <limits>
#include <unordered_set>

namespace ecar {

KeyFrameId nearestKeyFrame(const Map& map, const Eigen::Vector3d& p_w) {
  if (!p_w.allFinite()) return {};
  auto lock = map.readLock();
  KeyFrameId best;
  double best_d2 = std::numeric_limits<double>::max();
  for (const auto& id : map.keyframeIds()) {
    const KeyFrame* kf = map.keyframe(id);
    if (!kf || kf->bad) continue;
    const double d2 = (kf->center() - p_w).squaredNorm();
    if (d2 < best_d2) {
      best_d2 = d2;
      best = id;
    }
  }
  return best;
}

namespace {

// The keyframe's summary (the map's read lock held).
void summarise(const Map& map, const KeyFrame& kf, KeyFrameSummary* out) {
  out->id = kf.id;
  out->device = kf.device;
  out->frame_index = kf.frame_index;
  out->timestamp = kf.timestamp;
  out->T_w_c = kf.T_w_c();
  out->gravity_c = kf.features.gravity_c;
  out->map_epoch = map.epoch();
}

}  // namespace

CameraPtr keyframeCamera(const Map& map, KeyFrameId id) {
  auto lock = map.readLock();
  const KeyFrame* kf = map.keyframe(id);
  return kf ? kf->camera : nullptr;
}

std::optional<KeyFrameSummary> keyframeSummary(const Map& map, KeyFrameId id) {
  auto lock = map.readLock();
  const KeyFrame* kf = map.keyframe(id);
  if (!kf || kf->bad) return std::nullopt;
  KeyFrameSummary out;
  summarise(map, *kf, &out);
  return out;
}

std::optional<KeyFrameNeighbourhood> keyframeNeighbourhood(const Map& map, KeyFrameId id,
                                                           size_t neighbours) {
  auto lock = map.readLock();
  const KeyFrame* kf = map.keyframe(id);
  if (!kf || kf->bad) return std::nullopt;
  KeyFrameNeighbourhood out;
  summarise(map, *kf, &out);
  std::vector<KeyFrameId> kfs = map.bestCovisible(id, neighbours);
  kfs.push_back(id);
  std::unordered_set<MapPointId> seen;
  for (const auto& k_id : kfs) {
    const KeyFrame* k = map.keyframe(k_id);
    if (!k || k->bad) continue;
    for (const auto& pid : k->points) {
      if (!pid.valid() || !seen.insert(pid).second) continue;
      const MapPoint* p = map.point(pid);
      if (p && !p->bad) out.points.emplace_back(pid, p->p_w);
    }
  }
  return out;
}

std::optional<Bounds> keyframeBounds(const Map& map) {
  Bounds b;
  b.min = Eigen::Vector3d::Constant(std::numeric_limits<double>::max());
  b.max = -b.min;
  auto lock = map.readLock();
  for (const auto& id : map.keyframeIds()) {
    const KeyFrame* k = map.keyframe(id);
    if (!k || k->bad) continue;
    b.min = b.min.cwiseMin(k->center());
    b.max = b.max.cwiseMax(k->center());
  }
  if (b.min.x() > b.max.x()) return std::nullopt;
  return b;
}

MapOverview mapOverview(const Map& map) {
  MapOverview out;
  auto lock = map.readLock();
  const auto point_ids = map.pointIds();
  out.points.reserve(point_ids.size());
  for (const auto& id : point_ids) {
    if (const MapPoint* p = map.point(id)) out.points.push_back(p->p_w);
  }
  for (const auto& id : map.keyframeIds()) {
    const KeyFrame* kf = map.keyframe(id);
    if (!kf) continue;
    out.keyframes.push_back({id, kf->device, kf->center()});
  }
  out.num_keyframes = map.numKeyFrames();
  out.num_points = map.numPoints();
  return out;
}

uint32_t mapEpoch(const Map& map) {
  auto lock = map.readLock();
  return map.epoch();
}

}  // namespace ecar
