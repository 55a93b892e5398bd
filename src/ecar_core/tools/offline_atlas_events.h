// ecar_slam_offline's measures of the atlas's events against the ground truth
// (issue 12's targets): how soon a device is tracked again after a gap (a
// blank view, a new place), and how soon two maps merge after a device first
// sees ground the other map holds. Included by that tool only.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <optional>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "ecar_core/eval/trajectory_eval.h"

#include "ecar_core/slam/atlas.h"
#include "ecar_core/slam/slam_system.h"
#include "offline_runs.h"

namespace offline {

/// One upload in the order the atlas tracked them.
struct Step {
  size_t device = 0;
  int upload = 0;
  bool tracked = false;
  ecar::MapId map;  ///< the map it was tracked in (invalid when not tracked)
};

/// A run of untracked uploads after a device was first tracked.
struct Gap {
  int lost_upload = 0;      ///< the first untracked upload
  int blank_uploads = 0;    ///< of them, blank images (nothing to track)
  int textured_upload = 0;  ///< the first upload after the blank ones
  int tracked_upload = -1;  ///< tracked again (-1: never)
  bool new_map = false;     ///< tracked again in a map it made then
  /// Uploads from the first textured one to tracked again (0: at once).
  int delay() const { return tracked_upload < 0 ? -1 : tracked_upload - textured_upload; }
};

/// An image with nothing to track: grey levels within a few of their mean.
inline bool blankImage(const cv::Mat& image) {
  if (image.empty()) return true;
  cv::Scalar mean, stddev;
  cv::meanStdDev(image, mean, stddev);
  return stddev[0] < 5.0;
}

/// The gaps of one device: `tracked`, `blank` and `initialised` per upload.
inline std::vector<Gap> trackingGaps(const std::vector<bool>& tracked,
                                     const std::vector<bool>& blank,
                                     const std::vector<bool>& initialised) {
  std::vector<Gap> gaps;
  bool seen = false;
  for (size_t u = 0; u < tracked.size(); ++u) {
    if (tracked[u]) {
      seen = true;
      continue;
    }
    if (!seen || (u > 0 && !tracked[u - 1])) continue;
    Gap g;
    g.lost_upload = static_cast<int>(u);
    size_t v = u;
    while (v < tracked.size() && !tracked[v] && blank[v]) ++v;
    g.blank_uploads = static_cast<int>(v - u);
    g.textured_upload = static_cast<int>(v);
    while (v < tracked.size() && !tracked[v]) ++v;
    if (v < tracked.size()) {
      g.tracked_upload = static_cast<int>(v);
      g.new_map = initialised[v];
    }
    gaps.push_back(g);
  }
  return gaps;
}

/// When a merge could first have been found: the first upload (of either
/// map's devices, tracked in one of the two maps) whose ground-truth view
/// holds at least kOverlapPoints points that keyframes of the other map had
/// observed by then from a similar view: within 20% of the distance and 30
/// degrees of the direction, closer than the range the SLAM maps at.
struct MergeOverlap {
  size_t merge = 0;  ///< index into Atlas::merges()
  int step = -1;     ///< into `steps`; -1 when none was found
  /// Uploads of the merging device after `step` up to the merge (negative:
  /// the merge came first, found from views farther apart than the measure's).
  int delay = 0;
};

/// `merge_steps[j]`: the step at which merge j happened; `S` takes the final
/// map (`slam`) onto the ground truth.
inline std::vector<MergeOverlap> mergeOverlaps(const ecar::SlamSystem& slam, const ecar::Sim3& S,
                                               const std::vector<DeviceRun>& runs,
                                               const std::vector<Step>& steps,
                                               const std::vector<ecar::MergeEvent>& merges,
                                               const std::vector<size_t>& merge_steps,
                                               uint32_t id_range) {
  std::vector<double> distances;
  const std::vector<ObservedPoint> points = observedPoints(slam, S, runs, id_range, &distances);
  const double range = ecar::percentile(distances, 0.9);
  const double min_cos = std::cos(30.0 * M_PI / 180.0);
  std::vector<MergeOverlap> out;
  for (size_t j = 0; j < merges.size() && j < merge_steps.size(); ++j) {
    // Where a map had gone just before merge j.
    const auto before = [&](ecar::MapId m) {
      for (size_t i = 0; i < j; ++i) {
        if (merges[i].from == m) m = merges[i].into;
      }
      return m;
    };
    MergeOverlap o;
    o.merge = j;
    for (size_t s = 0; s < steps.size() && o.step < 0; ++s) {
      const Step& e = steps[s];
      if (!e.tracked) continue;
      const ecar::MapId mine = before(e.map);
      if (mine != merges[j].into && mine != merges[j].from) continue;
      const ecar::MapId other = mine == merges[j].into ? merges[j].from : merges[j].into;
      const DeviceRun& r = runs[e.device];
      const auto& f = r.dataset.frame(r.uploads[e.upload]);
      if (!f.T_w_c_gt) continue;
      const double t = f.timestamp - r.dataset.frame(0).timestamp;
      const ecar::SE3 T_c_w = f.T_w_c_gt->inverse();
      const Eigen::Vector3d c = f.T_w_c_gt->translation();
      int shared = 0;
      for (const ObservedPoint& p : points) {
        const Eigen::Vector3d pc = T_c_w * p.p;
        if (pc.z() < 0.1) continue;
        const std::optional<Eigen::Vector2d> uv = r.dataset.camera().project(pc);
        if (!uv || !r.dataset.camera().inImage(*uv)) continue;
        const Eigen::Vector3d ray = p.p - c;
        const double dist = ray.norm();
        if (dist > range) continue;
        for (const ObservedPoint::View& v : p.views) {
          if (v.time > t || before(v.origin) != other) continue;
          const Eigen::Vector3d ray_v = p.p - v.centre;
          if (std::abs(ray_v.norm() / dist - 1.0) <= 0.2 &&
              ray_v.dot(ray) >= min_cos * ray_v.norm() * dist) {
            ++shared;
            break;
          }
        }
        if (shared >= kOverlapPoints) break;
      }
      if (shared >= kOverlapPoints) o.step = static_cast<int>(s);
    }
    if (o.step >= 0) {
      const size_t merging = steps[merge_steps[j]].device;
      const size_t a = std::min<size_t>(static_cast<size_t>(o.step), merge_steps[j]);
      const size_t b = std::max<size_t>(static_cast<size_t>(o.step), merge_steps[j]);
      for (size_t s = a + 1; s <= b; ++s) {
        if (steps[s].device == merging) ++o.delay;
      }
      if (static_cast<size_t>(o.step) > merge_steps[j]) o.delay = -o.delay;
    }
    out.push_back(o);
  }
  return out;
}

/// ATE of every device's estimates made after atlas step `from` (after the
/// last merge: the one map as the devices then see it), one transform for all
/// (a similarity when `similarity`). n is 0 when fewer than 3 estimates.
inline ecar::ErrorStats ateAfterStep(const std::vector<DeviceRun>& runs, size_t from,
                                     bool similarity) {
  std::vector<Eigen::Vector3d> est, gt;
  for (const DeviceRun& r : runs) {
    for (size_t i = 0; i < r.estimate.size(); ++i) {
      if (r.estimate_step[i] <= from) continue;
      est.push_back(r.estimate[i].T_w_c.translation());
      gt.push_back(r.truth[i].T_w_c.translation());
    }
  }
  if (est.size() < 3) return ecar::ErrorStats();
  const ecar::Sim3 T = ecar::umeyama(est, gt, similarity);
  std::vector<double> e;
  for (size_t i = 0; i < est.size(); ++i) e.push_back((T * est[i] - gt[i]).norm());
  return ecar::computeStats(e);
}

}  // namespace offline
