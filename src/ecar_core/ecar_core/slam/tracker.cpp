// Tracking of one device's images against the shared map.
#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <unordered_set>

#include <opencv2/imgproc.hpp>

#include "ecar_core/slam/local_mapper.h"
#include "ecar_core/slam/matcher.h"
#include "ecar_core/slam/tracker.h"

namespace ecar {
namespace {

double msSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

// Whether a keyframe's pose agrees with its own gravity within tol_deg: the
// map's z axis is up there (the map was initialised with gravity).
bool gravityAlignedAt(const KeyFrame& kf, double tol_deg) {
  return kf.alignedUp(tol_deg).has_value();
}

bool hasGravity(const Frame& f) {
  return f.gravity_c && f.gravity_c->allFinite() && f.gravity_c->norm() >= 1.0;
}

// World frame of a new map: origin at the first camera, z up when gravity is
// known (x along the camera's horizontal forward direction), otherwise the
// first camera's frame.
SE3 initialWorldFrame(const std::optional<Eigen::Vector3d>& gravity_c) {
  SE3 T_c_w = SE3::Identity();
  if (!gravity_c || !gravity_c->allFinite() || gravity_c->norm() < 1.0) return T_c_w;
  const Eigen::Vector3d up = gravity_c->normalized();
  Eigen::Vector3d forward = Eigen::Vector3d::UnitZ() - up.z() * up;
  if (forward.norm() < 1e-3) forward = Eigen::Vector3d::UnitX() - up.x() * up;
  forward.normalize();
  // Columns: the world axes expressed in the camera frame.
  T_c_w.linear().col(0) = forward;
  T_c_w.linear().col(1) = up.cross(forward);
  T_c_w.linear().col(2) = up;
  return T_c_w;
}

// Ids of the map points the keyframes observe, each once, in keyframe order
// (the map's read lock held).
template <typename KeyFrames>
std::vector<MapPointId> pointsSeenBy(const Map& map, const KeyFrames& keyframes) {
  std::unordered_set<MapPointId> seen;
  std::vector<MapPointId> ids;
  for (const KeyFrameId& k : keyframes) {
    const KeyFrame* kf = map.keyframe(k);
    if (!kf) continue;
    for (const auto& id : kf->points) {
      if (id.valid() && seen.insert(id).second) ids.push_back(id);
    }
  }
  return ids;
}
}  // namespace

const char* toString(TrackingState state) {
  switch (state) {
    case TrackingState::kOk:
      return "OK";
    case TrackingState::kLost:
      return "LOST";
    default:
      return "NOT_INITIALISED";
  }
}

Tracker::Tracker(DeviceId device, Map* map, PlaceIndex* index, LocalMapper* mapper,
                 const PinholeCamera& camera, const SlamConfig& config, KeypointIndex* keypoints)
    : device_(device),
      map_(map),
      index_(index),
      keypoints_(keypoints),
      mapper_(mapper),
      camera_(camera),
      K_(intrinsicsOf(camera)),
      config_(config),
      extractor_(config.orb) {}

void Tracker::reset() {
  state_ = TrackingState::kNotInitialised;
  current_ = Frame();
  last_ = Frame();
  T_c_w_ = last_T_c_w_ = SE3::Identity();
  matches_.clear();
  last_matches_.clear();
  last_inliers_ = 0;
  inliers_.clear();
  velocity_.reset();
  reference_kf_ = KeyFrameId();
  local_keyframes_.clear();
  frames_since_keyframe_ = 0;
  init_candidates_.clear();
}

TrackResult Tracker::track(const cv::Mat& image, double timestamp, uint32_t frame_index,
                           const std::optional<Eigen::Vector3d>& gravity_c,
                           const std::optional<SE3>& T_o_c) {
  TrackResult result;
  const auto t0 = std::chrono::steady_clock::now();
  if (image.empty() || image.cols != camera_.width() || image.rows != camera_.height()) {
    result.state = state_;
    result.message = "image is empty or not " + std::to_string(camera_.width()) + "x" +
                     std::to_string(camera_.height());
    if (state_ == TrackingState::kOk) state_ = TrackingState::kLost;
    result.state = state_;
    return result;
  }
  cv::Mat gray;
  if (image.channels() == 3) {
    cv::cvtColor(image, gray, cv::COLOR_BGR2GRAY);
  } else {
    gray = image;
  }
  current_ = Frame();
  current_.frame_index = frame_index;
  current_.timestamp = timestamp;
  current_.gravity_c = gravity_c;
  current_.T_o_c = T_o_c;
  extractor_.detectAndCompute(gray, &current_.keypoints, &current_.descriptors);
  current_.finalize(camera_);
  result.orb_ms = msSince(t0);
  const auto t1 = std::chrono::steady_clock::now();
  matches_.assign(current_.size(), MapPointId());
  inliers_.assign(current_.size(), false);

  bool map_ready;
  {
    auto lock = map_->readLock();
    map_ready = map_->initialized();
  }
  if (current_.size() < 50) {
    result.message = "too few features (" + std::to_string(current_.size()) + ")";
    if (state_ == TrackingState::kOk) state_ = TrackingState::kLost;
  } else if (state_ == TrackingState::kOk) {
    const bool ok = trackFromLastFrame() >= config_.min_inliers;
    if (!ok) {
      state_ = TrackingState::kLost;
      result.message = "tracking lost";
    }
  } else if (map_ready) {
    // Lost, or a new device in an existing map: relocalise (join).
    if (relocalise() && trackLocalMap() >= config_.min_inliers) {
      state_ = TrackingState::kOk;
      result.relocalised = true;
      ++relocalisations_;
      velocity_.reset();
    } else {
      result.message = "relocalisation failed";
      if (state_ == TrackingState::kOk) state_ = TrackingState::kLost;
    }
  } else {
    if (initialise(&result)) {
      state_ = TrackingState::kOk;
      result.initialised = true;
    }
  }

  if (state_ == TrackingState::kOk) {
    if (!result.initialised) {
      velocity_ = T_c_w_ * last_T_c_w_.inverse();
      ++frames_since_keyframe_;
      if (needKeyFrame()) result.new_keyframe = createKeyFrame();
    }
    last_T_c_w_ = T_c_w_;
    last_inliers_ = static_cast<int>(std::count(inliers_.begin(), inliers_.end(), true));
    last_ = current_;
    last_matches_ = matches_;
    for (size_t i = 0; i < last_matches_.size(); ++i) {
      if (!inliers_[i]) last_matches_[i] = MapPointId();
    }
  } else {
    velocity_.reset();
  }
  result.state = state_;
  if (state_ == TrackingState::kOk) fillResult(&result);
  result.track_ms = msSince(t1);
  if (result.new_keyframe && config_.synchronous_mapping) mapper_->processPending();
  return result;
}

std::vector<PointSample> Tracker::samplesOf(const std::vector<MapPointId>& ids) const {
  std::vector<PointSample> out;
  out.reserve(ids.size());
  for (const auto& id : ids) {
    const MapPoint* p = map_->point(id);
    if (!p || p->descriptor.empty()) continue;
    PointSample s;
    s.id = id;
    s.p_w = p->p_w;
    s.normal = p->normal;
    s.min_distance = p->min_distance;
    s.max_distance = p->max_distance;
    std::copy(p->descriptor.ptr<uint8_t>(0), p->descriptor.ptr<uint8_t>(0) + 32,
              s.descriptor.begin());
    out.push_back(s);
  }
  return out;
}

int Tracker::optimiseCurrentPose() {
  std::vector<PoseObservation> obs;
  std::vector<int> index;
  {
    auto lock = map_->readLock();
    for (size_t i = 0; i < matches_.size(); ++i) {
      const MapPoint* p = map_->point(matches_[i]);
      if (!p) {
        matches_[i] = MapPointId();
        continue;
      }
      obs.push_back({p->p_w, current_.undistorted[i],
                     map_->scale().inv_sigma2[current_.keypoints[i].octave]});
      index.push_back(static_cast<int>(i));
    }
  }
  std::vector<bool> inl;
  SE3 T = T_c_w_;
  const auto r = optimizePose(K_, obs, &T, &inl, config_.pose);
  if (!isFinite(T)) return 0;
  T_c_w_ = T;
  inliers_.assign(current_.size(), false);
  int n = 0;
  for (size_t k = 0; k < index.size(); ++k) {
    if (inl[k]) {
      inliers_[index[k]] = true;
      ++n;
    } else {
      matches_[index[k]] = MapPointId();
    }
  }
  (void)r;
  return n;
}

int Tracker::trackFromLastFrame() {
  int inliers = 0;
  if (velocity_ && trackWithMotionModel()) inliers = trackLocalMap();
  // A wrong motion prediction (a shake reversing, a sudden turn) can still
  // give a pose with a few dozen inliers; when the result is much weaker than
  // the last frame's, the reference keyframe (matching by descriptor, no
  // prediction needed) gets its chance and the better pose wins.
  if (inliers >= config_.min_inliers && inliers >= config_.weak_tracking_ratio * last_inliers_) {
    return inliers;
  }
  const SE3 T_motion = T_c_w_;
  const std::vector<MapPointId> matches_motion = matches_;
  const std::vector<bool> inliers_motion = inliers_;
  const std::vector<KeyFrameId> local_motion = local_keyframes_;
  const KeyFrameId reference_motion = reference_kf_;
  int reference_inliers = 0;
  if (trackReferenceKeyFrame()) reference_inliers = trackLocalMap();
  if (reference_inliers > inliers) return reference_inliers;
  T_c_w_ = T_motion;
  matches_ = matches_motion;
  inliers_ = inliers_motion;
  local_keyframes_ = local_motion;
  reference_kf_ = reference_motion;
  return inliers;
}

bool Tracker::trackWithMotionModel() {
  T_c_w_ = (*velocity_) * last_T_c_w_;
  std::vector<PointSample> samples;
  {
    auto lock = map_->readLock();
    std::vector<MapPointId> ids;
    std::vector<int> octaves, rows;
    for (size_t i = 0; i < last_matches_.size(); ++i) {
      if (last_matches_[i].valid()) {
        ids.push_back(last_matches_[i]);
        octaves.push_back(last_.keypoints[i].octave);
        rows.push_back(static_cast<int>(i));
      }
    }
    samples = samplesOf(ids);
    const Eigen::Vector3d center = T_c_w_.inverse().translation();
    // Octave hints and descriptors from the last frame (samples keep the order
    // of ids): its view is the closest to the current one, also for points
    // another device mapped from the other side.
    size_t k = 0;
    for (size_t i = 0; i < ids.size() && k < samples.size(); ++i) {
      if (samples[k].id != ids[i]) continue;
      samples[k].octave_hint = octaves[i];
      // Only for points seen from well off their mean viewing direction (a
      // point mapped from the other side): elsewhere the representative
      // descriptor anchors the association, and the last frame's would let
      // it creep across scales from frame to frame (3% scale drift over the
      // corridor).
      const Eigen::Vector3d ray = (samples[k].p_w - center).normalized();
      if (ray.dot(samples[k].normal) < 0.5) {
        const uint8_t* d = last_.descriptors.ptr<uint8_t>(rows[i]);
        std::copy(d, d + 32, samples[k].descriptor.begin());
      }
      ++k;
    }
  }
  matches_.assign(current_.size(), MapPointId());
  int n = searchByProjection(current_, T_c_w_, K_, map_->scale(), samples,
                             config_.projection_radius, &matches_);
  if (n < 20) {
    matches_.assign(current_.size(), MapPointId());
    n = searchByProjection(current_, T_c_w_, K_, map_->scale(), samples,
                           2 * config_.projection_radius, &matches_);
  }
  if (n < 20) return false;
  return optimiseCurrentPose() >= 10;
}

bool Tracker::trackReferenceKeyFrame() {
  std::vector<PointSample> samples;
  {
    auto lock = map_->readLock();
    const KeyFrame* kf = map_->keyframe(reference_kf_);
    if (!kf) return false;
    std::vector<MapPointId> ids;
    std::vector<int> rows;
    for (size_t i = 0; i < kf->points.size(); ++i) {
      if (kf->points[i].valid()) {
        ids.push_back(kf->points[i]);
        rows.push_back(static_cast<int>(i));
      }
    }
    samples = samplesOf(ids);
    // The keyframe's own descriptors: its view is closer to the current one
    // than the representative descriptor (which may come from another side).
    size_t k = 0;
    for (size_t i = 0; i < ids.size() && k < samples.size(); ++i) {
      if (samples[k].id != ids[i]) continue;
      const uint8_t* d = kf->features.descriptors.ptr<uint8_t>(rows[i]);
      std::copy(d, d + 32, samples[k++].descriptor.begin());
    }
  }
  T_c_w_ = last_T_c_w_;
  matches_.assign(current_.size(), MapPointId());
  const int n = searchByDescriptor(current_, samples, 0.7, &matches_, nullptr);
  if (n < 15) return false;
  return optimiseCurrentPose() >= 10;
}

int Tracker::trackLocalMap() {
  // Local keyframes: those observing the current matches, plus their best neighbours.
  std::vector<PointSample> samples;
  {
    auto lock = map_->readLock();
    std::unordered_map<KeyFrameId, int> counter;
    for (const auto& id : matches_) {
      const MapPoint* p = map_->point(id);
      if (!p) continue;
      for (const auto& obs : p->observations) ++counter[obs.first];
    }
    std::vector<std::pair<int, KeyFrameId>> ranked;
    for (const auto& kv : counter) ranked.push_back({kv.second, kv.first});
    std::sort(ranked.begin(), ranked.end(), [](const auto& a, const auto& b) {
      return a.first != b.first ? a.first > b.first : a.second < b.second;
    });
    local_keyframes_.clear();
    std::unordered_set<KeyFrameId> in_local;
    for (const auto& r : ranked) {
      if (local_keyframes_.size() >= static_cast<size_t>(config_.local_keyframes) / 2) break;
      local_keyframes_.push_back(r.second);
      in_local.insert(r.second);
    }
    if (!local_keyframes_.empty()) reference_kf_ = local_keyframes_.front();
    const size_t direct = local_keyframes_.size();
    for (size_t k = 0; k < direct; ++k) {
      for (const auto& n : map_->bestCovisible(local_keyframes_[k], 10)) {
        if (local_keyframes_.size() >= static_cast<size_t>(config_.local_keyframes)) break;
        if (in_local.insert(n).second) local_keyframes_.push_back(n);
      }
    }
    std::unordered_set<MapPointId> already(matches_.begin(), matches_.end());
    std::vector<MapPointId> ids;
    for (const auto& kid : local_keyframes_) {
      const KeyFrame* kf = map_->keyframe(kid);
      if (!kf) continue;
      for (const auto& pid : kf->points) {
        if (pid.valid() && already.insert(pid).second) ids.push_back(pid);
      }
    }
    samples = samplesOf(ids);
  }
  searchByProjection(current_, T_c_w_, K_, map_->scale(), samples, config_.local_map_radius,
                     &matches_);
  const int inliers = optimiseCurrentPose();
  // Visibility statistics for point culling.
  {
    auto lock = map_->writeLock();
    for (size_t i = 0; i < matches_.size(); ++i) {
      if (!matches_[i].valid()) continue;
      if (MapPoint* p = map_->mutablePoint(matches_[i])) {
        ++p->visible;
        if (inliers_[i]) ++p->found;
      }
    }
  }
  return inliers;
}

bool Tracker::relocalise() { return relocaliseByPlace() || relocaliseByKeypoints(); }

bool Tracker::gravityConsistent() const {
  if (!hasGravity(current_)) return true;
  bool aligned = false;
  {
    auto lock = map_->readLock();
    const KeyFrame* kf = map_->keyframe(reference_kf_);
    aligned = kf && gravityAlignedAt(*kf, config_.gravity_tolerance_deg);
  }
  if (!aligned) return true;  // nothing to compare with
  const Eigen::Vector3d up = T_c_w_.linear() * Eigen::Vector3d::UnitZ();
  return up.dot(current_.gravity_c->normalized()) >
         std::cos(config_.gravity_tolerance_deg * M_PI / 180.0);
}

bool Tracker::verifyRelocalisation(std::vector<PointSample> samples) {
  if (optimiseCurrentPose() < 10) return false;
  for (auto& s : samples) s.normal.setZero();
  searchByProjection(current_, T_c_w_, K_, map_->scale(), samples, 10.0, &matches_);
  if (optimiseCurrentPose() < config_.min_inliers) return false;
  return gravityConsistent();
}

bool Tracker::relocaliseByPlace() {
  const auto candidates =
      index_->query(current_.descriptors, config_.relocalisation_candidates, 0.5);
  for (const auto& c : candidates) {
    std::vector<PointSample> samples;
    {
      auto lock = map_->readLock();
      if (!map_->keyframe(c.keyframe)) continue;
      samples = samplesOf(pointsSeenBy(*map_, std::array<KeyFrameId, 1>{c.keyframe}));
    }
    std::vector<MapPointId> m(current_.size());
    std::vector<int> which;
    const int nm = searchByDescriptor(current_, samples, config_.relocalisation_ratio, &m, &which);
    if (nm < 15) continue;
    std::vector<Eigen::Vector3d> pw;
    std::vector<Eigen::Vector2d> px;
    std::vector<int> kp_index;
    for (size_t i = 0; i < m.size(); ++i) {
      if (!m[i].valid()) continue;
      pw.push_back(samples[which[i]].p_w);
      px.push_back(current_.undistorted[i]);
      kp_index.push_back(static_cast<int>(i));
    }
    const Eigen::Matrix3d K = camera_.K();
    const PnpResult pnp = solvePnpRansac(pw, px, K, config_.pnp);
    if (!pnp.success) continue;
    matches_.assign(current_.size(), MapPointId());
    for (int k : pnp.inliers) matches_[kp_index[k]] = m[kp_index[k]];
    T_c_w_ = pnp.T_c_w;
    reference_kf_ = c.keyframe;
    if (verifyRelocalisation(std::move(samples))) return true;
  }
  return false;
}

bool Tracker::relocaliseByKeypoints() {
  if (!keypoints_) return false;
  // Nearest indexed keypoints of each keypoint; the nearest distinct map
  // point must pass a ratio test against the second.
  const auto hits = keypoints_->query(current_.descriptors, kDescriptorThresholdLow, 4);
  struct Putative {
    int row;
    MapPointId id;
    Eigen::Vector3d p_w;
    std::vector<KeyFrameId> observers;
  };
  std::vector<Putative> putative;
  std::unordered_map<KeyFrameId, int> votes;
  std::vector<std::pair<int, KeyFrameId>> ranked;  // (score, keyframe)
  {
    auto lock = map_->readLock();
    for (size_t i = 0; i < hits.size();) {
      size_t j = i;
      const MapPoint* best = nullptr;
      int best_d = 0, second_d = -1;
      for (; j < hits.size() && hits[j].query_row == hits[i].query_row; ++j) {
        const KeyFrame* kf = map_->keyframe(hits[j].keyframe);
        if (!kf || hits[j].row >= static_cast<int>(kf->points.size())) continue;
        const MapPoint* p = map_->point(kf->points[hits[j].row]);
        if (!p) continue;
        if (!best) {
          best = p;
          best_d = hits[j].distance;
        } else if (p != best && second_d < 0) {
          second_d = hits[j].distance;
        }
      }
      const int row = hits[i].query_row;
      i = j;
      if (!best || (second_d >= 0 && best_d > config_.keypoint_ratio * second_d)) continue;
      Putative pm{row, best->id, best->p_w, {}};
      for (const auto& obs : best->observations) {
        pm.observers.push_back(obs.first);
        ++votes[obs.first];
      }
      putative.push_back(std::move(pm));
    }
    if (static_cast<int>(putative.size()) < config_.pnp.min_inliers) return false;
    // A keyframe's score: its votes and those of its best neighbours.
    for (const auto& kv : votes) {
      int score = kv.second;
      for (const auto& n : map_->bestCovisible(kv.first, 10)) {
        const auto it = votes.find(n);
        if (it != votes.end()) score += it->second;
      }
      ranked.push_back({score, kv.first});
    }
  }
  std::sort(ranked.begin(), ranked.end(), [](const auto& a, const auto& b) {
    return a.first != b.first ? a.first > b.first : a.second < b.second;
  });
  // With gravity, all matches at once first: the correct ones of a view
  // from another direction are spread over several keyframe groups, too few
  // in any one of them.
  if (!ranked.empty() && hasGravity(current_)) {
    bool aligned = false;
    {
      auto lock = map_->readLock();
      const KeyFrame* kf = map_->keyframe(ranked.front().second);
      aligned = kf && gravityAlignedAt(*kf, config_.gravity_tolerance_deg);
    }
    if (aligned) {
      std::vector<Eigen::Vector3d> pw;
      std::vector<Eigen::Vector2d> px;
      std::vector<MapPointId> ids;
      std::vector<int> rows;
      for (const auto& pm : putative) {
        pw.push_back(pm.p_w);
        px.push_back(current_.undistorted[pm.row]);
        ids.push_back(pm.id);
        rows.push_back(pm.row);
      }
      if (relocaliseByGravity(pw, px, ids, rows, ranked.front().second)) return true;
    }
  }
  const Eigen::Matrix3d K = camera_.K();
  std::unordered_set<KeyFrameId> tried;
  int attempts = 0;
  for (const auto& r : ranked) {
    if (attempts >= config_.relocalisation_candidates) break;
    if (r.first < config_.pnp.min_inliers) break;
    if (tried.count(r.second)) continue;
    ++attempts;
    // The candidate's group: it and its best neighbours.
    std::unordered_set<KeyFrameId> group = {r.second};
    bool aligned = false;
    std::vector<PointSample> samples;
    {
      auto lock = map_->readLock();
      const KeyFrame* kf = map_->keyframe(r.second);
      if (!kf) continue;
      aligned = gravityAlignedAt(*kf, config_.gravity_tolerance_deg);
      for (const auto& n : map_->bestCovisible(r.second, config_.keypoint_group)) group.insert(n);
      samples = samplesOf(pointsSeenBy(*map_, group));
    }
    tried.insert(group.begin(), group.end());
    std::vector<Eigen::Vector3d> pw;
    std::vector<Eigen::Vector2d> px;
    std::vector<const Putative*> used;
    for (const auto& pm : putative) {
      for (const auto& o : pm.observers) {
        if (!group.count(o)) continue;
        pw.push_back(pm.p_w);
        px.push_back(current_.undistorted[pm.row]);
        used.push_back(&pm);
        break;
      }
    }
    if (static_cast<int>(pw.size()) < config_.pnp.min_inliers) continue;
    // With gravity in a gravity-aligned map only the yaw is unknown: a
    // 2-point RANSAC that copes with the few inliers of a view from another
    // direction.
    PnpConfig pnp_config = config_.pnp;
    pnp_config.ransac_iterations = std::max(pnp_config.ransac_iterations, 1000);
    const PnpResult pnp = aligned && hasGravity(current_)
                              ? solvePnpGravityRansac(pw, px, K, current_.gravity_c->normalized(),
                                                      pnp_config, current_.frame_index + 1)
                              : solvePnpRansac(pw, px, K, config_.pnp);
    if (!pnp.success) continue;
    matches_.assign(current_.size(), MapPointId());
    for (int k : pnp.inliers) matches_[used[k]->row] = used[k]->id;
    T_c_w_ = pnp.T_c_w;
    reference_kf_ = r.second;
    if (verifyRelocalisation(std::move(samples))) return true;
  }
  return false;
}

bool Tracker::relocaliseByGravity(const std::vector<Eigen::Vector3d>& points_w,
                                  const std::vector<Eigen::Vector2d>& pixels,
                                  const std::vector<MapPointId>& ids, const std::vector<int>& rows,
                                  KeyFrameId reference) {
  const Eigen::Matrix3d K = camera_.K();
  PnpConfig pnp_config = config_.pnp;
  pnp_config.ransac_iterations = std::max(pnp_config.ransac_iterations, 2000);
  pnp_config.min_inliers = config_.keypoint_gravity_min_inliers;
  const PnpResult pnp = solvePnpGravityRansac(points_w, pixels, K, current_.gravity_c->normalized(),
                                              pnp_config, current_.frame_index + 1);
  if (!pnp.success) return false;
  matches_.assign(current_.size(), MapPointId());
  std::vector<PointSample> samples;
  {
    auto lock = map_->readLock();
    std::unordered_set<KeyFrameId> observers;
    for (int k : pnp.inliers) {
      matches_[rows[k]] = ids[k];
      if (const MapPoint* p = map_->point(ids[k])) {
        for (const auto& obs : p->observations) observers.insert(obs.first);
      }
    }
    samples = samplesOf(pointsSeenBy(*map_, observers));
  }
  T_c_w_ = pnp.T_c_w;
  reference_kf_ = reference;
  return verifyRelocalisation(std::move(samples));
}

bool Tracker::needKeyFrame() const {
  if (!mapper_) return false;
  int tracked = 0;
  for (size_t i = 0; i < matches_.size(); ++i) tracked += inliers_[i] ? 1 : 0;
  int reference_points = 0;
  {
    auto lock = map_->readLock();
    if (const KeyFrame* kf = map_->keyframe(reference_kf_)) {
      for (const auto& id : kf->points) {
        const MapPoint* p = map_->point(id);
        if (p) ++reference_points;
      }
      if (kf->device != device_) return tracked > 15;  // another device's map: add our view
    }
  }
  const bool due = frames_since_keyframe_ >= static_cast<uint32_t>(config_.keyframe_max_gap);
  const bool weak = tracked < config_.keyframe_ratio * reference_points;
  return tracked > 15 && (weak || due) && (mapper_->idle() || due);
}

KeyFrameId Tracker::createKeyFrame() {
  KeyFrame kf;
  kf.device = device_;
  kf.frame_index = current_.frame_index;
  kf.timestamp = current_.timestamp;
  kf.T_c_w = T_c_w_;
  kf.features = current_;
  KeyFrameId id;
  {
    auto lock = map_->writeLock();
    id = map_->addKeyFrame(std::move(kf));
    for (size_t i = 0; i < matches_.size(); ++i) {
      if (matches_[i].valid() && inliers_[i] && map_->point(matches_[i])) {
        map_->addObservation(matches_[i], id, static_cast<int>(i));
      }
    }
    map_->updateCovisibility(id);
  }
  reference_kf_ = id;
  frames_since_keyframe_ = 0;
  mapper_->insert(id);
  return id;
}

void Tracker::fillResult(TrackResult* result) const {
  result->T_w_c = T_c_w_.inverse();
  result->local_keyframes = local_keyframes_;
  auto lock = map_->readLock();
  for (size_t i = 0; i < matches_.size(); ++i) {
    if (!matches_[i].valid() || !inliers_[i]) continue;
    const MapPoint* p = map_->point(matches_[i]);
    if (!p) continue;
    result->tracked.push_back({matches_[i], current_.keypoints[i], p->p_w});
  }
}

bool Tracker::initialise(TrackResult* result) {
  // Two-view initialisation against a pool of recent views: a hand-held
  // shake or a slow start reaches enough parallax only with the right earlier
  // view, not necessarily the first one. Each upload tries the candidates with
  // the largest median keypoint displacement first (a cheap proxy for the
  // baseline), at most init_attempts of them.
  const auto remember = [this] {
    if (static_cast<int>(current_.size()) < config_.init_min_matches) return;
    init_candidates_.push_back(current_);
    while (static_cast<int>(init_candidates_.size()) > std::max(1, config_.init_candidates)) {
      init_candidates_.pop_front();
    }
  };
  if (init_candidates_.empty()) {
    remember();
    result->message = "initialising: first view taken";
    return false;
  }
  struct Attempt {
    size_t candidate;
    double displacement;
    std::vector<int> m12;
  };
  std::vector<Attempt> attempts;
  int best_count = 0;
  bool still = false;
  for (size_t c = 0; c < init_candidates_.size(); ++c) {
    Attempt a{c, 0.0, {}};
    const Frame& first = init_candidates_[c];
    const int n = searchForInitialization(first, current_, config_.init_window, &a.m12);
    best_count = std::max(best_count, n);
    if (n < config_.init_min_matches) continue;
    std::vector<double> d;
    d.reserve(static_cast<size_t>(n));
    for (size_t i = 0; i < a.m12.size(); ++i) {
      if (a.m12[i] >= 0)
        d.push_back((current_.undistorted[a.m12[i]] - first.undistorted[i]).norm());
    }
    std::nth_element(d.begin(), d.begin() + d.size() / 2, d.end());
    a.displacement = d[d.size() / 2];
    // Parallax needs keypoints to move relative to each other; where even the
    // 90th percentile barely moved, the views are the same (a device at rest).
    std::nth_element(d.begin(), d.begin() + d.size() * 9 / 10, d.end());
    if (d[d.size() * 9 / 10] < config_.init_min_displacement_px) {
      still = true;
      continue;
    }
    attempts.push_back(std::move(a));
  }
  if (attempts.empty() && still) {
    result->message = "initialising: the camera has not moved";
    remember();
    return false;
  }
  if (attempts.empty()) {
    result->message = "initialising: " + std::to_string(best_count) + " matches";
    // The scene changed: older views no longer help.
    if (best_count < config_.init_min_matches / 2) init_candidates_.clear();
    remember();
    return false;
  }
  std::sort(attempts.begin(), attempts.end(),
            [](const Attempt& a, const Attempt& b) { return a.displacement > b.displacement; });
  if (static_cast<int>(attempts.size()) > config_.init_attempts) {
    attempts.resize(static_cast<size_t>(std::max(1, config_.init_attempts)));
  }
  const Eigen::Matrix3d K = camera_.K();
  std::optional<TwoViewResult> chosen;
  const Frame* first = nullptr;
  std::vector<std::pair<int, int>> pairs;
  for (const Attempt& a : attempts) {
    std::vector<Eigen::Vector2d> p1, p2;
    std::vector<std::pair<int, int>> candidate_pairs;
    const Frame& f1 = init_candidates_[a.candidate];
    for (size_t i = 0; i < a.m12.size(); ++i) {
      if (a.m12[i] < 0) continue;
      p1.push_back(f1.undistorted[i]);
      p2.push_back(current_.undistorted[a.m12[i]]);
      candidate_pairs.emplace_back(static_cast<int>(i), a.m12[i]);
    }
    TwoViewResult tv = reconstructTwoView(p1, p2, K, config_.two_view, current_.frame_index);
    if (!tv.success) {
      result->message = "initialising: " + tv.reason;
      continue;
    }
    chosen = std::move(tv);
    result->message.clear();
    first = &f1;
    pairs = std::move(candidate_pairs);
    break;
  }
  if (!chosen) {
    remember();
    return false;
  }
  const Frame& init_frame = *first;  // the pool is cleared only at the end
  const TwoViewResult& tv = *chosen;
  // Scale: metric from odometry when both views have it, else median depth 1.
  double scale = 1.0;
  if (init_frame.T_o_c && current_.T_o_c) {
    const double baseline =
        (current_.T_o_c->translation() - init_frame.T_o_c->translation()).norm();
    if (baseline > 1e-3) scale = baseline / tv.T_c2_c1.translation().norm();
  } else {
    std::vector<double> depths;
    for (size_t k = 0; k < tv.valid.size(); ++k) {
      if (tv.valid[k]) depths.push_back(tv.points_c1[k].z());
    }
    if (depths.empty()) return false;
    std::nth_element(depths.begin(), depths.begin() + depths.size() / 2, depths.end());
    scale = 1.0 / depths[depths.size() / 2];
  }
  const SE3 T_c1_w = initialWorldFrame(init_frame.gravity_c);
  SE3 T_c2_c1 = tv.T_c2_c1;
  T_c2_c1.translation() *= scale;
  const SE3 T_c2_w = T_c2_c1 * T_c1_w;

  auto lock = map_->writeLock();
  if (map_->initialized()) return false;  // another device was faster: relocalise next time
  KeyFrame kf1, kf2;
  kf1.device = kf2.device = device_;
  kf1.frame_index = init_frame.frame_index;
  kf1.timestamp = init_frame.timestamp;
  kf1.T_c_w = T_c1_w;
  kf1.features = init_frame;
  kf2.frame_index = current_.frame_index;
  kf2.timestamp = current_.timestamp;
  kf2.T_c_w = T_c2_w;
  kf2.features = current_;
  const KeyFrameId id1 = map_->addKeyFrame(std::move(kf1));
  const KeyFrameId id2 = map_->addKeyFrame(std::move(kf2));
  matches_.assign(current_.size(), MapPointId());
  inliers_.assign(current_.size(), false);
  const SE3 T_w_c1 = T_c1_w.inverse();
  for (size_t k = 0; k < pairs.size(); ++k) {
    if (!tv.valid[k]) continue;
    const MapPointId pid = map_->addPoint(T_w_c1 * (tv.points_c1[k] * scale), id1);
    map_->addObservation(pid, id1, pairs[k].first);
    map_->addObservation(pid, id2, pairs[k].second);
    map_->updatePointStatistics(pid);
    matches_[pairs[k].second] = pid;
    inliers_[pairs[k].second] = true;
  }
  map_->updateCovisibility(id1);
  map_->updateCovisibility(id2);
  std::vector<int> point_rows;
  if (const KeyFrame* k1 = map_->keyframe(id1)) {
    for (size_t i = 0; i < k1->points.size(); ++i) {
      if (k1->points[i].valid()) point_rows.push_back(static_cast<int>(i));
    }
  }
  lock.unlock();
  index_->add(id1, init_frame.descriptors);
  if (keypoints_) keypoints_->add(id1, init_frame.descriptors, point_rows);
  mapper_->insert(id2);  // refine the two-view map with BA and new points
  T_c_w_ = T_c2_w;
  reference_kf_ = id2;
  local_keyframes_ = {id1, id2};
  frames_since_keyframe_ = 0;
  init_candidates_.clear();
  result->new_keyframe = id2;
  return true;
}

}  // namespace ecar
