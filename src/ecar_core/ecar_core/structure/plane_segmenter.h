// Plane segmentation of one keyframe's map points (the paper's plane
// detection): sequential RANSAC, least-squares refinement, a connectivity
// filter, and labels from gravity (plane.h for the conventions).
//
//   PlaneSegmenter segmenter(config);
//   std::vector<PlaneObservation> found = segmenter.segment(input);  // no lock needed
#pragma once

#include <vector>

#include <Eigen/Core>

#include "ecar_core/structure/plane.h"

namespace ecar {

/// A plane found in one keyframe's points, before it is merged into the map.
struct PlaneObservation {
  PlaneLabel label = PlaneLabel::kOther;
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();  ///< unit, towards the camera
  double offset = 0.0;                                ///< m
  std::vector<PlanePoint> inliers;
  std::vector<Eigen::Vector3d> boundary;  ///< convex hull of the inliers, as in Plane
  double rms = 0.0;                       ///< RMS point-plane distance of the inliers, m
};

/// Sequential RANSAC on one keyframe's points. Stateless after construction:
/// segment() is const and safe to call from several threads at once.
class PlaneSegmenter {
 public:
  /// Throws ecar::Error when the config is invalid.
  explicit PlaneSegmenter(const PlaneConfig& config);
  const PlaneConfig& config() const { return config_; }

  /// The planes in input.points, largest first. Each plane's inliers are removed
  /// before the next is searched, so a point supports at most one observation.
  /// A plane nearly parallel to one found before it and closer to it than
  /// min_separation is that one's depth noise: left out, with its points.
  /// Deterministic for a given input, config and keyframe id. Throws ecar::Error
  /// when up_w or the camera centre is not finite or up_w is zero.
  std::vector<PlaneObservation> segment(const PlaneKeyFrameInput& input) const;

 private:
  PlaneConfig config_;
};

}  // namespace ecar
