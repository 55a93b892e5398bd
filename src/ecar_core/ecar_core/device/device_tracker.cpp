#include "ecar_core/device/device_tracker.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <string>

#include "ecar_core/common/error.h"
#include "ecar_core/common/math.h"
#include "ecar_core/common/timing.h"

namespace ecar {
namespace {

/// Size of a received keypoint (ORB's patch diameter; the wire does not carry it).
constexpr float kKeypointSize = 31.0f;

/// `velocity` (per frame) applied `frames` times.
SE3 scaledMotion(const SE3& velocity, double frames) {
  if (frames == 1.0) return velocity;
  return expSE3(logSE3(velocity) * frames);
}

}  // namespace

void DeviceTrackerConfig::validate() const {
  auto fail = [](const std::string& key, const std::string& why) { throw Error(key + ": " + why); };
  if (orb.num_features < 1) fail("orb.num_features", "must be >= 1");
  if (orb.num_levels < 1 || orb.num_levels > 32) fail("orb.num_levels", "must be in [1, 32]");
  if (!std::isfinite(orb.scale_factor) || orb.scale_factor <= 1.0f) {
    fail("orb.scale_factor", "must be > 1");
  }
  if (orb.fast_threshold < 1 || orb.min_fast_threshold < 1) {
    fail("orb.fast_threshold", "thresholds must be >= 1");
  }
  if (pose.rounds < 1 || pose.iterations_per_round < 1) fail("pose.rounds", "must be >= 1");
  if (keyframe_queue < 1) fail("keyframe_queue", "must be >= 1");
  if (!finitePositive(projection_radius)) fail("projection_radius", "must be > 0 px");
  if (!finitePositive(keyframe_radius)) fail("keyframe_radius", "must be > 0 px");
  if (!finitePositive(refine_radius)) fail("refine_radius", "must be > 0 px");
  if (min_matches < 4) fail("min_matches", "must be >= 4");
  if (min_inliers < 4) fail("min_inliers", "must be >= 4");
}

// ---------------------------------------------------------------- tracker

DeviceTracker::DeviceTracker(const PinholeCamera& camera, const DeviceTrackerConfig& config)
    : camera_(camera),
      K_(intrinsicsOf(camera)),
      config_((config.validate(), config)),
      scale_(ScaleInfo::fromConfig(config.orb)),
      extractor_(config.orb),
      queue_(config.keyframe_queue) {}

size_t DeviceTracker::numKeyFrames() const {
  return queue_.empty() ? edgeslam_keyframes_ : queue_.size();
}

GraphUpdate DeviceTracker::addLocalGraph(const cv::Mat& image, const LocalGraph& graph) {
  const auto t0 = std::chrono::steady_clock::now();
  GraphUpdate update;
  DeviceKeyFrame kf;
  kf.frame_index = graph.frame_index;
  kf.T_w_c = graph.T_w_c;
  kf.point_ids.reserve(graph.points.size());
  kf.keypoints.reserve(graph.points.size());
  for (const GraphPoint& p : graph.points) {
    kf.point_ids.push_back(p.id);
    kf.keypoints.emplace_back(p.u, p.v, kKeypointSize, p.angle, 0.0f, p.octave);
  }
  if (image.cols == camera_.width() && image.rows == camera_.height()) {
    extractor_.computeAt(image, kf.keypoints, &kf.descriptors, &kf.valid);
  } else {
    kf.descriptors = cv::Mat::zeros(static_cast<int>(kf.keypoints.size()), 32, CV_8U);
    kf.valid.assign(kf.keypoints.size(), 0);
  }
  update.descriptors = static_cast<int>(std::count(kf.valid.begin(), kf.valid.end(), 1));
  edgeslam_keyframes_ = 0;
  update.queue = queue_.insert(std::move(kf), graph.positions);
  anchor_T_c_w_ = graph.T_w_c.inverse();
  has_anchor_ = true;
  rebuildSamples();
  update.points = static_cast<int>(samples_.size());
  update.ms = msSince(t0);
  return update;
}

GraphUpdate DeviceTracker::replaceLocalMap(const LocalGraph& graph) {
  const auto t0 = std::chrono::steady_clock::now();
  GraphUpdate update;
  queue_.clear();
  samples_.clear();
  for (const GraphMapPoint& m : graph.map_points) {
    PointSample p;
    p.id = m.id;
    p.p_w = m.p_w.cast<double>();
    p.normal = m.normal.cast<double>();
    p.min_distance = m.min_distance;
    p.max_distance = m.max_distance;
    p.descriptor = m.descriptor;
    if (!p.p_w.allFinite() || !p.normal.allFinite()) continue;
    samples_.push_back(p);
  }
  edgeslam_keyframes_ = graph.keyframes.size();
  anchor_T_c_w_ = graph.T_w_c.inverse();
  has_anchor_ = true;
  update.points = static_cast<int>(samples_.size());
  update.ms = msSince(t0);
  return update;
}

void DeviceTracker::clear() {
  queue_.clear();
  samples_.clear();
  edgeslam_keyframes_ = 0;
  has_anchor_ = false;
  has_velocity_ = false;
  state_ = TrackingState::kNotInitialised;
}

void DeviceTracker::rebuildSamples() {
  samples_.clear();
  sample_of_.clear();
  normal_count_.clear();
  const auto& keyframes = queue_.keyframes();
  const float max_scale = scale_.scale.back();
  // Newest first: the newest view of a point is the closest to the coming frames.
  for (auto kf = keyframes.rbegin(); kf != keyframes.rend(); ++kf) {
    const Eigen::Vector3d center = kf->T_w_c.translation();
    for (size_t i = 0; i < kf->point_ids.size(); ++i) {
      if (!kf->valid[i]) continue;
      const MapPointId id = kf->point_ids[i];
      const Eigen::Vector3d* p_w = queue_.position(id);
      if (!p_w) continue;
      const Eigen::Vector3d ray = *p_w - center;
      const double dist = ray.norm();
      if (!(dist > 1e-6)) continue;
      const auto it = sample_of_.find(id);
      if (it != sample_of_.end()) {
        samples_[it->second].normal += ray / dist;
        ++normal_count_[it->second];
        continue;
      }
      PointSample s;
      s.id = id;
      s.p_w = *p_w;
      s.normal = ray / dist;
      const int octave = std::clamp(kf->keypoints[i].octave, 0, scale_.levels() - 1);
      // ORB-SLAM's scale-invariance range from the view the point was seen in.
      s.max_distance = static_cast<float>(dist * scale_.scale[octave]);
      s.min_distance = s.max_distance / max_scale;
      const uint8_t* d = kf->descriptors.ptr<uint8_t>(static_cast<int>(i));
      std::copy(d, d + 32, s.descriptor.begin());
      sample_of_.emplace(id, static_cast<int>(samples_.size()));
      samples_.push_back(s);
      normal_count_.push_back(1);
    }
  }
  for (auto& s : samples_) s.normal.normalize();
}

int DeviceTracker::optimise() {
  observations_.clear();
  observation_rows_.clear();
  for (size_t i = 0; i < matches_.size(); ++i) {
    if (!matches_[i].valid()) continue;
    const int level = std::clamp(current_.keypoints[i].octave, 0, scale_.levels() - 1);
    observations_.push_back(
        {samples_[match_index_[i]].p_w, current_.undistorted[i], scale_.inv_sigma2[level]});
    observation_rows_.push_back(static_cast<int>(i));
  }
  if (static_cast<int>(observations_.size()) < config_.pose.min_inliers) return 0;
  inliers_.assign(observations_.size(), true);
  SE3 T = T_c_w_;
  optimizePose(K_, observations_, &T, &inliers_, config_.pose);
  if (!isFinite(T)) return 0;
  T_c_w_ = T;
  int n = 0;
  for (size_t k = 0; k < observation_rows_.size(); ++k) {
    if (inliers_[k]) {
      ++n;
    } else {
      matches_[observation_rows_[k]] = MapPointId();
      match_index_[observation_rows_[k]] = -1;
    }
  }
  return n;
}

bool DeviceTracker::trackFrom(const SE3& T_c_w, double radius) {
  T_c_w_ = T_c_w;
  matches_.assign(current_.size(), MapPointId());
  match_index_.assign(current_.size(), -1);
  const int first =
      searchByProjection(current_, T_c_w_, K_, scale_, samples_, radius, &matches_, &match_index_);
  if (first < config_.min_matches) return false;
  if (optimise() < config_.pose.min_inliers) return false;
  // With the pose refined, a narrow window finds the points the first
  // (wide) search missed or rejected as ambiguous.
  searchByProjection(current_, T_c_w_, K_, scale_, samples_, config_.refine_radius, &matches_,
                     &match_index_);
  result_.matches = static_cast<int>(std::count_if(
      matches_.begin(), matches_.end(), [](const MapPointId& id) { return id.valid(); }));
  result_.inliers = optimise();
  return result_.inliers >= config_.min_inliers;
}

const DeviceTrackResult& DeviceTracker::track(const cv::Mat& image, double timestamp,
                                              uint32_t frame_index) {
  const auto t0 = std::chrono::steady_clock::now();
  const double cpu0 = threadCpuMs();
  DeviceTrackResult& r = result_;
  r.frame_index = frame_index;
  r.matches = r.inliers = 0;
  r.from_keyframe = false;
  r.orb_ms = r.track_ms = 0.0;
  r.tracked_pixels.clear();
  r.message = "";
  const TrackingState failed = has_anchor_ ? TrackingState::kLost : TrackingState::kNotInitialised;
  if (image.empty() || image.cols != camera_.width() || image.rows != camera_.height()) {
    r.message = "image is empty or not the camera's size";
    if (state_ == TrackingState::kOk) state_ = failed;
    has_velocity_ = false;
    r.state = state_;
    r.total_ms = msSince(t0);
    r.cpu_ms = threadCpuMs() - cpu0;
    return r;
  }
  current_.frame_index = frame_index;
  current_.timestamp = timestamp;
  extractor_.detectAndCompute(image, &current_.keypoints, &current_.descriptors);
  current_.finalize(camera_);
  r.orb_ms = msSince(t0);
  const auto t1 = std::chrono::steady_clock::now();

  bool ok = false;
  const bool was_ok = state_ == TrackingState::kOk;
  double gap = 1.0;
  if (was_ok && frame_index > last_frame_index_ && frame_index - last_frame_index_ < 30) {
    gap = static_cast<double>(frame_index - last_frame_index_);
  }
  if (samples_.empty()) {
    r.message = has_anchor_ ? "no local map points" : "no local graph yet";
  } else {
    if (was_ok) {
      const SE3 predicted =
          has_velocity_ ? scaledMotion(velocity_, gap) * last_T_c_w_ : last_T_c_w_;
      ok = trackFrom(predicted, config_.projection_radius);
    }
    if (!ok && has_anchor_) {
      r.from_keyframe = true;
      ok = trackFrom(anchor_T_c_w_, config_.keyframe_radius);
    }
    if (!ok) r.message = "too few matches with the local map";
  }

  if (ok) {
    if (was_ok) {
      velocity_ = scaledMotion(T_c_w_ * last_T_c_w_.inverse(), 1.0 / gap);
      has_velocity_ = true;
    } else {
      has_velocity_ = false;
    }
    last_T_c_w_ = T_c_w_;
    last_frame_index_ = frame_index;
    state_ = TrackingState::kOk;
    r.T_w_c = T_c_w_.inverse();
    for (size_t i = 0; i < matches_.size(); ++i) {
      if (matches_[i].valid()) r.tracked_pixels.push_back(current_.keypoints[i].pt);
    }
  } else {
    state_ = failed;
    has_velocity_ = false;
    r.inliers = 0;
  }
  r.state = state_;
  r.track_ms = msSince(t1);
  r.total_ms = msSince(t0);
  r.cpu_ms = threadCpuMs() - cpu0;
  return r;
}

}  // namespace ecar
