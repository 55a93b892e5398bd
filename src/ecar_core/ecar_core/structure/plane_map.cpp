#include "ecar_core/structure/plane_map.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <mutex>
#include <string>

#include "ecar_core/common/error.h"
#include "ecar_core/common/math.h"

namespace ecar {
namespace {

bool insideConvex(const std::vector<Eigen::Vector2d>& poly, const Eigen::Vector2d& p) {
  if (poly.size() < 3) return false;
  for (size_t i = 0; i < poly.size(); ++i) {
    if (cross2(poly[i], poly[(i + 1) % poly.size()], p) < -1e-12) return false;
  }
  return true;
}

double pointSegment(const Eigen::Vector2d& p, const Eigen::Vector2d& a, const Eigen::Vector2d& b) {
  const Eigen::Vector2d ab = b - a;
  const double len2 = ab.squaredNorm();
  const double t = len2 > 0.0 ? std::clamp((p - a).dot(ab) / len2, 0.0, 1.0) : 0.0;
  return (a + t * ab - p).norm();
}

bool segmentsCross(const Eigen::Vector2d& a, const Eigen::Vector2d& b, const Eigen::Vector2d& c,
                   const Eigen::Vector2d& d) {
  const double d1 = cross2(a, b, c), d2 = cross2(a, b, d);
  const double d3 = cross2(c, d, a), d4 = cross2(c, d, b);
  return ((d1 > 0) != (d2 > 0)) && ((d3 > 0) != (d4 > 0));
}

/// Distance between two convex polygons (0 when they overlap); a polygon of one
/// or two points counts as a point or a segment.
double polygonGap(const std::vector<Eigen::Vector2d>& a, const std::vector<Eigen::Vector2d>& b) {
  if (a.empty() || b.empty()) return std::numeric_limits<double>::infinity();
  for (const auto& p : a) {
    if (insideConvex(b, p)) return 0.0;
  }
  for (const auto& p : b) {
    if (insideConvex(a, p)) return 0.0;
  }
  double best = std::numeric_limits<double>::infinity();
  for (size_t i = 0; i < a.size(); ++i) {
    const auto& a0 = a[i];
    const auto& a1 = a[(i + 1) % a.size()];
    for (size_t j = 0; j < b.size(); ++j) {
      const auto& b0 = b[j];
      const auto& b1 = b[(j + 1) % b.size()];
      if (segmentsCross(a0, a1, b0, b1)) return 0.0;
      best = std::min({best, pointSegment(a0, b0, b1), pointSegment(a1, b0, b1),
                       pointSegment(b0, a0, a1), pointSegment(b1, a0, a1)});
    }
  }
  return best;
}

double medianAbsDistance(const std::vector<Eigen::Vector3d>& points, const Eigen::Vector3d& n,
                         double d) {
  std::vector<double> dist(points.size());
  for (size_t i = 0; i < points.size(); ++i) dist[i] = std::abs(n.dot(points[i]) + d);
  if (dist.empty()) return std::numeric_limits<double>::infinity();
  auto mid = dist.begin() + static_cast<long>(dist.size() / 2);
  std::nth_element(dist.begin(), mid, dist.end());
  return *mid;
}

}  // namespace

// ---------------------------------------------------------------- plane map

PlaneMap::PlaneMap(const PlaneConfig& config) : config_(config) { config_.validate(); }

bool PlaneMap::matches(const Entry& entry, const std::vector<Eigen::Vector3d>& points_w,
                       const std::vector<Eigen::Vector3d>& hull, const Eigen::Vector3d& normal,
                       double* median_distance) const {
  const Plane& p = entry.plane;
  if (std::abs(normal.dot(p.normal)) < std::cos(config_.merge_angle_deg * kDegToRad)) return false;
  const double md = medianAbsDistance(points_w, p.normal, p.offset);
  if (md > config_.merge_distance) return false;
  const PlaneFrame frame(p.normal, p.offset);
  std::vector<Eigen::Vector2d> a, b;
  for (const auto& v : p.boundary) a.push_back(frame.to2d(v));
  for (const auto& v : hull) b.push_back(frame.to2d(v));
  if (polygonGap(a, b) > config_.merge_gap) return false;
  *median_distance = md;
  return true;
}

void PlaneMap::reestimate(Entry* entry, const Eigen::Vector3d& camera_center_w,
                          const Eigen::Vector3d& up_w) {
  refitGeometry(entry);
  Plane& plane = entry->plane;
  plane.label = labelPlane(plane.normal, plane.offset, camera_center_w, up_w, config_);
}

void PlaneMap::refitGeometry(Entry* entry) {
  Plane& plane = entry->plane;
  std::vector<Eigen::Vector3d> pts;
  auto fit = [&]() {
    pts.clear();
    for (const auto& kv : entry->points) pts.push_back(kv.second);
    if (pts.size() < 3) return;
    Eigen::Vector3d n;
    double d;
    fitPlane(pts, &n, &d);
    if (n.dot(plane.normal) < 0.0) {  // keep the side it was seen from
      n = -n;
      d = -d;
    }
    plane.normal = n;
    plane.offset = d;
  };
  const double keep = config_.keep_factor * config_.distance_threshold;
  auto dropFar = [&](double limit) {
    bool dropped = false;
    for (auto it = entry->points.begin(); it != entry->points.end();) {
      if (std::abs(plane.signedDistance(it->second)) > limit) {
        point_owner_.erase(it->first);
        it = entry->points.erase(it);
        dropped = true;
      } else {
        ++it;
      }
    }
    return dropped;
  };
  // Points far from the current estimate (moved by bundle adjustment) leave
  // before the fit, so that they cannot tilt it (leniently: points just merged
  // in may lie up to merge_distance off it); then strictly after it.
  dropFar(keep + config_.merge_distance);
  fit();
  if (dropFar(keep)) fit();
  plane.boundary = planeHull(pts, plane.normal, plane.offset);
  plane.num_points = static_cast<uint32_t>(entry->points.size());
  ++plane.version;
}

void PlaneMap::erase(PlaneId id, PlaneMapUpdate* update) {
  Entry& e = planes_.at(id);
  for (const auto& kv : e.points) point_owner_.erase(kv.first);
  for (const KeyFrameId k : e.keyframes) {
    auto& list = keyframe_planes_[k];
    list.erase(std::remove(list.begin(), list.end(), id), list.end());
  }
  planes_.erase(id);
  update->removed.push_back(id);
}

void PlaneMap::absorb(Entry* into, Entry* from) {
  for (const auto& [pid, p_w] : from->points) {
    into->points[pid] = p_w;
    point_owner_[pid] = into->plane.id;
  }
  for (KeyFrameId kf : from->keyframes) {
    into->keyframes.insert(kf);
    auto& list = keyframe_planes_[kf];
    list.erase(std::remove(list.begin(), list.end(), from->plane.id), list.end());
    if (std::find(list.begin(), list.end(), into->plane.id) == list.end()) {
      list.push_back(into->plane.id);
    }
  }
}

PlaneMapUpdate PlaneMap::integrate(const PlaneKeyFrameInput& input,
                                   const std::vector<PlaneObservation>& observations) {
  if (!input.up_w.allFinite() || input.up_w.norm() < 1e-9 || !input.camera_center_w.allFinite()) {
    throw Error("planes: up_w and camera centre of keyframe " +
                std::to_string(input.keyframe.value) + " must be finite (up non-zero)");
  }
  const Eigen::Vector3d up = input.up_w.normalized();
  const Eigen::Vector3d& cam = input.camera_center_w;
  std::unique_lock<std::shared_mutex> lock(mutex_);
  PlaneMapUpdate update;

  // The keyframe's points take their current positions; a plane whose points
  // moved is refitted below, seen or not. (Bundle adjustment moves points: a
  // plane seen by one keyframe only stayed where its points had been first,
  // 13-16 cm above the floor they had moved down to, and took the strokes
  // drawn there.)
  const double moved_sq = std::pow(0.25 * config_.distance_threshold, 2);
  std::vector<PlaneId> moved;
  // Points the SLAM map no longer has leave their planes, which are refitted
  // (or go) below like planes whose points moved.
  for (const MapPointId id : input.gone) {
    const auto owner = point_owner_.find(id);
    if (owner == point_owner_.end()) continue;
    Entry& entry = planes_.at(owner->second);
    if (entry.plane.map != input.map) continue;
    entry.points.erase(id);
    moved.push_back(owner->second);
    point_owner_.erase(owner);
  }
  for (const auto& p : input.points) {
    const auto owner = point_owner_.find(p.id);
    if (owner == point_owner_.end() || !p.p_w.allFinite()) continue;
    auto& points = planes_.at(owner->second).points;
    const auto stored = points.find(p.id);
    if (stored == points.end()) continue;
    if ((stored->second - p.p_w).squaredNorm() > moved_sq) moved.push_back(owner->second);
    stored->second = p.p_w;
  }
  std::sort(moved.begin(), moved.end());
  moved.erase(std::unique(moved.begin(), moved.end()), moved.end());

  std::vector<PlaneId> touched;
  for (const auto& obs : observations) {
    std::vector<Eigen::Vector3d> pts;
    for (const auto& p : obs.inliers) pts.push_back(p.p_w);
    PlaneId best;
    double best_distance = std::numeric_limits<double>::infinity();
    for (const auto& [id, entry] : planes_) {
      double md = 0.0;
      if (entry.plane.map == input.map && matches(entry, pts, obs.boundary, obs.normal, &md) &&
          (md < best_distance || (md == best_distance && id < best))) {
        best = id;
        best_distance = md;
      }
    }
    Entry fresh;
    Entry* target = nullptr;
    if (best.valid()) {
      target = &planes_.at(best);
    } else {
      fresh.plane.id = PlaneId(next_id_);
      fresh.plane.map = input.map;
      fresh.plane.normal = obs.normal;
      fresh.plane.offset = obs.offset;
      target = &fresh;
    }
    for (const auto& p : obs.inliers) {
      const auto owner = point_owner_.find(p.id);
      if (owner == point_owner_.end() || owner->second == target->plane.id) {
        target->points[p.id] = p.p_w;
      }
    }
    if (!best.valid()) {
      if (static_cast<int>(fresh.points.size()) < config_.min_inliers) continue;
      ++next_id_;
      best = fresh.plane.id;
      target = &planes_.emplace(best, std::move(fresh)).first->second;
      update.created.push_back(best);
    }
    for (const auto& kv : target->points) point_owner_[kv.first] = best;
    target->keyframes.insert(input.keyframe);
    auto& links = keyframe_planes_[input.keyframe];
    if (std::find(links.begin(), links.end(), best) == links.end()) links.push_back(best);
    if (std::find(touched.begin(), touched.end(), best) == touched.end()) touched.push_back(best);
  }
  for (PlaneId id : touched) reestimate(&planes_.at(id), cam, up);
  // Planes whose points moved: refitted (points now far leave them); one left
  // with fewer than min_inliers points is no plane any more.
  for (PlaneId id : moved) {
    if (std::find(touched.begin(), touched.end(), id) != touched.end()) continue;
    Entry& entry = planes_.at(id);
    refitGeometry(&entry);
    if (static_cast<int>(entry.points.size()) < config_.min_inliers) {
      erase(id, &update);
    } else {
      touched.push_back(id);
    }
  }

  // Planes joined by this keyframe may now be one physical plane with another.
  for (size_t t = 0; t < touched.size(); ++t) {
    bool merged = true;
    while (merged && planes_.count(touched[t])) {
      merged = false;
      for (auto& [other_id, other] : planes_) {
        if (other_id == touched[t]) continue;
        Entry& self = planes_.at(touched[t]);
        if (other.plane.map != self.plane.map) continue;
        std::vector<Eigen::Vector3d> pts;
        for (const auto& kv : self.points) pts.push_back(kv.second);
        double md = 0.0;
        if (!matches(other, pts, self.plane.boundary, self.plane.normal, &md)) continue;
        const PlaneId keep = std::min(other_id, touched[t]);
        const PlaneId gone = std::max(other_id, touched[t]);
        absorb(&planes_.at(keep), &planes_.at(gone));
        planes_.erase(gone);
        update.removed.push_back(gone);
        for (auto& id : touched) {
          if (id == gone) id = keep;
        }
        reestimate(&planes_.at(keep), cam, up);
        if (std::find(touched.begin(), touched.end(), keep) == touched.end()) {
          touched.push_back(keep);
        }
        merged = true;
        break;
      }
    }
  }

  std::sort(touched.begin(), touched.end());
  touched.erase(std::unique(touched.begin(), touched.end()), touched.end());
  auto gone = [&](PlaneId id) { return planes_.count(id) == 0; };
  update.created.erase(std::remove_if(update.created.begin(), update.created.end(), gone),
                       update.created.end());
  for (PlaneId id : touched) {
    if (!gone(id) &&
        std::find(update.created.begin(), update.created.end(), id) == update.created.end()) {
      update.updated.push_back(id);
    }
  }
  std::sort(update.removed.begin(), update.removed.end());
  auto links = keyframe_planes_.find(input.keyframe);
  if (links != keyframe_planes_.end()) {
    std::sort(links->second.begin(), links->second.end());
    update.keyframe_planes = links->second;
  }
  if (!touched.empty()) ++revision_;
  return update;
}

std::vector<Plane> PlaneMap::planes() const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  std::vector<Plane> out;
  out.reserve(planes_.size());
  for (const auto& kv : planes_) out.push_back(kv.second.plane);
  std::sort(out.begin(), out.end(), [](const Plane& a, const Plane& b) { return a.id < b.id; });
  return out;
}

std::vector<Plane> PlaneMap::planes(const std::vector<PlaneId>& ids) const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  std::vector<Plane> out;
  for (PlaneId id : ids) {
    const auto it = planes_.find(id);
    if (it != planes_.end()) out.push_back(it->second.plane);
  }
  return out;
}

std::optional<Plane> PlaneMap::plane(PlaneId id) const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  const auto it = planes_.find(id);
  if (it == planes_.end()) return std::nullopt;
  return it->second.plane;
}

bool PlaneMap::contains(PlaneId id) const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  return planes_.count(id) > 0;
}

size_t PlaneMap::size() const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  return planes_.size();
}

uint64_t PlaneMap::revision() const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  return revision_;
}

std::vector<PlaneId> PlaneMap::planesOfKeyFrame(KeyFrameId keyframe) const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  const auto it = keyframe_planes_.find(keyframe);
  if (it == keyframe_planes_.end()) return {};
  std::vector<PlaneId> out = it->second;
  std::sort(out.begin(), out.end());
  return out;
}

std::vector<KeyFrameId> PlaneMap::keyframesOfPlane(PlaneId id) const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  const auto it = planes_.find(id);
  if (it == planes_.end()) return {};
  std::vector<KeyFrameId> out(it->second.keyframes.begin(), it->second.keyframes.end());
  std::sort(out.begin(), out.end());
  return out;
}

std::vector<MapPointId> PlaneMap::pointsOfPlane(PlaneId id) const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  const auto it = planes_.find(id);
  if (it == planes_.end()) return {};
  std::vector<MapPointId> out;
  out.reserve(it->second.points.size());
  for (const auto& kv : it->second.points) out.push_back(kv.first);
  std::sort(out.begin(), out.end());
  return out;
}

std::vector<MapPointId> PlaneMap::pointsOfMap(MapId map) const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  std::vector<MapPointId> out;
  out.reserve(point_owner_.size());
  for (const auto& [point, plane] : point_owner_) {
    if (planes_.at(plane).plane.map == map) out.push_back(point);
  }
  return out;
}

std::optional<PlaneId> PlaneMap::planeOfPoint(MapPointId point) const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  const auto it = point_owner_.find(point);
  if (it == point_owner_.end()) return std::nullopt;
  return it->second;
}

void PlaneMap::eraseKeyFrame(KeyFrameId keyframe) {
  std::unique_lock<std::shared_mutex> lock(mutex_);
  const auto it = keyframe_planes_.find(keyframe);
  if (it == keyframe_planes_.end()) return;
  for (PlaneId id : it->second) {
    const auto p = planes_.find(id);
    if (p != planes_.end()) p->second.keyframes.erase(keyframe);
  }
  keyframe_planes_.erase(it);
  ++revision_;
}

size_t PlaneMap::transformPlanes(
    const std::function<std::optional<Sim3>(const std::vector<KeyFrameId>&)>& correction) {
  std::unique_lock<std::shared_mutex> lock(mutex_);
  size_t moved = 0;
  for (auto& [id, entry] : planes_) {
    std::vector<KeyFrameId> keyframes(entry.keyframes.begin(), entry.keyframes.end());
    std::sort(keyframes.begin(), keyframes.end());
    const std::optional<Sim3> S = correction(keyframes);
    if (!S) continue;
    transform(&entry, *S);
    ++moved;
  }
  if (moved > 0) ++revision_;
  return moved;
}

size_t PlaneMap::moveMap(MapId from, MapId into, const Sim3& S) {
  std::unique_lock<std::shared_mutex> lock(mutex_);
  size_t moved = 0;
  for (auto& [id, entry] : planes_) {
    if (entry.plane.map != from) continue;
    transform(&entry, S);
    entry.plane.map = into;
    ++moved;
  }
  if (moved > 0) ++revision_;
  return moved;
}

PlaneMapUpdate PlaneMap::refit(
    MapId map, const std::function<std::optional<Eigen::Vector3d>(MapPointId)>& position) {
  std::unique_lock<std::shared_mutex> lock(mutex_);
  PlaneMapUpdate update;
  std::vector<PlaneId> ids;
  for (const auto& [id, entry] : planes_) {
    if (entry.plane.map == map) ids.push_back(id);
  }
  std::sort(ids.begin(), ids.end());
  for (const PlaneId id : ids) {
    Entry& e = planes_.at(id);
    for (auto it = e.points.begin(); it != e.points.end();) {
      const std::optional<Eigen::Vector3d> p = position(it->first);
      if (!p) {  // culled: no evidence of the plane any more
        point_owner_.erase(it->first);
        it = e.points.erase(it);
        continue;
      }
      if (p->allFinite()) it->second = *p;
      ++it;
    }
    refitGeometry(&e);
    if (static_cast<int>(e.points.size()) < config_.min_inliers) erase(id, &update);
  }
  // Planes that are one physical plane now: the lower id absorbs the higher.
  bool merged = true;
  while (merged) {
    merged = false;
    ids.erase(
        std::remove_if(ids.begin(), ids.end(), [&](PlaneId id) { return !planes_.count(id); }),
        ids.end());
    for (size_t a = 0; a < ids.size() && !merged; ++a) {
      for (size_t b = a + 1; b < ids.size() && !merged; ++b) {
        Entry& keep = planes_.at(ids[a]);
        Entry& gone = planes_.at(ids[b]);
        std::vector<Eigen::Vector3d> pts;
        for (const auto& kv : gone.points) pts.push_back(kv.second);
        double md = 0.0;
        if (!matches(keep, pts, gone.plane.boundary, gone.plane.normal, &md)) continue;
        absorb(&keep, &gone);
        gone.points.clear();  // now keep's (absorb moved the owners)
        gone.keyframes.clear();
        planes_.erase(ids[b]);
        update.removed.push_back(ids[b]);
        refitGeometry(&keep);
        merged = true;
      }
    }
  }
  for (const PlaneId id : ids) {
    if (planes_.count(id)) update.updated.push_back(id);
  }
  std::sort(update.removed.begin(), update.removed.end());
  if (!ids.empty() || !update.removed.empty()) ++revision_;
  return update;
}

void PlaneMap::transform(Entry* entry, const Sim3& S) {
  Plane& plane = entry->plane;
  const Eigen::Vector3d on_plane = S * (-plane.offset * plane.normal);
  plane.normal = (S.R * plane.normal).normalized();
  plane.offset = -plane.normal.dot(on_plane);
  for (Eigen::Vector3d& b : plane.boundary) b = S * b;
  for (auto& [pid, p_w] : entry->points) p_w = S * p_w;
  ++plane.version;
}

std::vector<PlaneRecord> PlaneMap::save() const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  std::vector<PlaneRecord> out;
  for (const auto& [id, entry] : planes_) {
    PlaneRecord r;
    r.plane = entry.plane;
    for (const auto& [pid, p_w] : entry.points) r.points.push_back({pid, p_w});
    std::sort(r.points.begin(), r.points.end(),
              [](const PlanePoint& a, const PlanePoint& b) { return a.id < b.id; });
    r.keyframes.assign(entry.keyframes.begin(), entry.keyframes.end());
    std::sort(r.keyframes.begin(), r.keyframes.end());
    out.push_back(std::move(r));
  }
  std::sort(out.begin(), out.end(),
            [](const PlaneRecord& a, const PlaneRecord& b) { return a.plane.id < b.plane.id; });
  return out;
}

uint32_t PlaneMap::nextId() const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  return next_id_;
}

void PlaneMap::load(const std::vector<PlaneRecord>& records, uint32_t next_id) {
  std::unordered_map<PlaneId, Entry> planes;
  std::unordered_map<MapPointId, PlaneId> owner;
  std::unordered_map<KeyFrameId, std::vector<PlaneId>> links;
  uint32_t next = std::max<uint32_t>(1, next_id);
  for (const auto& r : records) {
    const PlaneId id = r.plane.id;
    const std::string what = "planes: record of plane " + std::to_string(id.value);
    if (!id.valid()) throw Error("planes: record with invalid plane id 0");
    if (planes.count(id)) throw Error(what + " appears twice");
    if (!r.plane.normal.allFinite() || std::abs(r.plane.normal.norm() - 1.0) > 1e-6 ||
        !std::isfinite(r.plane.offset)) {
      throw Error(what + " has a non-unit normal or a non-finite offset");
    }
    Entry e;
    e.plane = r.plane;
    for (const auto& p : r.points) {
      e.points[p.id] = p.p_w;
      const auto held = owner.emplace(p.id, id);
      if (held.first->second != id) {
        throw Error(what + ": point " + std::to_string(p.id.value) + " is held by plane " +
                    std::to_string(held.first->second.value) + " too");
      }
    }
    for (KeyFrameId kf : r.keyframes) {
      e.keyframes.insert(kf);
      links[kf].push_back(id);
    }
    e.plane.num_points = static_cast<uint32_t>(e.points.size());
    next = std::max(next, id.value + 1);
    planes.emplace(id, std::move(e));
  }
  std::unique_lock<std::shared_mutex> lock(mutex_);
  planes_ = std::move(planes);
  point_owner_ = std::move(owner);
  keyframe_planes_ = std::move(links);
  next_id_ = next;
  ++revision_;
}

void PlaneMap::clear() {
  std::unique_lock<std::shared_mutex> lock(mutex_);
  planes_.clear();
  point_owner_.clear();
  keyframe_planes_.clear();
  next_id_ = 1;
  ++revision_;
}

}  // namespace ecar