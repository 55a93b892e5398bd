// ecar_slam_offline's measures of the atlas's events against the ground truth
// (issue 12's targets): how soon a device is tracked again after a gap (a
// blank view, a new place), and how soon two maps merge after a device first
// sees ground the other map holds. Included by that tool only.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <optional>
#include <utility>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>
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
  ecar::MapId map;       ///< the map it was tracked in (invalid when not tracked)
  double call_ms = 0.0;  ///< the whole Atlas::track call (a merge's pause included)
};

/// Atlas::track call times of the `n` uploads after `step` (while what the
/// event queued, such as a global BA, runs beside them with --threads): median
/// and p95, and the call at `step` itself.
struct CallTimes {
  double at_ms = 0.0, median_ms = 0.0, p95_ms = 0.0;
};
inline CallTimes callTimesAfter(const std::vector<Step>& steps, size_t step, size_t n) {
  CallTimes t;
  if (step >= steps.size()) return t;
  t.at_ms = steps[step].call_ms;
  std::vector<double> after;
  for (size_t s = step + 1; s < steps.size() && s <= step + n; ++s)
    after.push_back(steps[s].call_ms);
  t.median_ms = ecar::percentile(after, 0.5);
  t.p95_ms = ecar::percentile(after, 0.95);
  return t;
}

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

/// Everything the tool records of the atlas while it runs.
struct AtlasLog {
  std::vector<Step> steps;
  std::vector<std::pair<size_t, int>> merge_found_by, loop_found_by;  ///< device, upload
  std::vector<size_t> merge_steps, loop_steps;
};

/// Prints the merges (with their first overlap, measured in `slam` aligned by
/// S when it is given, and the track() times around them), the ATE after the
/// last merge and the loops closed, and puts them into the summary: `maps`,
/// `merges`, `ate_after_merges(_sim3)`, `loop_closures`.
inline void reportAtlasEvents(const ecar::Atlas& atlas, const ecar::SlamSystem* slam,
                              const ecar::Sim3& S, const std::vector<DeviceRun>& runs,
                              const AtlasLog& log, bool metric, uint32_t id_range,
                              nlohmann::json* summary) {
  const std::vector<Step>& steps = log.steps;
  const auto& merge_found_by = log.merge_found_by;
  const auto& loop_found_by = log.loop_found_by;
  const std::vector<size_t>& merge_steps = log.merge_steps;
  const std::vector<size_t>& loop_steps = log.loop_steps;
  (*summary)["maps"] = atlas.mapIds().size();
  (*summary)["merges"] = nlohmann::json::array();
  const std::vector<ecar::MergeEvent> merges = atlas.merges();
  const std::vector<MergeOverlap> overlaps =
      slam ? mergeOverlaps(*slam, S, runs, steps, merges, merge_steps, id_range)
           : std::vector<MergeOverlap>();
  for (size_t k = 0; k < merges.size(); ++k) {
    const ecar::MergeEvent& m = merges[k];
    const size_t d = k < merge_found_by.size() ? merge_found_by[k].first : m.device.value - 1;
    const int upload = k < merge_found_by.size() ? merge_found_by[k].second : -1;
    std::printf(
        "maps merged: %s upload %d (keyframe %u) found map %u in map %u (keyframe %u), %d "
        "inliers, scale %.4f; %zu keyframes moved, %zu points fused, seam refit %s (%d of %d "
        "reprojections, %.2f -> %.2f px, %.2f deg, scale %.4f), %.1f ms\n",
        d < runs.size() ? runs[d].name.c_str() : "?", upload, m.query.value, m.from.value,
        m.into.value, m.match.value, m.inliers, m.scale, m.keyframes_moved, m.points_fused,
        m.refit.applied ? "applied" : "not applied", m.refit.inliers, m.refit.observations,
        m.refit.rms_before_px, m.refit.rms_after_px,
        ecar::rotationAngle(m.refit.D.R) * 180.0 / M_PI, m.refit.D.scale, m.ms);
    nlohmann::json entry = {{"upload", upload},
                            {"device", d < runs.size() ? runs[d].name : "?"},
                            {"inliers", m.inliers},
                            {"ms", m.ms},
                            {"into", m.into.value},
                            {"from", m.from.value},
                            {"scale", m.scale},
                            {"overlap_device", nullptr},
                            {"refit",
                             {{"applied", m.refit.applied},
                              {"inliers", m.refit.inliers},
                              {"observations", m.refit.observations},
                              {"rms_before_px", m.refit.rms_before_px},
                              {"rms_after_px", m.refit.rms_after_px},
                              {"rotation_deg", ecar::rotationAngle(m.refit.D.R) * 180.0 / M_PI}}},
                            {"overlap_upload", -1},
                            {"delay_uploads", -1}};
    if (k < overlaps.size() && overlaps[k].step >= 0) {
      const Step& o = steps[static_cast<size_t>(overlaps[k].step)];
      entry["overlap_device"] = runs[o.device].name;
      entry["overlap_upload"] = o.upload;
      entry["delay_uploads"] = overlaps[k].delay;
      std::printf(
          "  first overlap (30 deg, 20%% of the distance): %s upload %d; merged %d "
          "uploads of %s %s\n",
          runs[o.device].name.c_str(), o.upload, std::abs(overlaps[k].delay),
          d < runs.size() ? runs[d].name.c_str() : "?",
          overlaps[k].delay < 0 ? "before it" : "later");
    } else if (k < overlaps.size()) {
      std::printf("  first overlap: none measured\n");
    }
    if (k < merge_steps.size()) {
      const CallTimes t = callTimesAfter(steps, merge_steps[k], 20);
      std::printf("  track() calls: the merging one %.1f ms; the next 20 median %.1f p95 %.1f ms\n",
                  t.at_ms, t.median_ms, t.p95_ms);
      entry["call_ms"] = t.at_ms;
      entry["next_calls_median_ms"] = t.median_ms;
      entry["next_calls_p95_ms"] = t.p95_ms;
    }
    (*summary)["merges"].push_back(entry);
  }
  if (!merge_steps.empty()) {
    const ecar::ErrorStats after = ateAfterStep(runs, merge_steps.back(), !metric);
    const ecar::ErrorStats after_sim3 = ateAfterStep(runs, merge_steps.back(), true);
    std::printf(
        "ATE after the last merge (one transform, %zu uploads): %s rmse %.4f m, Sim(3) rmse "
        "%.4f m\n",
        after.n, metric ? "SE(3)" : "Sim(3)", after.rmse, after_sim3.rmse);
    (*summary)["ate_after_merges"] = ecar::toJson(after);
    (*summary)["ate_after_merges_sim3"] = ecar::toJson(after_sim3);
  }
  std::printf("maps at the end: %zu\n", atlas.mapIds().size());
  (*summary)["loop_closures"] = nlohmann::json::array();
  const std::vector<ecar::LoopClosure> loops = atlas.loopClosures();
  for (size_t k = 0; k < loops.size(); ++k) {
    const ecar::LoopClosure& l = loops[k];
    const size_t d = k < loop_found_by.size() ? loop_found_by[k].first : l.device.value - 1;
    const int upload = k < loop_found_by.size() ? loop_found_by[k].second : -1;
    char odometry[160] = "";
    if (l.by_odometry) {
      std::snprintf(odometry, sizeof(odometry),
                    " (odometry across a tracking gap: off by %.3f m, %d covisibility links apart)",
                    l.odometry_disagreement_m, l.links);
    }
    std::printf(
        "loop closed%s: %s upload %d (keyframe %u) with keyframe %u, %d inliers, similarity scale "
        "%.4f, the keyframe moved %.3f m; detect %.1f ms, correct %.1f ms (%zu keyframes, %zu "
        "points moved, %zu fused), global BA %.1f ms\n",
        odometry, d < runs.size() ? runs[d].name.c_str() : "?", upload, l.query.value,
        l.match.value, l.inliers, l.scale, l.drift_m, l.detect_ms, l.correct_ms, l.keyframes_moved,
        l.points_moved, l.points_fused, l.global_ba_ms);
    (*summary)["loop_closures"].push_back({{"upload", upload},
                                           {"device", d < runs.size() ? runs[d].name : "?"},
                                           {"keyframe", l.query.value},
                                           {"match", l.match.value},
                                           {"inliers", l.inliers},
                                           {"scale", l.scale},
                                           {"moved_m", l.drift_m},
                                           {"by_odometry", l.by_odometry},
                                           {"links", l.links},
                                           {"ms", l.detect_ms + l.correct_ms},
                                           {"detect_ms", l.detect_ms},
                                           {"correct_ms", l.correct_ms},
                                           {"global_ba_ms", l.global_ba_ms},
                                           {"by_odometry", l.by_odometry}});
    if (k < loop_steps.size()) {
      const CallTimes t = callTimesAfter(steps, loop_steps[k], 20);
      std::printf("  track() calls: the closing one %.1f ms; the next 20 median %.1f p95 %.1f ms\n",
                  t.at_ms, t.median_ms, t.p95_ms);
    }
  }
}

}  // namespace offline
