// Monocular initialisation of an empty map by a Tracker: two-view
// reconstruction against a pool of recent views, the scale, and the world
// frame (gravity-aligned when gravity is known).
#include <algorithm>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "ecar_core/slam/local_mapper.h"
#include "ecar_core/slam/matcher.h"
#include "ecar_core/slam/tracker.h"
#include "ecar_core/slam/two_view.h"

namespace ecar {
namespace {

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

}  // namespace

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
  const Eigen::Matrix3d K = camera_->K();
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
    std::optional<TwoViewGravity> gravity;
    if (f1.gravity_c && current_.gravity_c && f1.gravity_c->norm() > 1.0 &&
        current_.gravity_c->norm() > 1.0) {
      gravity =
          TwoViewGravity{*f1.gravity_c, *current_.gravity_c, config_.init_gravity_tolerance_deg};
    }
    TwoViewResult tv =
        reconstructTwoView(p1, p2, K, config_.two_view, current_.frame_index, gravity);
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
  bool metric = false;
  if (init_frame.T_o_c && current_.T_o_c) {
    const double baseline =
        (current_.T_o_c->translation() - init_frame.T_o_c->translation()).norm();
    if (baseline > 1e-3) scale = baseline / tv.T_c2_c1.translation().norm();
    metric = baseline > 1e-3;
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
  kf1.camera = kf2.camera = camera_;
  kf1.frame_index = init_frame.frame_index;
  kf1.timestamp = init_frame.timestamp;
  kf1.T_c_w = T_c1_w;
  kf1.features = init_frame;
  kf2.frame_index = current_.frame_index;
  kf2.timestamp = current_.timestamp;
  kf2.T_c_w = T_c2_w;
  kf2.features = current_;
  map_->setMetric(metric);
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
  // The first answer comes from the adjusted two-view map: the devices that
  // receive it track on its points until their next graph, and the mapper's
  // first adjustment would move the raw reconstruction a moment later (the
  // newer keyframe by 1.1 mm in slam_test's corridor pair).
  mapper_->adjustNow(id2);
  SE3 T_c2_w_adjusted = T_c2_w;
  {
    auto read = map_->readLock();
    if (const KeyFrame* k2 = map_->keyframe(id2)) T_c2_w_adjusted = k2->T_c_w;
  }
  index_->add(id1, init_frame.descriptors);
  if (keypoints_) keypoints_->add(id1, init_frame.descriptors, point_rows);
  mapper_->insert(id2);  // new points and the next adjustments
  T_c_w_ = T_c2_w_adjusted;
  reference_kf_ = id2;
  local_keyframes_ = {id1, id2};
  frames_since_keyframe_ = 0;
  init_candidates_.clear();
  result->new_keyframe = id2;
  return true;
}

}  // namespace ecar
