#include "ecar_core/slam/loop_closer.h"

#include <algorithm>
#include <chrono>
#include <limits>
#include <unordered_set>

#include "ecar_core/common/timing.h"
#include "ecar_core/slam/local_mapper.h"
#include "ecar_core/slam/optimizer.h"
#include "ecar_core/slam/place_verification.h"
#include "ecar_core/slam/pose_graph.h"

namespace ecar {

struct LoopCloser::Candidate {
  KeyFrameId query, match;
  Sim3 S;  ///< current-side world -> match-side world
  int inliers = 0;
  std::vector<std::pair<MapPointId, MapPointId>> duplicates;  ///< (current side, match side)
};

LoopCloser::LoopCloser(Map* map, PlaceIndex* index, const SlamConfig& config)
    : map_(map), index_(index), config_(config) {}

LoopCloser::~LoopCloser() { stopThread(); }

namespace {
// Queued by requestBundleAdjustAll and closeByOdometry: no keyframe ever has
// these ids.
const KeyFrameId kBundleAdjustAll(std::numeric_limits<uint32_t>::max());
const KeyFrameId kOdometryLoop(std::numeric_limits<uint32_t>::max() - 1);
}  // namespace

void LoopCloser::closeByOdometry(const OdometryLoop& loop) {
  if (!config_.loops.enabled || !config_.loops.by_odometry) return;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    odometry_loops_.push_back(loop);
  }
  worker_.push(kOdometryLoop);
  if (!worker_.threaded()) worker_.processPending();
}

void LoopCloser::processOdometryLoop() {
  OdometryLoop loop;
  int links = 0;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (odometry_loops_.empty()) return;
    loop = odometry_loops_.front();
    odometry_loops_.pop_front();
  }
  {
    auto lock = map_->readLock();
    if (!map_->keyframe(loop.before) || !map_->keyframe(loop.after)) return;
    // The two places are held together by shared points (directly or through
    // a few keyframes): the relocalisation is no loop.
    links = map_->covisibilityHops(loop.before, loop.after, LoopClosure::kCountedLinks);
    if (links < config_.loops.odometry_min_hops ||
        loop.drift_m > config_.loops.odometry_max_drift_per_link * links) {
      return;
    }
  }
  Candidate candidate;
  candidate.query = loop.before;
  candidate.match = loop.after;
  candidate.S.R = loop.G.linear();
  candidate.S.t = loop.G.translation();
  candidate.inliers = loop.inliers;
  LoopClosure report;
  report.query = loop.before;
  report.match = loop.after;
  report.inliers = loop.inliers;
  report.by_odometry = true;
  report.odometry_disagreement_m = loop.drift_m;
  report.links = links;
  close(candidate, &report);
}

void LoopCloser::requestBundleAdjustAll() {
  worker_.push(kBundleAdjustAll);
  if (!worker_.threaded()) worker_.processPending();
}

std::vector<double> LoopCloser::requestedBundleAdjustmentsMs() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return requested_ba_ms_;
}

void LoopCloser::insert(KeyFrameId kf) {
  if (!config_.loops.enabled) return;
  worker_.push(kf);
  // Synchronous mode: deterministic, inside the mapper's call.
  if (!worker_.threaded()) worker_.processPending();
}

void LoopCloser::processPending() { worker_.processPending(); }

void LoopCloser::startThread() { worker_.startThread({"ecar_loops", config_.background_nice}); }

void LoopCloser::stopThread() { worker_.stopThread(); }

void LoopCloser::reset() {
  // Not waiting for a loop being closed: it was computed on the old map, whose
  // epoch differs now, and is dropped before it changes anything (and a
  // corrected callback may be waiting for the caller's own locks).
  worker_.clear();
  std::lock_guard<std::mutex> lock(mutex_);
  odometry_loops_.clear();
  loop_edges_.clear();
  last_loop_keyframe_ = KeyFrameId();
}

bool LoopCloser::idle() const { return worker_.idle(); }

std::vector<LoopClosure> LoopCloser::closures() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return closures_;
}

void LoopCloser::setCorrectedCallback(std::function<void(const MapCorrection&)> callback) {
  std::lock_guard<std::mutex> lock(mutex_);
  callback_ = std::move(callback);
}

void LoopCloser::notify(const MapCorrection& correction) {
  std::function<void(const MapCorrection&)> callback;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    callback = callback_;
  }
  if (callback) callback(correction);
}

void LoopCloser::process(KeyFrameId kf) {
  if (kf == kOdometryLoop) {
    processOdometryLoop();
    return;
  }
  if (kf == kBundleAdjustAll) {
    const double ms = bundleAdjustAll();
    std::lock_guard<std::mutex> lock(mutex_);
    requested_ba_ms_.push_back(ms);
    return;
  }
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (last_loop_keyframe_.valid() &&
        kf.value < last_loop_keyframe_.value +
                       static_cast<uint32_t>(config_.loops.keyframes_between_loops)) {
      return;
    }
  }
  LoopClosure report;
  Candidate candidate;
  const auto t0 = std::chrono::steady_clock::now();
  const bool found = detect(kf, &candidate, &report);
  report.detect_ms = msSince(t0);
  if (!found) return;
  close(candidate, &report);
}

bool LoopCloser::close(const Candidate& candidate, LoopClosure* report) {
  const MapCorrection correction = correct(candidate, report);
  if (correction.empty()) return false;
  size_t index = 0;
  {
    // Recorded before the correction is announced (listeners may read it).
    std::lock_guard<std::mutex> lock(mutex_);
    if (!report->by_odometry) last_loop_keyframe_ = candidate.query;
    index = closures_.size();
    closures_.push_back(*report);
  }
  notify(correction);
  if (config_.loops.global_ba) {
    globalBundleAdjustment(report);
    std::lock_guard<std::mutex> lock(mutex_);
    if (index < closures_.size()) closures_[index].global_ba_ms = report->global_ba_ms;
  }
  return true;
}

bool LoopCloser::detect(KeyFrameId kf, Candidate* out, LoopClosure* report) {
  const LoopClosingConfig& c = config_.loops;
  cv::Mat descriptors;
  std::unordered_set<KeyFrameId> excluded;
  bool metric = false;
  {
    auto lock = map_->readLock();
    metric = map_->metric();
    const KeyFrame* k = map_->keyframe(kf);
    if (!k || k->features.descriptors.empty()) return false;
    if (map_->numKeyFrames() < static_cast<size_t>(c.min_keyframe_gap)) return false;
    descriptors = k->features.descriptors;
    excluded.insert(kf);
    for (const KeyFrameId n : map_->bestCovisible(kf, c.covisible_excluded)) excluded.insert(n);
  }
  const std::vector<PlaceCandidate> candidates =
      index_->query(descriptors, static_cast<size_t>(c.covisible_excluded) + 3 * c.candidates, 0.0);
  size_t tried = 0;
  for (const PlaceCandidate& pc : candidates) {
    if (tried >= c.candidates) break;
    if (excluded.count(pc.keyframe) ||
        pc.keyframe.value + static_cast<uint32_t>(c.min_keyframe_gap) > kf.value) {
      continue;
    }
    ++tried;
    const std::optional<PlaceMatch> m =
        // A metric map (odometry) keeps its scale: SE(3), as a merge of metric maps.
        verifyPlace(*map_, kf, *map_, pc.keyframe, excluded, c, metric, kf.value);
    if (!m) continue;
    Candidate cand;
    cand.duplicates = m->duplicates;
    cand.query = kf;
    cand.match = pc.keyframe;
    cand.S = m->S;
    cand.inliers = m->inliers;
    *out = std::move(cand);
    report->query = kf;
    report->match = pc.keyframe;
    report->inliers = m->inliers;
    report->scale = m->S.scale;
    return true;
  }
  return false;
}

MapCorrection LoopCloser::correct(const Candidate& cand, LoopClosure* report) {
  const auto t0 = std::chrono::steady_clock::now();
  const LoopClosingConfig& c = config_.loops;
  // A snapshot of the keyframe graph.
  std::vector<KeyFrameId> ids;
  std::vector<Sim3> S_old;
  std::vector<std::vector<std::pair<KeyFrameId, int>>> neighbours;
  std::unordered_map<KeyFrameId, int> index;
  std::unordered_set<KeyFrameId> current_side;
  std::vector<KeyFrameId> match_side;
  uint32_t epoch = 0;
  {
    auto lock = map_->readLock();
    epoch = map_->epoch();
    const KeyFrame* q = map_->keyframe(cand.query);
    if (!q || !map_->keyframe(cand.match)) return {};
    report->device = q->device;
    ids = map_->keyframeIds();
    std::sort(ids.begin(), ids.end());
    for (size_t i = 0; i < ids.size(); ++i) {
      const KeyFrame* k = map_->keyframe(ids[i]);
      index[ids[i]] = static_cast<int>(i);
      S_old.push_back(similarityOf(k->T_c_w));
      std::vector<std::pair<KeyFrameId, int>> n(k->covisibility.begin(), k->covisibility.end());
      neighbours.push_back(std::move(n));
    }
    current_side.insert(cand.query);
    for (const KeyFrameId n : map_->bestCovisible(cand.query, c.covisible_excluded)) {
      current_side.insert(n);
    }
    match_side.push_back(cand.match);
    for (const KeyFrameId n : map_->bestCovisible(cand.match, 5)) {
      if (!current_side.count(n)) match_side.push_back(n);
    }
  }
  // The current side moves rigidly with the loop's similarity; the pose graph
  // spreads the rest of the correction along the essential graph.
  const Sim3 S_inverse = cand.S.inverse();
  std::vector<Sim3> initial = S_old;
  for (const KeyFrameId id : current_side) {
    const auto it = index.find(id);
    if (it != index.end()) initial[it->second] = S_old[it->second] * S_inverse;
  }
  std::vector<PoseGraphEdge> edges;
  const auto edge = [&](int a, int b, const Sim3& S_a_b) { edges.push_back({a, b, S_a_b, 1.0}); };
  for (size_t i = 0; i < ids.size(); ++i) {
    // Spanning tree: the older neighbour sharing the most points.
    int parent = -1, parent_weight = 0;
    for (const auto& [n, w] : neighbours[i]) {
      const auto it = index.find(n);
      if (it == index.end() || it->second >= static_cast<int>(i)) continue;
      if (w > parent_weight) {
        parent_weight = w;
        parent = it->second;
      }
      if (w >= c.strong_covisibility)
        edge(static_cast<int>(i), it->second, relative(S_old[i], S_old[it->second]));
    }
    if (parent >= 0 && parent_weight < c.strong_covisibility) {
      edge(static_cast<int>(i), parent, relative(S_old[i], S_old[parent]));
    } else if (parent < 0 && i > 0) {
      edge(static_cast<int>(i), static_cast<int>(i) - 1, relative(S_old[i], S_old[i - 1]));
    }
  }
  // The new loop, between the current side and the match side.
  for (const KeyFrameId a : current_side) {
    for (const KeyFrameId b : match_side) {
      const auto ia = index.find(a), ib = index.find(b);
      if (ia == index.end() || ib == index.end()) continue;
      edge(ia->second, ib->second, relative(initial[ia->second], initial[ib->second]));
    }
  }
  {
    std::lock_guard<std::mutex> lock(mutex_);
    for (const LoopEdge& l : loop_edges_) {
      const auto ia = index.find(l.a), ib = index.find(l.b);
      if (ia != index.end() && ib != index.end()) edge(ia->second, ib->second, l.S_a_b);
    }
  }
  std::vector<bool> fixed(ids.size(), false);
  fixed[0] = true;  // the map's oldest keyframe: its origin
  fixed[index.at(cand.match)] = true;
  PoseGraphConfig pc;
  pc.iterations = c.pose_graph_iterations;
  const PoseGraphResult r = optimizePoseGraph(initial, fixed, edges, pc);
  if (!r.converged) return {};

  std::unordered_map<KeyFrameId, Sim3> before, after;
  for (size_t i = 0; i < ids.size(); ++i) {
    before[ids[i]] = S_old[i];
    after[ids[i]] = r.S_c_w[i];
  }
  MapCorrection correction;
  {
    auto lock = map_->writeLock();
    if (map_->epoch() != epoch) return {};  // the map was replaced meanwhile
    const KeyFrame* q = map_->keyframe(cand.query);
    const Eigen::Vector3d centre_before = q ? q->center() : Eigen::Vector3d::Zero();
    correction = applyCorrection(map_, before, after);
    if (q) report->drift_m = (map_->keyframe(cand.query)->center() - centre_before).norm();
    // Weld the seam: the same physical points seen from both sides become one.
    for (const auto& [mine, theirs] : cand.duplicates) {
      const MapPoint* a = map_->point(mine);
      const MapPoint* b = map_->point(theirs);
      if (!a || !b || mine == theirs) continue;
      if (a->observations.size() > b->observations.size()) {
        map_->replacePoint(theirs, mine);
      } else {
        map_->replacePoint(mine, theirs);
      }
      ++report->points_fused;
    }
    for (const KeyFrameId id : current_side) {
      if (map_->keyframe(id)) map_->updateCovisibility(id);
    }
    for (const KeyFrameId id : match_side) {
      if (map_->keyframe(id)) map_->updateCovisibility(id);
    }
  }
  {
    std::lock_guard<std::mutex> lock(mutex_);
    loop_edges_.push_back(
        {cand.query, cand.match, relative(after.at(cand.query), after.at(cand.match))});
  }
  report->keyframes_moved = correction.keyframes.size();
  report->points_moved = correction.points_moved;
  report->correct_ms = msSince(t0);
  return correction;
}

double LoopCloser::bundleAdjustAll() {
  LoopClosure report;
  globalBundleAdjustment(&report);
  return report.global_ba_ms;
}

void LoopCloser::globalBundleAdjustment(LoopClosure* report) {
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
    kf_ids = map_->keyframeIds();
    std::sort(kf_ids.begin(), kf_ids.end());
    if (kf_ids.size() < 3) return;
    std::unordered_map<KeyFrameId, int> kf_index;
    for (size_t i = 0; i < kf_ids.size(); ++i) {
      const KeyFrame* k = map_->keyframe(kf_ids[i]);
      kf_index[kf_ids[i]] = static_cast<int>(i);
      problem.keyframes.push_back(
          {k->T_c_w, k->K(), i == 0, k->alignedUp(config_.gravity_tolerance_deg)});
    }
    point_ids = map_->pointIds();
    for (size_t p = 0; p < point_ids.size(); ++p) {
      const MapPoint* mp = map_->point(point_ids[p]);
      problem.points.push_back({mp->p_w});
      for (const auto& [kid, idx] : mp->observations) {
        const auto it = kf_index.find(kid);
        if (it == kf_index.end()) continue;
        const KeyFrame* k = map_->keyframe(kid);
        const int octave = k->features.keypoints[idx].octave;
        problem.observations.push_back({it->second, static_cast<int>(p),
                                        k->features.undistorted[idx],
                                        map_->scale().inv_sigma2[octave], false});
      }
    }
    if (map_->metric()) addOdometryEdges(*map_, config_, kf_ids, &problem);
  }
  BaConfig ba = config_.ba;
  ba.iterations_first = std::max(1, config_.loops.global_ba_iterations / 2);
  ba.iterations_second = config_.loops.global_ba_iterations;
  const BaResult result = localBundleAdjust(&problem, ba);
  if (!result.converged) return;
  std::unordered_map<KeyFrameId, Sim3> before, after;
  MapCorrection correction;
  {
    auto lock = map_->writeLock();
    if (map_->epoch() != epoch || map_->revision() != revision) return;  // moved meanwhile
    for (size_t i = 0; i < kf_ids.size(); ++i) {
      const KeyFrame* k = map_->keyframe(kf_ids[i]);
      if (!k) continue;
      before[kf_ids[i]] = similarityOf(k->T_c_w);
      after[kf_ids[i]] = similarityOf(problem.keyframes[i].T_c_w);
    }
    correction = applyCorrection(map_, before, after);
    // The adjusted points take their own positions, not their keyframe's motion.
    for (size_t p = 0; p < point_ids.size(); ++p) {
      if (MapPoint* mp = map_->mutablePoint(point_ids[p])) mp->p_w = problem.points[p].p_w;
    }
    for (const MapPointId pid : point_ids) map_->updatePointStatistics(pid);
  }
  report->global_ba_ms = msSince(t0);
  notify(correction);
}

}  // namespace ecar
