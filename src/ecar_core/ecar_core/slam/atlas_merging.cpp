// The atlas's merges (see atlas.h): finding an overlap between maps (place
// recognition on a new keyframe, or a relocalisation probe of a tracked upload
// into the other maps), merging the smaller map into the larger, and the
// adjustment after it.
#include <algorithm>
#include <chrono>
#include <map>

#include "ecar_core/common/timing.h"
#include "ecar_core/slam/atlas.h"
#include "ecar_core/slam/map_merge.h"
#include "ecar_core/slam/place_verification.h"
#include "ecar_core/slam/sim3_solver.h"

namespace ecar {

std::optional<Atlas::MergeCandidate> Atlas::relocalisedOverlap(MapId a_id, const SlamSystem& a,
                                                               const TrackResult& in_a, MapId b_id,
                                                               const SlamSystem& b,
                                                               const TrackResult& in_b,
                                                               DeviceId device) const {
  if (in_b.state != TrackingState::kOk) return std::nullopt;
  // One image, one extractor: a keypoint matched in both maps is one point.
  std::map<std::pair<float, float>, const TrackedPoint*> in_a_by_pixel;
  for (const TrackedPoint& t : in_a.tracked) in_a_by_pixel[{t.keypoint.pt.x, t.keypoint.pt.y}] = &t;
  std::vector<PointPair> pairs;
  std::vector<std::pair<MapPointId, MapPointId>> ids;
  const Eigen::Vector3d centre_b = in_b.T_w_c.translation();
  for (const TrackedPoint& t : in_b.tracked) {
    const auto it = in_a_by_pixel.find({t.keypoint.pt.x, t.keypoint.pt.y});
    if (it == in_a_by_pixel.end()) continue;
    pairs.push_back({it->second->p_w, t.p_w,
                     config_.loops.tolerance_fraction * (t.p_w - centre_b).norm() + 0.01});
    ids.emplace_back(it->second->id, t.id);
  }
  bool metric = false;
  {
    auto la = a.map().readLock();
    auto lb = b.map().readLock();
    metric = a.map().metric() && b.map().metric();
  }
  Sim3EstimateConfig sc;
  sc.min_inliers = atlas_.relocalise_min_inliers;
  sc.fix_scale = metric;
  sc.seed = in_a.map_epoch;
  const Sim3Estimate e = estimateSim3(pairs, sc);
  if (!e.success) return std::nullopt;
  MergeCandidate c;
  c.a = a_id;
  c.b = b_id;
  c.S = e.S;
  for (size_t i = 0; i < ids.size(); ++i) {
    if (e.inliers[i]) c.duplicates.push_back(ids[i]);
  }
  if (!in_a.local_keyframes.empty()) c.query = in_a.local_keyframes.front();
  if (!in_b.local_keyframes.empty()) c.match = in_b.local_keyframes.front();
  c.device = device;
  c.inliers = e.num_inliers;
  return c;
}

void Atlas::tryMerge(MapId map_id, KeyFrameId keyframe, DeviceId device) {
  const auto start = std::chrono::steady_clock::now();
  std::optional<MergeCandidate> found;
  {
    // The search alongside the other devices' tracking (it was 11% of the
    // server's CPU with twenty devices, all of it blocking them); only the
    // merge itself stops them. doMerge() finds out if a map went meanwhile.
    std::shared_lock<std::shared_mutex> session(session_mutex_);
    found = findMerge(map_id, keyframe, device);
  }
  if (!found) return;
  std::shared_ptr<SlamSystem> merged;
  std::vector<KeyFrameId> moved;
  {
    std::unique_lock<std::shared_mutex> session(session_mutex_);  // no track() runs
    merged = doMerge(*found, start, &moved);
  }
  adjustMerged(merged, moved);
}

std::optional<Atlas::MergeCandidate> Atlas::findMerge(MapId map_id, KeyFrameId keyframe,
                                                      DeviceId device) const {
  std::shared_ptr<SlamSystem> a;
  std::vector<std::pair<MapId, std::shared_ptr<SlamSystem>>> others;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    a = slamOf(map_id);
    for (const Entry& e : maps_) {
      if (e.id != map_id) others.emplace_back(e.id, e.slam);
    }
  }
  if (!a || others.empty()) return std::nullopt;
  cv::Mat descriptors;
  bool metric_a = false;
  {
    auto lock = a->map().readLock();
    const KeyFrame* k = a->map().keyframe(keyframe);
    if (!k || k->features.descriptors.empty()) return std::nullopt;
    descriptors = k->features.descriptors;
    metric_a = a->map().metric();
  }
  for (const auto& [b_id, b] : others) {
    if (!initialised(*b)) continue;
    bool metric_b = false;
    {
      auto lock = b->map().readLock();
      metric_b = b->map().metric();
    }
    for (const PlaceCandidate& c :
         b->placeIndex().query(descriptors, atlas_.merge_candidates, 0.0)) {
      const std::optional<PlaceMatch> m =
          verifyPlace(a->map(), keyframe, b->map(), c.keyframe, {}, config_.loops,
                      metric_a && metric_b, keyframe.value);
      if (!m) continue;
      return MergeCandidate{map_id,   b_id,       m->S,   m->duplicates,
                            keyframe, c.keyframe, device, m->inliers};
    }
  }
  return std::nullopt;
}

void Atlas::adjustMerged(const std::shared_ptr<SlamSystem>& merged,
                         const std::vector<KeyFrameId>& moved) const {
  if (!merged) return;
  // The moved keyframes join the merged map's place and keypoint indexes
  // (most of a merge's time, 180 of 210 ms on the small ring when it ran
  // under the session lock); tracking goes on meanwhile, and only place
  // recognition and relocalisation could have used them sooner.
  merged->indexKeyFrames(moved);
  // The whole merged map adjusted at once (as after a loop): the seam holds
  // only the points seen from both sides so far. Here, or on the merged map's
  // loop-closer thread (AtlasConfig::background_merge_ba). The correction
  // reaches what hangs on the map through the closer's callback.
  if (!config_.loops.global_ba) return;
  if (atlas_.background_merge_ba) {
    merged->loopCloser().requestBundleAdjustAll();
  } else {
    merged->loopCloser().bundleAdjustAll();
  }
}

std::shared_ptr<SlamSystem> Atlas::doMerge(const MergeCandidate& c,
                                           std::chrono::steady_clock::time_point start,
                                           std::vector<KeyFrameId>* moved) {
  // The smaller map goes into the larger.
  size_t size_a = 0, size_b = 0;
  std::shared_ptr<SlamSystem> a, b;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    a = slamOf(c.a);
    b = slamOf(c.b);
  }
  if (!a || !b) return nullptr;
  {
    auto la = a->map().readLock();
    size_a = a->map().numKeyFrames();
  }
  {
    auto lb = b->map().readLock();
    size_b = b->map().numKeyFrames();
  }
  const bool into_b = size_b >= size_a;
  const std::shared_ptr<SlamSystem> into = into_b ? b : a, from = into_b ? a : b;
  const MapId into_id = into_b ? c.b : c.a, from_id = into_b ? c.a : c.b;
  Sim3 S = into_b ? c.S : c.S.inverse();
  std::vector<std::pair<MapPointId, MapPointId>> duplicates = c.duplicates;
  if (!into_b) {
    for (auto& d : duplicates) std::swap(d.first, d.second);
  }
  from->mapper().stopThread();
  from->loopCloser().stopThread();
  MergeResult r;
  bool metric = false;
  {
    auto lock_into = into->map().writeLock();
    auto lock_from = from->map().writeLock();
    metric = into->map().metric() && from->map().metric();
    r = mergeMaps(&into->map(), &from->map(), S, duplicates);
  }
  // The seam welded: the points around each side fused into the keyframes
  // around the other (the matches of one view gave only a few dozen), so the
  // bundle adjustments after the merge hold the two sides together.
  if (c.query.valid() && c.match.valid()) {
    r.points_fused += static_cast<size_t>(into->mapper().weld(c.query, c.match, 10));
  }
  // The similarity refitted on the welded seam: hundreds of reprojections
  // across it instead of the few dozen 3D positions that verified it.
  MergeEvent event;
  {
    auto lock = into->map().writeLock();
    event.refit = refitMerge(&into->map(), &r, &S, metric);
  }
  // The seam is mapped again: new points across it, fusion, local BA.
  if (c.query.valid()) into->mapper().insert(c.query);
  if (c.match.valid()) into->mapper().insert(c.match);
  if (config_.synchronous_mapping) into->mapper().processPending();
  event.into = into_id;
  event.from = from_id;
  event.query = c.query;
  event.match = c.match;
  event.device = c.device;
  event.inliers = c.inliers;
  event.scale = c.S.scale;
  event.keyframes_moved = r.keyframes_moved;
  event.points_fused = r.points_fused;
  event.S = S;
  event.correction = std::move(r.correction);
  moved->clear();
  for (const auto& kv : event.correction.keyframes) moved->push_back(kv.first);
  std::function<void(const MergeEvent&)> merged;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    for (const LoopClosure& l : from->loopCloser().closures()) closed_loops_.push_back(l);
    for (auto& [id, d] : devices_) {
      if (d.current == from_id) d.current = into_id;
      if (d.fresh == from_id) d.fresh = MapId();
    }
    merged_into_[from_id] = {into_id, S};
    dropMap(from_id);
    merged = callbacks_.merged;
  }
  event.ms = msSince(start);  // verification and the SLAM maps' merge
  // What hangs on the maps moves before any device is answered.
  if (merged) merged(event);
  std::lock_guard<std::mutex> lock(mutex_);
  merges_.push_back(event);
  return into;
}

}  // namespace ecar
