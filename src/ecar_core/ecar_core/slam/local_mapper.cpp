// Local mapping: every keyframe from every device enters the one map here.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <unordered_set>

#include "ecar_core/common/error.h"
#include "ecar_core/slam/local_mapper.h"
#include "ecar_core/slam/loop_closer.h"
#include "ecar_core/slam/matcher.h"

namespace ecar {

LocalMapper::LocalMapper(Map* map, PlaceIndex* index, const SlamConfig& config,
                         KeypointIndex* keypoints)
    : map_(map), index_(index), keypoints_(keypoints), config_(config) {}

LocalMapper::~LocalMapper() { stopThread(); }

void LocalMapper::insert(KeyFrameId kf) { worker_.push(kf); }

bool LocalMapper::idle() const { return worker_.idle(); }

std::vector<double> LocalMapper::baTimes() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return ba_ms_;
}

void LocalMapper::setMappedCallback(std::function<void(KeyFrameId)> callback) {
  std::lock_guard<std::mutex> lock(mutex_);
  mapped_callback_ = std::move(callback);
}

void LocalMapper::setCulledCallback(std::function<void(KeyFrameId, KeyFrameId)> callback) {
  std::lock_guard<std::mutex> lock(mutex_);
  culled_callback_ = std::move(callback);
}

void LocalMapper::processPending() { worker_.processPending(); }

void LocalMapper::startThread() { worker_.startThread({"ecar_mapping", config_.background_nice}); }

void LocalMapper::stopThread() { worker_.stopThread(); }

void LocalMapper::reset() {
  const bool threaded = worker_.threaded();
  worker_.clear();
  worker_.stopThread();  // finishes the keyframe being mapped, if any
  recent_points_.clear();
  if (threaded) startThread();
}

void LocalMapper::process(KeyFrameId kf) {
  {
    auto lock = map_->writeLock();
    KeyFrame* k = map_->mutableKeyFrame(kf);
    if (!k) return;
    // Points the tracker matched: refresh their statistics with this view.
    for (const auto& pid : k->points) {
      if (map_->point(pid)) map_->updatePointStatistics(pid);
    }
    map_->updateCovisibility(kf);
  }
  cullRecentPoints(kf);
  triangulateNewPoints(kf);
  fuseDuplicates(kf);
  localBundleAdjustment(kf);
  cullKeyFrames(kf);
  cv::Mat descriptors;
  std::vector<int> point_rows;  // keypoints with a map point
  {
    auto lock = map_->readLock();
    if (const KeyFrame* k = map_->keyframe(kf)) {
      descriptors = k->features.descriptors;
      for (size_t i = 0; i < k->points.size(); ++i) {
        if (map_->point(k->points[i])) point_rows.push_back(static_cast<int>(i));
      }
    }
  }
  if (!descriptors.empty()) index_->add(kf, descriptors);
  if (!descriptors.empty() && keypoints_) keypoints_->add(kf, descriptors, point_rows);
  std::function<void(KeyFrameId)> callback;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    callback = mapped_callback_;
  }
  if (callback) callback(kf);
  if (loop_closer_) loop_closer_->insert(kf);
}

void LocalMapper::cullRecentPoints(KeyFrameId kf) {
  auto lock = map_->writeLock();
  const uint32_t current = kf.value;
  std::vector<MapPointId> keep;
  for (const auto& pid : recent_points_) {
    MapPoint* p = map_->mutablePoint(pid);
    if (!p) continue;
    const uint32_t age = current - p->first_keyframe.value;
    if (p->foundRatio() < 0.25f || (age >= 2 && p->observations.size() <= 2)) {
      map_->erasePoint(pid);
    } else if (age < 3) {
      keep.push_back(pid);
    }
  }
  recent_points_.swap(keep);
}

int LocalMapper::triangulateNewPoints(KeyFrameId kf) {
  // Copy what is needed under the read lock; triangulate; add under the write lock.
  struct View {
    KeyFrameId id;
    SE3 T_c_w;
    Intrinsics K;  ///< of the keyframe's own camera
    Frame features;
    std::vector<bool> used;
  };
  View cur;
  std::vector<View> neighbours;
  double median_depth = 1.0;
  {
    auto lock = map_->readLock();
    const KeyFrame* k = map_->keyframe(kf);
    if (!k) return 0;
    cur = {kf, k->T_c_w, k->K(), k->features, {}};
    for (const auto& id : k->points) cur.used.push_back(map_->point(id) != nullptr);
    std::vector<double> depths;
    for (const auto& id : k->points) {
      if (const MapPoint* p = map_->point(id)) depths.push_back((k->T_c_w * p->p_w).z());
    }
    if (!depths.empty()) {
      std::nth_element(depths.begin(), depths.begin() + depths.size() / 2, depths.end());
      median_depth = depths[depths.size() / 2];
    }
    for (const auto& nid : map_->bestCovisible(kf, config_.covisible_triangulation)) {
      const KeyFrame* n = map_->keyframe(nid);
      if (!n) continue;
      // Baseline large enough compared with the scene depth.
      if ((n->center() - k->center()).norm() < 0.01 * median_depth) continue;
      View v{nid, n->T_c_w, n->K(), n->features, {}};
      for (const auto& id : n->points) v.used.push_back(map_->point(id) != nullptr);
      neighbours.push_back(std::move(v));
    }
  }
  const ScaleInfo& scale = map_->scale();
  struct NewPoint {
    Eigen::Vector3d p_w;
    KeyFrameId other;
    int idx_cur, idx_other;
  };
  std::vector<NewPoint> created;
  const SE3 T_w_c1 = cur.T_c_w.inverse();
  for (auto& n : neighbours) {
    const auto pairs = searchForTriangulation(cur.features, cur.T_c_w, cur.used, n.features,
                                              n.T_c_w, n.used, cur.K, n.K, scale);
    const SE3 T_w_c2 = n.T_c_w.inverse();
    for (const auto& [i1, i2] : pairs) {
      const Eigen::Vector2d& u1 = cur.features.undistorted[i1];
      const Eigen::Vector2d& u2 = n.features.undistorted[i2];
      const Eigen::Vector2d x1((u1.x() - cur.K.cx) / cur.K.fx, (u1.y() - cur.K.cy) / cur.K.fy);
      const Eigen::Vector2d x2((u2.x() - n.K.cx) / n.K.fx, (u2.y() - n.K.cy) / n.K.fy);
      const auto p = triangulate(cur.T_c_w, n.T_c_w, x1, x2);
      if (!p) continue;
      // Enough parallax, small reprojection errors, consistent scales.
      const Eigen::Vector3d r1 = *p - T_w_c1.translation(), r2 = *p - T_w_c2.translation();
      const double cos_parallax = r1.dot(r2) / (r1.norm() * r2.norm());
      if (cos_parallax > 0.9998) continue;
      bool ok = true;
      for (int view = 0; view < 2 && ok; ++view) {
        const SE3& T = view == 0 ? cur.T_c_w : n.T_c_w;
        const Frame& f = view == 0 ? cur.features : n.features;
        const Intrinsics& K = view == 0 ? cur.K : n.K;
        const int idx = view == 0 ? i1 : i2;
        const Eigen::Vector3d pc = T * *p;
        if (pc.z() <= 0) {
          ok = false;
          break;
        }
        const Eigen::Vector2d proj(K.fx * pc.x() / pc.z() + K.cx, K.fy * pc.y() / pc.z() + K.cy);
        const int octave = f.keypoints[idx].octave;
        if ((proj - f.undistorted[idx]).squaredNorm() > 5.991 * scale.sigma2[octave]) ok = false;
      }
      if (!ok) continue;
      const double ratio_dist = r2.norm() / r1.norm();
      const double ratio_octave = scale.scale[cur.features.keypoints[i1].octave] /
                                  scale.scale[n.features.keypoints[i2].octave];
      if (ratio_dist * 1.8 < ratio_octave || ratio_dist > ratio_octave * 1.8) continue;
      created.push_back({*p, n.id, i1, i2});
      cur.used[i1] = true;
      n.used[i2] = true;
    }
  }
  auto lock = map_->writeLock();
  int added = 0;
  KeyFrame* k = map_->mutableKeyFrame(kf);
  if (!k) return 0;
  for (const auto& np : created) {
    KeyFrame* other = map_->mutableKeyFrame(np.other);
    if (!other) continue;
    // The keypoints may have been matched meanwhile (by the tracker or a fusion).
    if (map_->point(k->points[np.idx_cur]) || map_->point(other->points[np.idx_other])) continue;
    const MapPointId pid = map_->addPoint(np.p_w, kf);
    map_->addObservation(pid, kf, np.idx_cur);
    map_->addObservation(pid, np.other, np.idx_other);
    map_->updatePointStatistics(pid);
    recent_points_.push_back(pid);
    ++added;
  }
  map_->updateCovisibility(kf);
  return added;
}

int LocalMapper::fuseDuplicates(KeyFrameId kf) {
  // Both ways, as ORB-SLAM does: the keyframe's points into its neighbours, and
  // the neighbours' points into the keyframe. Where a keypoint already has
  // another point for the same place, the two are merged; where it has none,
  // the observation is added.
  auto lock = map_->writeLock();
  const KeyFrame* k = map_->keyframe(kf);
  if (!k) return 0;
  const std::vector<KeyFrameId> neighbours = map_->bestCovisible(kf, 10);
  std::vector<MapPointId> own;
  for (const auto& id : k->points) {
    if (map_->point(id)) own.push_back(id);
  }
  int fused = 0;
  for (const auto& nid : neighbours) fused += fuseInto(nid, own);
  std::vector<MapPointId> theirs;
  std::unordered_set<MapPointId> seen(own.begin(), own.end());
  for (const auto& nid : neighbours) {
    const KeyFrame* n = map_->keyframe(nid);
    if (!n) continue;
    for (const auto& id : n->points) {
      if (map_->point(id) && seen.insert(id).second) theirs.push_back(id);
    }
  }
  fused += fuseInto(kf, theirs);
  map_->updateCovisibility(kf);
  for (const auto& nid : neighbours) map_->updateCovisibility(nid);
  return fused;
}

int LocalMapper::weld(KeyFrameId a, KeyFrameId b, size_t window) {
  auto lock = map_->writeLock();
  const auto around = [&](KeyFrameId k) {
    std::vector<KeyFrameId> w;
    if (!map_->keyframe(k)) return w;
    w.push_back(k);
    for (const KeyFrameId n : map_->bestCovisible(k, window)) w.push_back(n);
    return w;
  };
  const auto pointsOf = [&](const std::vector<KeyFrameId>& w) {
    std::vector<MapPointId> points;
    std::unordered_set<MapPointId> seen;
    for (const KeyFrameId k : w) {
      for (const MapPointId id : map_->keyframe(k)->points) {
        if (map_->point(id) && seen.insert(id).second) points.push_back(id);
      }
    }
    return points;
  };
  const std::vector<KeyFrameId> wa = around(a), wb = around(b);
  int fused = 0;
  const std::vector<MapPointId> from_a = pointsOf(wa);
  for (const KeyFrameId k : wb) fused += fuseInto(k, from_a);
  const std::vector<MapPointId> from_b = pointsOf(wb);
  for (const KeyFrameId k : wa) fused += fuseInto(k, from_b);
  for (const KeyFrameId k : wa) map_->updateCovisibility(k);
  for (const KeyFrameId k : wb) map_->updateCovisibility(k);
  return fused;
}

int LocalMapper::fuseInto(KeyFrameId target, const std::vector<MapPointId>& points) {
  KeyFrame* n = map_->mutableKeyFrame(target);
  if (!n) return 0;
  const Eigen::Vector3d center = n->center();
  std::vector<int> candidates;
  int fused = 0;
  for (const auto& pid : points) {
    const MapPoint* p = map_->point(pid);
    if (!p || p->observations.count(target) || p->descriptor.empty()) continue;
    const Eigen::Vector3d pc = n->T_c_w * p->p_w;
    if (pc.z() <= 0) continue;
    const Intrinsics K = n->K();
    const Eigen::Vector2d uv(K.fx * pc.x() / pc.z() + K.cx, K.fy * pc.y() / pc.z() + K.cy);
    const double dist = (p->p_w - center).norm();
    if (p->max_distance > 0 && (dist < 0.8 * p->min_distance || dist > 1.2 * p->max_distance)) {
      continue;
    }
    if ((p->p_w - center).dot(p->normal) < 0.5 * dist) continue;
    const int level = p->predictScale(dist, map_->scale());
    const double radius = 3.0 * map_->scale().scale[level];
    n->features.grid.query(uv.x(), uv.y(), radius, level - 1, level + 1, &candidates);
    int best = kDescriptorThresholdLow + 1, best_idx = -1;
    for (int idx : candidates) {
      const int octave = n->features.keypoints[idx].octave;
      if ((n->features.undistorted[idx] - uv).squaredNorm() >
          5.991 * map_->scale().sigma2[octave]) {
        continue;
      }
      const int d = descriptorDistance(p->descriptor.ptr<uint8_t>(0),
                                       n->features.descriptors.ptr<uint8_t>(idx));
      if (d < best) {
        best = d;
        best_idx = idx;
      }
    }
    if (best_idx < 0) continue;
    const MapPointId existing = n->points[best_idx];
    if (const MapPoint* e = map_->point(existing)) {
      // Keep the point with more observations.
      if (e->observations.size() >= p->observations.size()) {
        map_->replacePoint(pid, existing);
      } else {
        map_->replacePoint(existing, pid);
      }
    } else {
      map_->addObservation(pid, target, best_idx);
      map_->updatePointStatistics(pid);
    }
    ++fused;
  }
  return fused;
}

void addOdometryEdges(const Map& map, const SlamConfig& config, const std::vector<KeyFrameId>& ids,
                      BaProblem* problem) {
  if (!config.odometryEdges()) return;
  // Each device's keyframes in the window with odometry, in time order; an
  // edge between consecutive ones.
  struct Stamped {
    double timestamp;
    int index;
    const KeyFrame* kf;
  };
  std::unordered_map<DeviceId, std::vector<Stamped>> by_device;
  for (size_t i = 0; i < ids.size(); ++i) {
    const KeyFrame* k = map.keyframe(ids[i]);
    if (k && k->features.T_o_c) {
      by_device[k->device].push_back({k->timestamp, static_cast<int>(i), k});
    }
  }
  for (auto& [device, list] : by_device) {
    std::sort(list.begin(), list.end(),
              [](const Stamped& a, const Stamped& b) { return a.timestamp < b.timestamp; });
    for (size_t i = 1; i < list.size(); ++i) {
      const Stamped& a = list[i - 1];
      const Stamped& b = list[i];
      if (b.timestamp - a.timestamp > config.odometry_max_gap) continue;
      const SE3& T_o_a = *a.kf->features.T_o_c;
      const SE3& T_o_b = *b.kf->features.T_o_c;
      BaProblem::OdometryEdge edge;
      edge.from = a.index;
      edge.to = b.index;
      edge.t_from_to = T_o_a.linear().transpose() * (T_o_b.translation() - T_o_a.translation());
      edge.sigma = config.odometrySigma(edge.t_from_to.norm());
      problem->odometry.push_back(edge);
    }
  }
}

void LocalMapper::localBundleAdjustment(KeyFrameId kf) {
  const auto t0 = std::chrono::steady_clock::now();
  BaProblem problem;
  std::vector<KeyFrameId> kf_ids;
  std::vector<MapPointId> point_ids;
  uint32_t epoch = 0;
  uint64_t revision = 0;
  {
    auto lock = map_->readLock();
    epoch = map_->epoch();
    revision = map_->revision();
    if (!map_->keyframe(kf)) return;
    std::vector<KeyFrameId> local = {kf};
    if (map_->metric() && config_.odometryEdges() &&
        map_->numKeyFrames() <= static_cast<size_t>(config_.ba_whole_map_keyframes)) {
      // A young metric map: all of it, so that every device's odometry sets
      // its scale at once (see SlamConfig::ba_whole_map_keyframes).
      for (const auto& id : map_->keyframeIds()) {
        if (id != kf) local.push_back(id);
      }
    } else {
      for (const auto& n : map_->bestCovisible(kf, config_.ba_keyframes)) local.push_back(n);
    }
    std::unordered_map<KeyFrameId, int> kf_index;
    for (const auto& id : local) {
      kf_index[id] = static_cast<int>(problem.keyframes.size());
      const KeyFrame* k = map_->keyframe(id);
      problem.keyframes.push_back(
          {k->T_c_w, k->K(), false, k->alignedUp(config_.gravity_tolerance_deg)});
      kf_ids.push_back(id);
    }
    // The first keyframe of the map anchors the gauge when it is in the window.
    std::unordered_set<MapPointId> seen;
    for (const auto& id : local) {
      for (const auto& pid : map_->keyframe(id)->points) {
        if (map_->point(pid) && seen.insert(pid).second) point_ids.push_back(pid);
      }
    }
    std::unordered_map<MapPointId, int> point_index;
    for (const auto& pid : point_ids) {
      point_index[pid] = static_cast<int>(problem.points.size());
      problem.points.push_back({map_->point(pid)->p_w});
    }
    // Keyframes that see local points but are not local are fixed.
    for (const auto& pid : point_ids) {
      const MapPoint* p = map_->point(pid);
      for (const auto& obs : p->observations) {
        auto it = kf_index.find(obs.first);
        if (it == kf_index.end()) {
          const KeyFrame* fk = map_->keyframe(obs.first);
          if (!fk) continue;
          it = kf_index.emplace(obs.first, static_cast<int>(problem.keyframes.size())).first;
          problem.keyframes.push_back({fk->T_c_w, fk->K(), true, std::nullopt});
          kf_ids.push_back(obs.first);
        }
        const KeyFrame* ok = map_->keyframe(obs.first);
        const int octave = ok->features.keypoints[obs.second].octave;
        problem.observations.push_back({it->second, point_index[pid],
                                        ok->features.undistorted[obs.second],
                                        map_->scale().inv_sigma2[octave], false});
      }
    }
    // Gauge: with no fixed keyframe (a young map) fix the oldest one.
    bool any_fixed = false;
    for (const auto& k : problem.keyframes) any_fixed |= k.fixed;
    if (!any_fixed) {
      size_t oldest = 0;
      for (size_t i = 1; i < kf_ids.size(); ++i) {
        if (kf_ids[i] < kf_ids[oldest]) oldest = i;
      }
      problem.keyframes[oldest].fixed = true;
    }
    if (map_->metric()) addOdometryEdges(*map_, config_, kf_ids, &problem);
  }
  if (problem.observations.empty()) return;
  localBundleAdjust(&problem, config_.ba);

  auto lock = map_->writeLock();
  // The map was reset, or moved by a loop correction, meanwhile.
  if (map_->epoch() != epoch || map_->revision() != revision) return;
  for (size_t i = 0; i < kf_ids.size(); ++i) {
    if (problem.keyframes[i].fixed) continue;
    if (KeyFrame* k = map_->mutableKeyFrame(kf_ids[i])) k->T_c_w = problem.keyframes[i].T_c_w;
  }
  for (size_t i = 0; i < point_ids.size(); ++i) {
    if (MapPoint* p = map_->mutablePoint(point_ids[i])) {
      if ((p->p_w - problem.points[i].p_w).squaredNorm() > 1e-12) ++p->version;
      p->p_w = problem.points[i].p_w;
    }
  }
  for (const auto& o : problem.observations) {
    if (o.outlier) map_->eraseObservation(point_ids[o.point], kf_ids[o.keyframe]);
  }
  for (const auto& pid : point_ids) {
    if (map_->point(pid)) map_->updatePointStatistics(pid);
  }
  lock.unlock();
  std::lock_guard<std::mutex> ql(mutex_);
  ba_ms_.push_back(
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
}

void LocalMapper::cullKeyFrames(KeyFrameId kf) {
  // A neighbour whose points are (90%) seen by at least three other keyframes
  // at the same or a finer scale is redundant.
  auto lock = map_->writeLock();
  for (const auto& nid : map_->bestCovisible(kf, 20)) {
    const KeyFrame* n = map_->keyframe(nid);
    if (!n || nid.value <= 2) continue;  // keep the initial pair
    int total = 0, redundant = 0;
    for (size_t i = 0; i < n->points.size(); ++i) {
      const MapPoint* p = map_->point(n->points[i]);
      if (!p) continue;
      ++total;
      if (p->observations.size() <= 3) continue;
      const int octave = n->features.keypoints[i].octave;
      int others = 0;
      for (const auto& obs : p->observations) {
        if (obs.first == nid) continue;
        const KeyFrame* o = map_->keyframe(obs.first);
        if (o && o->features.keypoints[obs.second].octave <= octave + 1 && ++others >= 3) break;
      }
      if (others >= 3) ++redundant;
    }
    if (total > 0 && redundant > 0.9 * total) {
      KeyFrameId heir;
      for (const auto& h : map_->bestCovisible(nid, 1)) heir = h;
      map_->eraseKeyFrame(nid);
      lock.unlock();
      index_->remove(nid);
      if (keypoints_) keypoints_->remove(nid);
      std::function<void(KeyFrameId, KeyFrameId)> callback;
      {
        std::lock_guard<std::mutex> ql(mutex_);
        callback = culled_callback_;
      }
      if (callback) callback(nid, heir);
      lock.lock();
    }
  }
}

}  // namespace ecar
