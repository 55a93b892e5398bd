#include "ecar_core/sync/local_graph_composer.h"

#include <algorithm>
#include <cmath>
#include <string>

#include "ecar_core/common/error.h"
#include "ecar_core/common/math.h"

namespace ecar {
namespace {

ObjectId idOf(const VirtualObject& vo) { return vo.id; }
ObjectId idOf(ObjectId id) { return id; }

}  // namespace

void LocalGraphComposerConfig::validate() const {
  const auto fail = [](const std::string& key, const std::string& why) {
    throw Error(key + ": " + why);
  };
  if (!finiteNonNegative(position_tolerance)) fail("position_tolerance", "must be >= 0 m");
  if (!finiteNonNegative(position_tolerance_deg)) fail("position_tolerance_deg", "must be >= 0");
  if (!finiteNonNegative(position_tolerance_depth)) {
    fail("position_tolerance_depth", "must be >= 0");
  }
  if (edgeslam_keyframes < 0) fail("edgeslam_keyframes", "must be >= 0");
  if (plane_refresh < 1) fail("plane_refresh", "must be >= 1");
  if (!finiteNonNegative(plane_resend_angle_deg)) fail("plane_resend_angle_deg", "must be >= 0");
  if (!finiteNonNegative(plane_resend_offset)) fail("plane_resend_offset", "must be >= 0 m");
  if (!finiteNonNegative(plane_resend_extent)) fail("plane_resend_extent", "must be >= 0 m");
  if (max_points < 1 || max_points > 65535) fail("max_points", "must be in [1, 65535]");
}

void DeviceSyncState::reset() {
  resetMap();
  objects_.clear();
  has_epoch_ = false;
  map_ = MapId();
}

void DeviceSyncState::resetMap() {
  points_.reset();
  planes_.clear();
}

GraphStatus graphStatus(const TrackResult& result) {
  switch (result.state) {
    case TrackingState::kOk:
      return result.relocalised ? GraphStatus::kRelocalised : GraphStatus::kOk;
    case TrackingState::kLost:
      return GraphStatus::kLost;
    default:
      return GraphStatus::kNotInitialised;
  }
}

LocalGraphComposer::LocalGraphComposer(const LocalGraphComposerConfig& config) : config_(config) {
  config_.validate();
}

std::optional<LocalGraph> LocalGraphComposer::compose(const Map& map, const ComposerInput& in,
                                                      const ComposerLookups& lookups,
                                                      DeviceSyncState* state) const {
  if (!in.frame) throw Error("LocalGraphComposer: no tracked frame");
  if (!state) throw Error("LocalGraphComposer: no device state");
  const TrackResult& frame = *in.frame;
  const MapId map_id = frame.state == TrackingState::kOk ? frame.map : MapId();
  if (!state->has_epoch_ || state->epoch_ != in.map_epoch ||
      (map_id.valid() && state->map_.valid() && map_id != state->map_)) {
    // A new device, a replaced map, or its map merged into another: the
    // device drops what it held.
    state->reset();
    state->has_epoch_ = true;
    state->epoch_ = in.map_epoch;
  } else if (in.reset) {
    state->resetMap();  // the device lost its local map; it keeps its objects
  }
  LocalGraph out;
  out.device = in.device;
  out.frame_index = in.frame_index;
  out.status = graphStatus(frame);
  out.T_w_c = frame.T_w_c;
  out.map_epoch = in.map_epoch;
  out.map = map_id;
  if (map_id.valid()) state->map_ = map_id;
  out.mode = in.mode;
  if (frame.state == TrackingState::kOk) {
    {
      auto lock = map.readLock();
      if (map.epoch() != in.map_epoch) {
        // Aligned in a map that was replaced since: its ids and coordinates
        // mean nothing in the current one.
        state->reset();
        return std::nullopt;
      }
      if (in.mode == SyncMode::kEcar) {
        addEcarPoints(map, frame, &state->points_, &out);
      } else {
        addEdgeSlamPoints(map, frame, lookups, &out);
      }
    }
    if (out.points.size() > config_.max_points) {
      state->resetMap();
      throw Error("local graph: " + std::to_string(out.points.size()) + " points, more than " +
                  std::to_string(config_.max_points));
    }
    ++state->graphs_;
    if (in.planes) addPlanes(*in.planes, lookups, state, &out);
    if (in.objects) addObjects(*in.objects, lookups, state, &out);
  } else {
    auto lock = map.readLock();
    if (map.epoch() != in.map_epoch) {
      state->reset();
      return std::nullopt;
    }
  }
  return out;
}

void LocalGraphComposer::addEcarPoints(const Map& map, const TrackResult& frame,
                                       DeviceMirror* mirror, LocalGraph* out) const {
  out->points.reserve(frame.tracked.size());
  std::vector<MapPointId> ids;
  ids.reserve(frame.tracked.size());
  std::unordered_set<MapPointId> seen;
  seen.reserve(frame.tracked.size() * 2);
  const float tolerance2 =
      static_cast<float>(config_.position_tolerance * config_.position_tolerance);
  const Eigen::Vector3f center = frame.T_w_c.translation().cast<float>();
  for (const TrackedPoint& t : frame.tracked) {
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

bool LocalGraphComposer::movedInView(const Eigen::Vector3f& held, const Eigen::Vector3f& now,
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

void LocalGraphComposer::addEdgeSlamPoints(const Map& map, const TrackResult& frame,
                                           const ComposerLookups& lookups, LocalGraph* out) const {
  size_t n = frame.local_keyframes.size();
  if (config_.edgeslam_keyframes > 0) {
    n = std::min(n, static_cast<size_t>(config_.edgeslam_keyframes));
  }
  std::unordered_set<MapPointId> seen;
  for (size_t k = 0; k < n; ++k) {
    const KeyFrame* kf = map.keyframe(frame.local_keyframes[k]);
    if (!kf) continue;
    GraphKeyFrame g;
    g.id = kf->id;
    if (lookups.device_name) g.device = lookups.device_name(kf->device);
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

void LocalGraphComposer::addPlanes(const std::vector<Plane>& planes, const ComposerLookups& lookups,
                                   DeviceSyncState* state, LocalGraph* out) const {
  if (lookups.plane_exists) {
    for (auto it = state->planes_.begin(); it != state->planes_.end();) {
      if (lookups.plane_exists(it->first)) {
        ++it;
      } else {
        out->removed_planes.push_back(it->first);
        it = state->planes_.erase(it);
      }
    }
  }
  const double min_cos = std::cos(config_.plane_resend_angle_deg * kDegToRad);
  for (const Plane& p : planes) {
    // The visible planes are a snapshot: one may have been fused away since.
    if (lookups.plane_exists && !lookups.plane_exists(p.id)) continue;
    DeviceSyncState::SentPlane now;
    now.graph = state->graphs_;
    now.normal = p.normal;
    now.offset = p.offset;
    now.label = static_cast<uint8_t>(p.label);
    if (!p.boundary.empty()) {
      now.min = now.max = p.boundary.front();
      for (const auto& b : p.boundary) {
        now.min = now.min.cwiseMin(b);
        now.max = now.max.cwiseMax(b);
      }
    }
    const auto it = state->planes_.find(p.id);
    if (it != state->planes_.end()) {
      const DeviceSyncState::SentPlane& sent = it->second;
      const bool changed =
          sent.label != now.label || sent.normal.dot(now.normal) < min_cos ||
          std::abs(sent.offset - now.offset) > config_.plane_resend_offset ||
          (sent.min - now.min).cwiseAbs().maxCoeff() > config_.plane_resend_extent ||
          (sent.max - now.max).cwiseAbs().maxCoeff() > config_.plane_resend_extent;
      if (!changed && state->graphs_ - sent.graph < static_cast<uint64_t>(config_.plane_refresh)) {
        continue;
      }
    }
    state->planes_[p.id] = now;
    out->planes.push_back(p);
  }
}

void LocalGraphComposer::addObjects(const std::vector<VirtualObject>& objects,
                                    const ComposerLookups& lookups, DeviceSyncState* state,
                                    LocalGraph* out) const {
  out->objects.reserve(objects.size());
  std::map<ObjectId, uint32_t>& sent = state->objects_;
  for (const VirtualObject& vo : objects) {
    sent[vo.id] = vo.version;
    out->objects.push_back(vo);
  }
  // Objects the device was sent that are out of view: it keeps them while
  // they live; a deleted one gets its tombstone, once.
  std::vector<ObjectId> gone;
  for (const auto& kv : sent) {
    const bool visible =
        std::binary_search(objects.begin(), objects.end(), kv.first,
                           [](const auto& a, const auto& b) { return idOf(a) < idOf(b); });
    if (!visible) gone.push_back(kv.first);
  }
  if (gone.empty() || !lookups.objects) return;
  const std::vector<VirtualObject> known = lookups.objects(gone);  // by id, as `gone`
  size_t k = 0;
  for (const ObjectId id : gone) {
    while (k < known.size() && known[k].id < id) ++k;
    if (k < known.size() && known[k].id == id) {
      if (!known[k].deleted) continue;
      out->objects.push_back(known[k]);
    } else {
      // The store compacted its tombstone (VoStoreConfig::tombstone_retention): tell the
      // device it is gone with a tombstone of its own, one version past what it holds.
      VirtualObject tombstone;
      tombstone.id = id;
      tombstone.version = sent.at(id) + 1;
      tombstone.deleted = true;
      out->objects.push_back(tombstone);
    }
    sent.erase(id);
  }
}

}  // namespace ecar
