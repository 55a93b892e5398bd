// Robust similarity between two sets of matched 3D points: the transform that
// takes one part of a map onto another (a loop closure within a map, a merge
// of two maps). RANSAC over minimal sets of three pairs (Eigen::umeyama), then
// a least-squares refit on the inliers; SE(3) when the scale is known (both
// sides metric).
//
//   std::vector<PointPair> pairs = ...;   // source (current side) -> target (old side)
//   Sim3Estimate e = estimateSim3(pairs, config);
//   if (e.success) corrected = e.S * p_source;
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "ecar_core/common/geometry.h"

namespace ecar {

/// One correspondence: the same physical point in both frames.
struct PointPair {
  Eigen::Vector3d source;
  Eigen::Vector3d target;
  /// Largest distance (target frame units) at which S * source still counts
  /// as target: grows with the point's depth from the camera that saw it.
  double tolerance = 0.05;
};

struct Sim3EstimateConfig {
  int iterations = 300;
  int min_inliers = 20;
  bool fix_scale = false;  ///< SE(3): both sides share the metric scale
  uint32_t seed = 1;       ///< RANSAC samples are drawn from this seed (reproducible)
};

struct Sim3Estimate {
  bool success = false;
  Sim3 S;                     ///< maps source into target
  std::vector<bool> inliers;  ///< per pair
  int num_inliers = 0;
  std::string reason;  ///< why it failed, for logs
};

/// The similarity with the most inliers (|S * source - target| <= tolerance),
/// refitted on them. Fails (with a reason) with fewer than min_inliers, or
/// pairs that are not finite or have no positive tolerance (ignored).
Sim3Estimate estimateSim3(const std::vector<PointPair>& pairs,
                          const Sim3EstimateConfig& config = Sim3EstimateConfig());

/// Least-squares similarity (SE(3) with fix_scale) taking `source` onto
/// `target` (Eigen::umeyama). Needs at least 3 pairs not all on one line.
Sim3 fitSim3(const std::vector<Eigen::Vector3d>& source, const std::vector<Eigen::Vector3d>& target,
             bool fix_scale);

}  // namespace ecar
