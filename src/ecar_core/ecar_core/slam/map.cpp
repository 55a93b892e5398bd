#include "ecar_core/slam/map.h"

#include <algorithm>
#include <cmath>
#include <unordered_set>

#include "ecar_core/common/error.h"
#include "ecar_core/slam/features.h"

namespace ecar {

int KeyFrame::numTrackedPoints(int /*min_observations*/) const {
  int n = 0;
  for (const auto& id : points) n += id.valid() ? 1 : 0;
  return n;
}

std::optional<Eigen::Vector3d> KeyFrame::alignedUp(double tol_deg) const {
  const auto& g = features.gravity_c;
  if (!g || !g->allFinite() || g->norm() < 1.0) return std::nullopt;
  const Eigen::Vector3d up = g->normalized();
  const Eigen::Vector3d map_up = T_c_w.linear() * Eigen::Vector3d::UnitZ();
  if (map_up.dot(up) <= std::cos(tol_deg * M_PI / 180.0)) return std::nullopt;
  return up;
}

int MapPoint::predictScale(double dist, const ScaleInfo& scale) const {
  if (!(max_distance > 0) || !(dist > 0)) return 0;
  const double ratio = max_distance / dist;
  int level = static_cast<int>(std::ceil(std::log(ratio) / scale.log_scale_factor));
  return std::clamp(level, 0, scale.levels() - 1);
}

const KeyFrame* Map::keyframe(KeyFrameId id) const {
  const auto it = keyframes_.find(id);
  return it == keyframes_.end() ? nullptr : &it->second;
}

const MapPoint* Map::point(MapPointId id) const {
  const auto it = points_.find(id);
  return it == points_.end() ? nullptr : &it->second;
}

KeyFrame* Map::mutableKeyFrame(KeyFrameId id) {
  const auto it = keyframes_.find(id);
  return it == keyframes_.end() ? nullptr : &it->second;
}

MapPoint* Map::mutablePoint(MapPointId id) {
  const auto it = points_.find(id);
  return it == points_.end() ? nullptr : &it->second;
}

std::vector<KeyFrameId> Map::keyframeIds() const {
  std::vector<KeyFrameId> ids;
  ids.reserve(keyframes_.size());
  for (const auto& kv : keyframes_) ids.push_back(kv.first);
  std::sort(ids.begin(), ids.end());
  return ids;
}

std::vector<MapPointId> Map::pointIds() const {
  std::vector<MapPointId> ids;
  ids.reserve(points_.size());
  for (const auto& kv : points_) ids.push_back(kv.first);
  std::sort(ids.begin(), ids.end());
  return ids;
}

std::vector<KeyFrameId> Map::bestCovisible(KeyFrameId id, size_t n, int min_weight) const {
  const KeyFrame* kf = keyframe(id);
  if (!kf) return {};
  std::vector<std::pair<int, KeyFrameId>> v;
  for (const auto& kv : kf->covisibility) {
    if (kv.second >= min_weight && keyframes_.count(kv.first)) v.push_back({kv.second, kv.first});
  }
  std::sort(v.begin(), v.end(), [](const auto& a, const auto& b) {
    return a.first != b.first ? a.first > b.first : a.second < b.second;
  });
  std::vector<KeyFrameId> out;
  for (size_t i = 0; i < v.size() && i < n; ++i) out.push_back(v[i].second);
  return out;
}

int Map::covisibilityHops(KeyFrameId a, KeyFrameId b, int max_hops) const {
  if (!keyframe(a) || !keyframe(b)) return max_hops + 1;
  if (a == b) return 0;
  std::vector<KeyFrameId> frontier = {a}, next;
  std::unordered_set<KeyFrameId> seen = {a};
  for (int hops = 1; hops <= max_hops && !frontier.empty(); ++hops) {
    next.clear();
    for (const KeyFrameId f : frontier) {
      for (const auto& [n, weight] : keyframe(f)->covisibility) {
        if (weight < 1 || !keyframes_.count(n) || !seen.insert(n).second) continue;
        if (n == b) return hops;
        next.push_back(n);
      }
    }
    frontier.swap(next);
  }
  return max_hops + 1;
}

KeyFrameId Map::addKeyFrame(KeyFrame kf) {
  if (!kf.camera) throw Error("Map::addKeyFrame: the keyframe has no camera");
  kf.id = KeyFrameId(next_keyframe_++);
  if (kf.points.size() != kf.features.size()) kf.points.assign(kf.features.size(), MapPointId());
  const KeyFrameId id = kf.id;
  keyframes_.emplace(id, std::move(kf));
  return id;
}

MapPointId Map::addPoint(const Eigen::Vector3d& p_w, KeyFrameId reference) {
  MapPoint p;
  p.id = MapPointId(next_point_++);
  p.p_w = p_w;
  p.reference = reference;
  p.first_keyframe = reference;
  const MapPointId id = p.id;
  points_.emplace(id, std::move(p));
  return id;
}

void Map::addObservation(MapPointId pid, KeyFrameId kid, int idx) {
  MapPoint* p = mutablePoint(pid);
  KeyFrame* kf = mutableKeyFrame(kid);
  if (!p || !kf || idx < 0 || idx >= static_cast<int>(kf->points.size())) return;
  // One keypoint per point and keyframe, one point per keypoint: whatever
  // held either end before lets go of it.
  const auto it = p->observations.find(kid);
  if (it != p->observations.end() && it->second != idx && it->second >= 0 &&
      it->second < static_cast<int>(kf->points.size()) && kf->points[it->second] == pid) {
    kf->points[it->second] = MapPointId();
  }
  const MapPointId previous = kf->points[idx];
  if (previous.valid() && previous != pid) {
    eraseObservation(previous, kid);  // may erase `previous`, never p or kf
    p = mutablePoint(pid);
    kf = mutableKeyFrame(kid);
  }
  p->observations[kid] = idx;
  kf->points[idx] = pid;
}

void Map::eraseObservation(MapPointId pid, KeyFrameId kid) {
  MapPoint* p = mutablePoint(pid);
  if (!p) return;
  const auto it = p->observations.find(kid);
  if (it == p->observations.end()) return;
  if (KeyFrame* kf = mutableKeyFrame(kid)) {
    if (it->second >= 0 && it->second < static_cast<int>(kf->points.size()) &&
        kf->points[it->second] == pid) {
      kf->points[it->second] = MapPointId();
    }
  }
  p->observations.erase(it);
  // A point seen by fewer than two keyframes carries no structure: drop it.
  if (p->observations.size() < 2) {
    erasePoint(pid);
  } else if (p->reference == kid) {
    p->reference = p->observations.begin()->first;
  }
}

void Map::erasePoint(MapPointId pid) {
  const auto it = points_.find(pid);
  if (it == points_.end()) return;
  for (const auto& obs : it->second.observations) {
    if (KeyFrame* kf = mutableKeyFrame(obs.first)) {
      if (obs.second >= 0 && obs.second < static_cast<int>(kf->points.size()) &&
          kf->points[obs.second] == pid) {
        kf->points[obs.second] = MapPointId();
      }
    }
  }
  points_.erase(it);
}

void Map::eraseKeyFrame(KeyFrameId kid) {
  KeyFrame* kf = mutableKeyFrame(kid);
  if (!kf) return;
  const std::vector<MapPointId> observed = kf->points;
  for (const auto& pid : observed) {
    // A keyframe sharing points may keep a weak link that this one dropped
    // (updateCovisibility keeps weak links on one side): it goes too.
    if (const MapPoint* p = point(pid)) {
      for (const auto& obs : p->observations) {
        if (KeyFrame* other = mutableKeyFrame(obs.first)) other->covisibility.erase(kid);
      }
    }
  }
  for (const auto& pid : observed) {
    if (pid.valid()) eraseObservation(pid, kid);
  }
  for (const auto& kv : kf->covisibility) {
    if (KeyFrame* other = mutableKeyFrame(kv.first)) other->covisibility.erase(kid);
  }
  keyframes_.erase(kid);
}

void Map::replacePoint(MapPointId old_id, MapPointId new_id) {
  if (old_id == new_id) return;
  MapPoint* old_p = mutablePoint(old_id);
  MapPoint* new_p = mutablePoint(new_id);
  if (!old_p || !new_p) return;
  for (const auto& obs : old_p->observations) {
    KeyFrame* kf = mutableKeyFrame(obs.first);
    if (!kf) continue;
    if (new_p->observations.count(obs.first)) {
      // Both seen in this keyframe: keep the new point's observation.
      if (kf->points[obs.second] == old_id) kf->points[obs.second] = MapPointId();
    } else {
      kf->points[obs.second] = new_id;
      new_p->observations[obs.first] = obs.second;
    }
  }
  new_p->visible += old_p->visible;
  new_p->found += old_p->found;
  points_.erase(old_id);
  updatePointStatistics(new_id);
  recordReplacement(old_id, new_id);
}

void Map::recordReplacement(MapPointId old_id, MapPointId new_id) {
  if (replaced_.emplace(old_id, new_id).second) replaced_order_.push_back(old_id);
  while (replaced_order_.size() > kMaxReplacements) {
    replaced_.erase(replaced_order_.front());
    replaced_order_.pop_front();
  }
}

MapPointId Map::livePoint(MapPointId id) const {
  // A chain is as long as the fusions one point went through; bounded anyway
  // (and against a cycle, which replacePoint cannot make).
  for (int hop = 0; hop < 64; ++hop) {
    if (points_.count(id)) return id;
    const auto it = replaced_.find(id);
    if (it == replaced_.end()) return MapPointId();
    id = it->second;
  }
  return MapPointId();
}

void Map::adoptReplacements(Map* other) {
  for (const MapPointId old_id : other->replaced_order_) {
    recordReplacement(old_id, other->replaced_.at(old_id));
  }
  other->replaced_.clear();
  other->replaced_order_.clear();
}

void Map::updatePointStatistics(MapPointId pid) {
  MapPoint* p = mutablePoint(pid);
  if (!p || p->observations.empty()) return;
  // Descriptor with the least median distance to the others.
  std::vector<const uint8_t*> descs;
  Eigen::Vector3d normal = Eigen::Vector3d::Zero();
  const KeyFrame* ref = nullptr;
  int ref_idx = -1;
  for (const auto& obs : p->observations) {
    const KeyFrame* kf = keyframe(obs.first);
    if (!kf || obs.second >= kf->features.descriptors.rows) continue;
    descs.push_back(kf->features.descriptors.ptr<uint8_t>(obs.second));
    normal += (p->p_w - kf->center()).normalized();
    if (obs.first == p->reference || !ref) {
      ref = kf;
      ref_idx = obs.second;
    }
  }
  if (descs.empty()) return;
  size_t best = 0;
  int best_median = 1 << 30;
  std::vector<int> d(descs.size());
  for (size_t i = 0; i < descs.size(); ++i) {
    for (size_t j = 0; j < descs.size(); ++j) d[j] = descriptorDistance(descs[i], descs[j]);
    std::nth_element(d.begin(), d.begin() + d.size() / 2, d.end());
    if (d[d.size() / 2] < best_median) {
      best_median = d[d.size() / 2];
      best = i;
    }
  }
  p->descriptor = cv::Mat(1, 32, CV_8U, const_cast<uint8_t*>(descs[best])).clone();
  if (normal.norm() > 0) p->normal = normal.normalized();
  if (ref && ref_idx >= 0) {
    const double dist = (p->p_w - ref->center()).norm();
    const int level = ref->features.keypoints[ref_idx].octave;
    const float level_scale = scale_.scale[std::clamp(level, 0, scale_.levels() - 1)];
    p->max_distance = static_cast<float>(dist * level_scale);
    p->min_distance = p->max_distance / scale_.scale.back();
  }
}

void Map::updateCovisibility(KeyFrameId kid) {
  KeyFrame* kf = mutableKeyFrame(kid);
  if (!kf) return;
  std::unordered_map<KeyFrameId, int> counts;
  for (const auto& pid : kf->points) {
    const MapPoint* p = point(pid);
    if (!p) continue;
    for (const auto& obs : p->observations) {
      if (obs.first != kid) ++counts[obs.first];
    }
  }
  // Old links that vanished.
  for (const auto& kv : kf->covisibility) {
    if (!counts.count(kv.first)) {
      if (KeyFrame* other = mutableKeyFrame(kv.first)) other->covisibility.erase(kid);
    }
  }
  kf->covisibility.clear();
  // Links of fewer than 15 shared points are kept only when nothing stronger
  // exists (as ORB-SLAM does), so a new keyframe is never disconnected.
  bool has_strong = false;
  for (const auto& c : counts) has_strong |= c.second >= 15;
  for (const auto& kv : counts) {
    if (kv.second < 15 && has_strong) continue;
    kf->covisibility[kv.first] = kv.second;
    if (KeyFrame* other = mutableKeyFrame(kv.first)) other->covisibility[kid] = kv.second;
  }
}

std::string Map::checkConsistency() const {
  const auto name = [](const char* what, uint32_t id) {
    return std::string(what) + std::to_string(id);
  };
  for (const auto& [pid, p] : points_) {
    if (p.id != pid) return name("point stored under the wrong id ", pid.value);
    if (!p.p_w.allFinite()) return name("non-finite position of point ", pid.value);
    for (const auto& [kid, idx] : p.observations) {
      const KeyFrame* kf = keyframe(kid);
      if (!kf) return name("point ", pid.value) + name(" observed by missing keyframe ", kid.value);
      if (idx < 0 || idx >= static_cast<int>(kf->points.size()) || kf->points[idx] != pid) {
        return name("point ", pid.value) + name(" not at its keypoint in keyframe ", kid.value);
      }
    }
  }
  for (const auto& [kid, kf] : keyframes_) {
    if (kf.id != kid) return name("keyframe stored under the wrong id ", kid.value);
    if (kf.points.size() != kf.features.size()) {
      return name("keyframe ", kid.value) + " has a point slot count unlike its keypoints";
    }
    for (size_t i = 0; i < kf.points.size(); ++i) {
      if (!kf.points[i].valid()) continue;
      const MapPoint* p = point(kf.points[i]);
      if (!p) continue;  // a culled point: looked up and skipped by every reader
      const auto it = p->observations.find(kid);
      if (it == p->observations.end() || it->second != static_cast<int>(i)) {
        return name("keyframe ", kid.value) + name(" holds point ", kf.points[i].value) +
               " that does not record the observation";
      }
    }
    for (const auto& link : kf.covisibility) {
      if (!keyframe(link.first)) {
        return name("keyframe ", kid.value) +
               name(" linked to missing keyframe ", link.first.value);
      }
    }
  }
  return {};
}

void Map::insertKeyFrame(KeyFrame kf) {
  if (!kf.id.valid()) throw Error("Map::insertKeyFrame: invalid keyframe id 0");
  if (keyframes_.count(kf.id)) {
    throw Error("Map::insertKeyFrame: keyframe " + std::to_string(kf.id.value) + " is present");
  }
  if (!kf.camera) {
    throw Error("Map::insertKeyFrame: keyframe " + std::to_string(kf.id.value) + " has no camera");
  }
  if (kf.points.size() != kf.features.size()) {
    throw Error("Map::insertKeyFrame: keyframe " + std::to_string(kf.id.value) + " has " +
                std::to_string(kf.points.size()) + " point slots for " +
                std::to_string(kf.features.size()) + " keypoints");
  }
  const KeyFrameId id = kf.id;
  keyframes_.emplace(id, std::move(kf));
}

void Map::insertPoint(MapPoint p) {
  if (!p.id.valid()) throw Error("Map::insertPoint: invalid point id 0");
  if (points_.count(p.id)) {
    throw Error("Map::insertPoint: point " + std::to_string(p.id.value) + " is present");
  }
  const MapPointId id = p.id;
  points_.emplace(id, std::move(p));
}

void Map::setCounters(KeyFrameId next_keyframe, MapPointId next_point, uint32_t epoch) {
  for (const auto& kv : keyframes_) {
    if (!(kv.first < next_keyframe)) {
      throw Error("Map::setCounters: next keyframe id " + std::to_string(next_keyframe.value) +
                  " is not above keyframe " + std::to_string(kv.first.value));
    }
  }
  for (const auto& kv : points_) {
    if (!(kv.first < next_point)) {
      throw Error("Map::setCounters: next point id " + std::to_string(next_point.value) +
                  " is not above point " + std::to_string(kv.first.value));
    }
  }
  next_keyframe_ = next_keyframe.value;
  next_point_ = next_point.value;
  epoch_ = epoch;
}

void Map::replaceWith(Map&& other) {
  keyframes_ = std::move(other.keyframes_);
  points_ = std::move(other.points_);
  replaced_ = std::move(other.replaced_);
  replaced_order_ = std::move(other.replaced_order_);
  other.keyframes_.clear();
  other.points_.clear();
  other.replaced_.clear();
  other.replaced_order_.clear();
  next_keyframe_ = other.next_keyframe_;
  next_point_ = other.next_point_;
  metric_ = other.metric_;
  epoch_ = std::max(epoch_, other.epoch_) + 1;
}

void Map::clear() {
  keyframes_.clear();
  points_.clear();
  replaced_.clear();
  replaced_order_.clear();
  metric_ = false;
  ++epoch_;
}

}  // namespace ecar
