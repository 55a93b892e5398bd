#include "ecar_core/local_graph.h"

#include <algorithm>
#include <cmath>
#include <unordered_set>

#include "ecar_core/error.h"

namespace ecar {

const char* toString(SyncMode mode) { return mode == SyncMode::kEdgeSlam ? "edgeslam" : "ecar"; }

SyncMode parseSyncMode(const std::string& text) {
  if (text == "ecar") return SyncMode::kEcar;
  if (text == "edgeslam") return SyncMode::kEdgeSlam;
  throw Error("sync_mode must be 'ecar' or 'edgeslam' (got '" + text + "')");
}

DeviceMirror::DeviceMirror(size_t queue_length)
    : queue_length_(queue_length == 0 ? 10 : queue_length) {}

void DeviceMirror::reset() {
  queue_.clear();
  held_.clear();
}

bool DeviceMirror::holds(MapPointId id, uint32_t* version, Eigen::Vector3f* p_w) const {
  const auto it = held_.find(id);
  if (it == held_.end()) return false;
  if (version) *version = it->second.version;
  if (p_w) *p_w = it->second.p_w;
  return true;
}

void DeviceMirror::setHeld(MapPointId id, uint32_t version, const Eigen::Vector3f& p_w) {
  Held& h = held_[id];
  h.version = version;
  h.p_w = p_w;
}

void DeviceMirror::pushKeyFrame(const std::vector<MapPointId>& points) {
  std::vector<MapPointId> kept;
  kept.reserve(points.size());
  for (const auto& id : points) {
    const auto it = held_.find(id);
    if (it == held_.end()) continue;
    ++it->second.keyframes;
    kept.push_back(id);
  }
  queue_.push_back(std::move(kept));
  while (queue_.size() > queue_length_) {
    for (const auto& id : queue_.front()) {
      const auto it = held_.find(id);
      if (it != held_.end() && --it->second.keyframes <= 0) held_.erase(it);
    }
    queue_.pop_front();
  }
  // Points recorded by setHeld() but in no keyframe (a graph that was not
  // pushed) are not on the device either.
  for (auto it = held_.begin(); it != held_.end();) {
    it = it->second.keyframes <= 0 ? held_.erase(it) : std::next(it);
  }
}

LocalGraphData LocalGraphBuilder::build(const Map& map, const TrackResult& result, SyncMode mode,
                                        DeviceMirror* mirror) const {
  LocalGraphData out;
  out.mode = mode;
  if (result.state != TrackingState::kOk) return out;
  if (mode == SyncMode::kEcar) {
    if (!mirror) throw Error("LocalGraphBuilder: ecar mode needs the device's mirror");
    buildEcar(map, result, mirror, &out);
  } else {
    buildEdgeSlam(map, result, &out);
  }
  return out;
}

void LocalGraphBuilder::buildEcar(const Map& map, const TrackResult& result, DeviceMirror* mirror,
                                  LocalGraphData* out) const {
  out->points.reserve(result.tracked.size());
  std::vector<MapPointId> ids;
  ids.reserve(result.tracked.size());
  std::unordered_set<MapPointId> seen;
  seen.reserve(result.tracked.size() * 2);
  const float tolerance2 =
      static_cast<float>(config_.position_tolerance * config_.position_tolerance);
  const Eigen::Vector3f center = result.T_w_c.translation().cast<float>();
  auto lock = map.readLock();
  for (const TrackedPoint& t : result.tracked) {
    const MapPoint* p = map.point(t.id);
    if (!p || !seen.insert(t.id).second) continue;
    GraphPoint g;
    g.id = t.id;
    g.u = t.keypoint.pt.x;
    g.v = t.keypoint.pt.y;
    g.angle = t.keypoint.angle < 0.0f ? 0.0f : t.keypoint.angle;
    g.octave = t.keypoint.octave;
    out->points.push_back(g);
    ids.push_back(t.id);
    uint32_t held_version = 0;
    Eigen::Vector3f held_p_w;
    const Eigen::Vector3f p_w = p->p_w.cast<float>();
    if (!mirror->holds(t.id, &held_version, &held_p_w) ||
        (held_version != p->version && (p_w - held_p_w).squaredNorm() > tolerance2 &&
         movedInView(held_p_w, p_w, center))) {
      out->positions.push_back({t.id, p_w});
      mirror->setHeld(t.id, p->version, p_w);
    }
  }
  mirror->pushKeyFrame(ids);
}

bool LocalGraphBuilder::movedInView(const Eigen::Vector3f& held, const Eigen::Vector3f& now,
                                    const Eigen::Vector3f& center) const {
  if (config_.position_tolerance_deg <= 0.0 || config_.position_tolerance_depth <= 0.0) return true;
  const Eigen::Vector3f ray = now - center;
  const float dist = ray.norm();
  if (!(dist > 1e-6f)) return true;
  const Eigen::Vector3f move = now - held;
  const float along = move.dot(ray) / dist;
  const float across = std::sqrt(std::max(0.0f, move.squaredNorm() - along * along));
  const double angle_deg = std::atan2(across, dist) * 180.0 / M_PI;
  return angle_deg > config_.position_tolerance_deg ||
         std::abs(along) > config_.position_tolerance_depth * dist;
}

void LocalGraphBuilder::buildEdgeSlam(const Map& map, const TrackResult& result,
                                      LocalGraphData* out) const {
  size_t n = result.local_keyframes.size();
  if (config_.edgeslam_keyframes > 0) {
    n = std::min(n, static_cast<size_t>(config_.edgeslam_keyframes));
  }
  std::unordered_set<MapPointId> seen;
  auto lock = map.readLock();
  for (size_t k = 0; k < n; ++k) {
    const KeyFrame* kf = map.keyframe(result.local_keyframes[k]);
    if (!kf) continue;
    GraphKeyFrame g;
    g.id = kf->id;
    g.device = kf->device;
    g.T_w_c = kf->T_w_c();
    g.points.reserve(kf->points.size());
    for (const auto& pid : kf->points) {
      const MapPoint* p = map.point(pid);
      if (!p || p->descriptor.empty()) continue;
      g.points.push_back(pid);
      if (!seen.insert(pid).second) continue;
      GraphMapPoint m;
      m.id = pid;
      m.p_w = p->p_w.cast<float>();
      m.normal = p->normal.cast<float>();
      m.min_distance = p->min_distance;
      m.max_distance = p->max_distance;
      std::copy(p->descriptor.ptr<uint8_t>(0), p->descriptor.ptr<uint8_t>(0) + 32,
                m.descriptor.begin());
      out->map_points.push_back(m);
    }
    out->keyframes.push_back(std::move(g));
  }
}

}  // namespace ecar
