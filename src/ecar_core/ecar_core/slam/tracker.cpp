// Tracking of one device's images against the shared map: track(), the
// motion model and reference keyframe, the local-map search and the keyframe
// decision. Initialisation is in tracker_initialise.cpp, relocalisation in
// tracker_relocalise.cpp.
#include <algorithm>
#include <chrono>
#include <string>
#include <unordered_map>
#include <unordered_set>
#include <utility>
#include <vector>

#include <opencv2/imgproc.hpp>

#include "ecar_core/common/error.h"
#include "ecar_core/common/timing.h"
#include "ecar_core/slam/local_mapper.h"
#include "ecar_core/slam/matcher.h"
#include "ecar_core/slam/tracker.h"

namespace ecar {
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
                 CameraPtr camera, const SlamConfig& config, KeypointIndex* keypoints)
    : device_(device),
      map_(map),
      index_(index),
      keypoints_(keypoints),
      mapper_(mapper),
      camera_((camera ? void() : throw Error("Tracker: no camera"), std::move(camera))),
      K_(camera_->intrinsics()),
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
  reference_kf_ = last_reference_kf_ = KeyFrameId();
  local_keyframes_.clear();
  frames_since_keyframe_ = 0;
  init_candidates_.clear();
}

TrackResult Tracker::track(const cv::Mat& image, double timestamp, uint32_t frame_index,
                           const std::optional<Eigen::Vector3d>& gravity_c,
                           const std::optional<SE3>& T_o_c, ImageFeatures* features) {
  TrackResult result;
  const auto t0 = std::chrono::steady_clock::now();
  if (image.empty() || image.cols != camera_->width() || image.rows != camera_->height()) {
    result.state = state_;
    result.message = "image is empty or not " + std::to_string(camera_->width()) + "x" +
                     std::to_string(camera_->height());
    if (state_ == TrackingState::kOk) state_ = TrackingState::kLost;
    result.state = state_;
    return result;
  }
  current_.clear();  // the frame before last's memory, reused
  current_.frame_index = frame_index;
  current_.timestamp = timestamp;
  current_.gravity_c = gravity_c;
  current_.T_o_c = T_o_c;
  if (features && features->extracted) {
    current_.keypoints.assign(features->keypoints.begin(), features->keypoints.end());
    current_.descriptors = features->descriptors;
  } else {
    cv::Mat gray;
    if (image.channels() == 3) {
      cv::cvtColor(image, gray, cv::COLOR_BGR2GRAY);
    } else {
      gray = image;
    }
    extractor_.detectAndCompute(gray, &current_.keypoints, &current_.descriptors);
    if (features) {
      features->keypoints.assign(current_.keypoints.begin(), current_.keypoints.end());
      features->descriptors = current_.descriptors;
      features->extracted = true;
    }
  }
  current_.finalize(*camera_);
  result.orb_ms = msSince(t0);
  const auto t1 = std::chrono::steady_clock::now();
  matches_.assign(current_.size(), MapPointId());
  inliers_.assign(current_.size(), false);

  bool map_ready;
  {
    auto lock = map_->readLock();
    map_ready = map_->initialized();
    // A loop correction moved the map since the last image: the last pose
    // moves with the reference keyframe, so the motion model predicts in the
    // corrected map.
    if (state_ == TrackingState::kOk && map_->revision() != seen_revision_) {
      if (const KeyFrame* ref = map_->keyframe(reference_kf_)) {
        last_T_c_w_ = last_T_c_w_ * reference_pose_.inverse() * ref->T_c_w;
      }
    }
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
    const bool was_lost = state_ == TrackingState::kLost;
    const int inliers = relocalise() ? trackLocalMap() : 0;
    if (inliers >= config_.min_inliers) {
      state_ = TrackingState::kOk;
      result.relocalised = true;
      ++relocalisations_;
      velocity_.reset();
      if (was_lost && inliers >= config_.loops.odometry_min_inliers) {
        result.odometry_loop = odometryLoop();
        if (result.odometry_loop) result.odometry_loop->inliers = inliers;
      }
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
    {
      auto lock = map_->readLock();
      seen_revision_ = map_->revision();
      const KeyFrame* ref = map_->keyframe(reference_kf_);
      reference_pose_ = ref ? ref->T_c_w : SE3::Identity();
    }
    last_reference_kf_ = reference_kf_;
    last_inliers_ = static_cast<int>(std::count(inliers_.begin(), inliers_.end(), true));
    last_matches_ = matches_;
    for (size_t i = 0; i < last_matches_.size(); ++i) {
      if (!inliers_[i]) last_matches_[i] = MapPointId();
    }
  } else {
    velocity_.reset();
  }
  result.state = state_;
  if (state_ == TrackingState::kOk) {
    fillResult(&result);
    std::swap(last_, current_);  // this frame becomes the last one, without a copy
  }
  result.track_ms = msSince(t1);
  if (result.new_keyframe && config_.synchronous_mapping) mapper_->processPending();
  return result;
}

std::optional<OdometryLoop> Tracker::odometryLoop() const {
  // last_ and last_T_c_w_ are still the last image tracked (current_ is the
  // relocalised one).
  const LoopClosingConfig& c = config_.loops;
  if (!c.enabled || !c.by_odometry || !last_.T_o_c || !current_.T_o_c) return std::nullopt;
  const double gap = current_.timestamp - last_.timestamp;
  if (!(gap > 0.0) || gap > c.odometry_max_gap) return std::nullopt;
  {
    auto lock = map_->readLock();
    if (!map_->metric() || !map_->keyframe(last_reference_kf_) || !map_->keyframe(reference_kf_) ||
        last_reference_kf_ == reference_kf_) {
      return std::nullopt;
    }
  }
  // The odometry's step from the last image to this one (camera_last <- camera_now),
  // in metres: a metric map's units.
  const SE3 T_last_now = last_.T_o_c->inverse() * *current_.T_o_c;
  const SE3 T_c_w_predicted = T_last_now.inverse() * last_T_c_w_;
  const double drift =
      (T_c_w_predicted.inverse().translation() - T_c_w_.inverse().translation()).norm();
  const double sigma = config_.odometrySigma(T_last_now.translation().norm());
  if (!(drift >= std::max(c.odometry_min_drift, 3.0 * sigma)) || drift > c.odometry_max_drift) {
    return std::nullopt;
  }
  OdometryLoop loop;
  loop.device = device_;
  loop.before = last_reference_kf_;
  loop.after = reference_kf_;
  // The last image's pose in the relocalised part of the map is T_last_now *
  // T_c_w_; the old part moves with it.
  loop.G = T_c_w_.inverse() * T_last_now.inverse() * last_T_c_w_;
  loop.drift_m = drift;
  loop.gap_s = gap;
  return loop;
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
  kf.camera = camera_;
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

}  // namespace ecar
