#include "ecar_core/slam/matcher.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "ecar_core/slam/descriptor_block.h"
#include "ecar_core/slam/features.h"

namespace ecar {
namespace {

constexpr int kHistogramBins = 30;

float angleDelta(float a, float b) {
  float d = a - b;
  if (d < 0) d += 360.0f;
  return d;
}

// Where a point projects, and at which pyramid level it is expected.
struct Projection {
  bool ok = false;
  Eigen::Vector2d uv;
  int level = 0;
  double dist = 0.0;
};

Projection project(const PointSample& p, const SE3& T_c_w, const Eigen::Vector3d& center,
                   const Intrinsics& K, const ScaleInfo& scale, const Frame& frame) {
  Projection r;
  const Eigen::Vector3d pc = T_c_w * p.p_w;
  if (pc.z() <= 1e-3) return r;
  r.uv = {K.fx * pc.x() / pc.z() + K.cx, K.fy * pc.y() / pc.z() + K.cy};
  if (r.uv.x() < frame.min_u || r.uv.y() < frame.min_v || r.uv.x() >= frame.max_u ||
      r.uv.y() >= frame.max_v) {
    return r;
  }
  const Eigen::Vector3d po = p.p_w - center;
  r.dist = po.norm();
  if (p.max_distance > 0) {
    if (r.dist < 0.8 * p.min_distance || r.dist > 1.2 * p.max_distance) return r;
    r.level = std::clamp(
        static_cast<int>(std::ceil(std::log(p.max_distance / r.dist) / scale.log_scale_factor)), 0,
        scale.levels() - 1);
  } else {
    r.level = p.octave_hint >= 0 ? p.octave_hint : 0;
  }
  // Viewing direction within 60 degrees of the mean one.
  if (p.normal.squaredNorm() > 0 && po.dot(p.normal) < 0.5 * r.dist) return r;
  r.ok = true;
  return r;
}

}  // namespace

std::vector<bool> orientationConsistent(const std::vector<float>& delta_deg) {
  std::vector<int> hist[kHistogramBins];
  for (size_t i = 0; i < delta_deg.size(); ++i) {
    if (delta_deg[i] < 0) continue;
    int bin = static_cast<int>(std::lround(delta_deg[i] * kHistogramBins / 360.0f));
    if (bin == kHistogramBins) bin = 0;
    hist[bin].push_back(static_cast<int>(i));
  }
  int best[3] = {-1, -1, -1};
  for (int b = 0; b < kHistogramBins; ++b) {
    const size_t n = hist[b].size();
    if (best[0] < 0 || n > hist[best[0]].size()) {
      best[2] = best[1];
      best[1] = best[0];
      best[0] = b;
    } else if (best[1] < 0 || n > hist[best[1]].size()) {
      best[2] = best[1];
      best[1] = b;
    } else if (best[2] < 0 || n > hist[best[2]].size()) {
      best[2] = b;
    }
  }
  std::vector<bool> keep(delta_deg.size(), false);
  const size_t top = best[0] >= 0 ? hist[best[0]].size() : 0;
  for (int k = 0; k < 3; ++k) {
    if (best[k] < 0) continue;
    // Secondary bins only when they are not much weaker than the best (ORB-SLAM: 10%).
    if (k > 0 && hist[best[k]].size() < 0.1 * top) continue;
    for (int i : hist[best[k]]) keep[i] = true;
  }
  return keep;
}

int searchByProjection(const Frame& frame, const SE3& T_c_w, const Intrinsics& K,
                       const ScaleInfo& scale, const std::vector<PointSample>& points,
                       double radius, std::vector<MapPointId>* matches,
                       std::vector<int>* match_point_index) {
  if (matches->size() != frame.size()) matches->assign(frame.size(), MapPointId());
  if (match_point_index && match_point_index->size() != frame.size()) {
    match_point_index->assign(frame.size(), -1);
  }
  const Eigen::Vector3d center = T_c_w.inverse().translation();
  std::vector<int> candidates;
  std::vector<int> best_dist(frame.size(), std::numeric_limits<int>::max());
  std::vector<int> owner(frame.size(), -1);
  // A point already matched in this frame keeps its keypoint (a sorted list:
  // no hash nodes allocated per frame).
  std::vector<MapPointId> taken;
  for (const auto& id : *matches) {
    if (id.valid()) taken.push_back(id);
  }
  std::sort(taken.begin(), taken.end());
  for (size_t pi = 0; pi < points.size(); ++pi) {
    const PointSample& p = points[pi];
    if (!taken.empty() && std::binary_search(taken.begin(), taken.end(), p.id)) continue;
    const Projection pr = project(p, T_c_w, center, K, scale, frame);
    if (!pr.ok) continue;
    const int min_level = p.octave_hint >= 0 ? std::max(0, p.octave_hint - 1) : pr.level - 1;
    const int max_level = p.octave_hint >= 0 ? p.octave_hint + 1 : pr.level + 1;
    const double r = radius * scale.scale[std::clamp(pr.level, 0, scale.levels() - 1)];
    frame.grid.query(pr.uv.x(), pr.uv.y(), r, std::max(0, min_level), max_level, &candidates);
    int best = std::numeric_limits<int>::max(), second = best, best_idx = -1;
    int best_level = -1, second_level = -1;
    for (int idx : candidates) {
      if ((*matches)[idx].valid()) continue;
      const int d = descriptorDistance(p.descriptor.data(), frame.descriptors.ptr<uint8_t>(idx));
      if (d < best) {
        second = best;
        second_level = best_level;
        best = d;
        best_idx = idx;
        best_level = frame.keypoints[idx].octave;
      } else if (d < second) {
        second = d;
        second_level = frame.keypoints[idx].octave;
      }
    }
    if (best_idx < 0 || best > kDescriptorThresholdHigh) continue;
    // Ratio test between candidates at the same level.
    if (best_level == second_level && best > 0.8 * second) continue;
    if (best < best_dist[best_idx]) {
      best_dist[best_idx] = best;
      owner[best_idx] = static_cast<int>(pi);
    }
  }
  int count = 0;
  for (size_t i = 0; i < frame.size(); ++i) {
    if (owner[i] < 0) continue;
    ++count;
    (*matches)[i] = points[owner[i]].id;
    if (match_point_index) (*match_point_index)[i] = owner[i];
  }
  return count;
}

int searchForInitialization(const Frame& f1, const Frame& f2, double window,
                            std::vector<int>* matches12) {
  matches12->assign(f1.size(), -1);
  std::vector<int> dist21(f2.size(), std::numeric_limits<int>::max());
  std::vector<int> match21(f2.size(), -1);
  std::vector<int> candidates;
  for (size_t i1 = 0; i1 < f1.size(); ++i1) {
    // Fine levels only (coarse keypoints localise poorly), at a similar scale.
    const int level = f1.keypoints[i1].octave;
    if (level > 3) continue;
    f2.grid.query(f1.undistorted[i1].x(), f1.undistorted[i1].y(), window, std::max(0, level - 1),
                  level + 1, &candidates);
    int best = std::numeric_limits<int>::max(), second = best, best_idx = -1;
    for (int i2 : candidates) {
      const int d = descriptorDistance(f1.descriptors, static_cast<int>(i1), f2.descriptors, i2);
      if (d > dist21[i2]) continue;
      if (d < best) {
        second = best;
        best = d;
        best_idx = i2;
      } else if (d < second) {
        second = d;
      }
    }
    if (best_idx < 0 || best > kDescriptorThresholdLow || best > 0.9 * second) continue;
    if (match21[best_idx] >= 0) (*matches12)[match21[best_idx]] = -1;
    (*matches12)[i1] = best_idx;
    match21[best_idx] = static_cast<int>(i1);
    dist21[best_idx] = best;
  }
  std::vector<float> delta(f1.size(), -1.0f);
  for (size_t i1 = 0; i1 < f1.size(); ++i1) {
    if ((*matches12)[i1] >= 0) {
      delta[i1] = angleDelta(f1.keypoints[i1].angle, f2.keypoints[(*matches12)[i1]].angle);
    }
  }
  const auto keep = orientationConsistent(delta);
  int count = 0;
  for (size_t i1 = 0; i1 < f1.size(); ++i1) {
    if ((*matches12)[i1] < 0) continue;
    if (!keep[i1]) {
      (*matches12)[i1] = -1;
    } else {
      ++count;
    }
  }
  return count;
}

int searchByDescriptor(const Frame& frame, const std::vector<PointSample>& points, double ratio,
                       std::vector<MapPointId>* matches, std::vector<int>* match_point_index) {
  if (matches->size() != frame.size()) matches->assign(frame.size(), MapPointId());
  if (match_point_index && match_point_index->size() != frame.size()) {
    match_point_index->assign(frame.size(), -1);
  }
  // The free keypoints, laid out for the one-against-many search.
  std::vector<int> free_rows;
  free_rows.reserve(frame.size());
  DescriptorBlock block;
  block.reserve(frame.size());
  for (size_t i = 0; i < frame.size(); ++i) {
    if ((*matches)[i].valid()) continue;
    free_rows.push_back(static_cast<int>(i));
    block.push_back(frame.descriptors.ptr<uint8_t>(static_cast<int>(i)));
  }
  std::vector<int> best_dist(frame.size(), std::numeric_limits<int>::max());
  std::vector<int> owner(frame.size(), -1);
  for (size_t pi = 0; pi < points.size(); ++pi) {
    const DescriptorBlock::Nearest n = block.nearest(points[pi].descriptor.data());
    if (n.index < 0 || n.distance > kDescriptorThresholdLow || n.distance > ratio * n.second) {
      continue;
    }
    const int best = n.distance, best_idx = free_rows[n.index];
    if (best < best_dist[best_idx]) {
      best_dist[best_idx] = best;
      owner[best_idx] = static_cast<int>(pi);
    }
  }
  int count = 0;
  for (size_t i = 0; i < frame.size(); ++i) {
    if (owner[i] < 0) continue;
    (*matches)[i] = points[owner[i]].id;
    if (match_point_index) (*match_point_index)[i] = owner[i];
    ++count;
  }
  return count;
}

std::vector<std::pair<int, int>> searchForTriangulation(const Frame& f1, const SE3& T1_c_w,
                                                        const std::vector<bool>& used1,
                                                        const Frame& f2, const SE3& T2_c_w,
                                                        const std::vector<bool>& used2,
                                                        const Intrinsics& K1, const Intrinsics& K2,
                                                        const ScaleInfo& scale) {
  // Fundamental matrix F21 (x2^T F21 x1 = 0 in undistorted pixels), each view
  // with its own camera.
  const SE3 T21 = T2_c_w * T1_c_w.inverse();
  const auto inverseK = [](const Intrinsics& K) {
    Eigen::Matrix3d Kinv;
    Kinv << 1.0 / K.fx, 0, -K.cx / K.fx, 0, 1.0 / K.fy, -K.cy / K.fy, 0, 0, 1;
    return Kinv;
  };
  const Eigen::Matrix3d F21 =
      inverseK(K2).transpose() * skew(T21.translation()) * T21.linear() * inverseK(K1);
  // Epipole of camera 1 in image 2: keypoints too close to it give no depth.
  const Eigen::Vector3d c1_in_2 = T21.translation();
  Eigen::Vector2d epipole(-1e9, -1e9);
  if (c1_in_2.z() > 1e-6) {
    epipole = {K2.fx * c1_in_2.x() / c1_in_2.z() + K2.cx,
               K2.fy * c1_in_2.y() / c1_in_2.z() + K2.cy};
  }
  std::vector<int> free2;
  for (size_t i = 0; i < f2.size(); ++i) {
    if (!used2[i]) free2.push_back(static_cast<int>(i));
  }
  std::vector<int> match21(f2.size(), -1), dist21(f2.size(), std::numeric_limits<int>::max());
  std::vector<int> match12(f1.size(), -1);
  for (size_t i1 = 0; i1 < f1.size(); ++i1) {
    if (used1[i1]) continue;
    const Eigen::Vector3d x1(f1.undistorted[i1].x(), f1.undistorted[i1].y(), 1.0);
    const Eigen::Vector3d line = F21 * x1;  // a u + b v + c = 0 in image 2
    const double norm2 = line.head<2>().squaredNorm();
    if (norm2 < 1e-12) continue;
    int best = kDescriptorThresholdLow + 1, best_idx = -1;
    for (int i2 : free2) {
      const int d = descriptorDistance(f1.descriptors, static_cast<int>(i1), f2.descriptors, i2);
      if (d >= best) continue;
      const Eigen::Vector2d& x2 = f2.undistorted[i2];
      if ((x2 - epipole).squaredNorm() < 100.0 * scale.scale[f2.keypoints[i2].octave]) continue;
      const double num = line.x() * x2.x() + line.y() * x2.y() + line.z();
      const double dist2 = num * num / norm2;
      if (dist2 > 3.84 * scale.sigma2[f2.keypoints[i2].octave]) continue;
      best = d;
      best_idx = i2;
    }
    if (best_idx < 0 || best >= dist21[best_idx]) continue;
    if (match21[best_idx] >= 0) match12[match21[best_idx]] = -1;
    match21[best_idx] = static_cast<int>(i1);
    dist21[best_idx] = best;
    match12[i1] = best_idx;
  }
  std::vector<float> delta(f1.size(), -1.0f);
  for (size_t i1 = 0; i1 < f1.size(); ++i1) {
    if (match12[i1] >= 0) {
      delta[i1] = angleDelta(f1.keypoints[i1].angle, f2.keypoints[match12[i1]].angle);
    }
  }
  const auto keep = orientationConsistent(delta);
  std::vector<std::pair<int, int>> out;
  for (size_t i1 = 0; i1 < f1.size(); ++i1) {
    if (match12[i1] >= 0 && keep[i1]) out.emplace_back(static_cast<int>(i1), match12[i1]);
  }
  return out;
}

}  // namespace ecar
