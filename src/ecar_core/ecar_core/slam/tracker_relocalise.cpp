// Relocalisation of a Tracker (also how a new device joins an existing map):
// by place recognition, by keypoint matches (optionally a gravity RANSAC over
// all of them), and the checks of a relocalised pose.
#include <algorithm>
#include <array>
#include <cmath>
#include <unordered_map>
#include <unordered_set>
#include <utility>
#include <vector>

#include "ecar_core/slam/matcher.h"
#include "ecar_core/slam/pnp.h"
#include "ecar_core/slam/tracker.h"

namespace ecar {
namespace {

// Whether a keyframe's pose agrees with its own gravity within tol_deg: the
// map's z axis is up there (the map was initialised with gravity).
bool gravityAlignedAt(const KeyFrame& kf, double tol_deg) {
  return kf.alignedUp(tol_deg).has_value();
}

bool hasGravity(const Frame& f) {
  return f.gravity_c && f.gravity_c->allFinite() && f.gravity_c->norm() >= 1.0;
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
    const Eigen::Matrix3d K = camera_->K();
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
  const Eigen::Matrix3d K = camera_->K();
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
  const Eigen::Matrix3d K = camera_->K();
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

}  // namespace ecar
