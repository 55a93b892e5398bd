// Multi-view geometry for monocular SLAM: triangulation, two-view
// reconstruction (homography vs fundamental model); PnP is in pnp.h.
// Pixel inputs are undistorted pixels (ideal pinhole with K).
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "ecar_core/common/geometry.h"

namespace ecar {

/// Linear (DLT) triangulation of normalised image points x1, x2 ((x/z, y/z))
/// seen by cameras T_c1_w and T_c2_w. nullopt when the point is at infinity,
/// behind either camera, or not finite.
std::optional<Eigen::Vector3d> triangulate(const SE3& T_c1_w, const SE3& T_c2_w,
                                           const Eigen::Vector2d& x1, const Eigen::Vector2d& x2);

/// Parallax angle (degrees) between the rays from two camera centres to p_w.
double parallaxDeg(const Eigen::Vector3d& p_w, const Eigen::Vector3d& c1_w,
                   const Eigen::Vector3d& c2_w);

struct TwoViewConfig {
  int ransac_iterations = 200;
  double sigma = 1.0;                   ///< pixel noise (px) for the model scores / inlier tests
  double min_parallax_deg = 1.0;        ///< median parallax of the triangulated points
  int min_triangulated = 50;            ///< points with parallax and positive depth
  double min_triangulated_ratio = 0.9;  ///< of the model's inliers, explained (incl. far points)
  /// Homography chosen when S_H / (S_H + S_F) exceeds this (ORB-SLAM's heuristic).
  double homography_ratio = 0.40;
  /// The best motion hypothesis must triangulate clearly more points than the
  /// second best (ambiguity check), by this factor.
  double ambiguity_ratio = 0.75;
  /// When the homography's decompositions tie, let the fundamental matrix's
  /// motion decide (if it is itself unambiguous) instead of refusing.
  bool fundamental_breaks_ties = true;
};

struct TwoViewResult {
  bool success = false;
  std::string reason;                      ///< why it was refused (weak baseline, ambiguity, ...)
  SE3 T_c2_c1 = SE3::Identity();           ///< translation has unit norm
  std::vector<Eigen::Vector3d> points_c1;  ///< per correspondence, in camera 1 (valid only)
  std::vector<bool> valid;                 ///< per correspondence: inlier and triangulated
  bool used_homography = false;
  double parallax_deg = 0.0;  ///< median parallax of the valid points
  int num_valid = 0;
};

/// What the device's accelerometer says of the two views: the up direction in
/// each camera. A motion hypothesis whose rotation does not carry up_c1 onto
/// up_c2 within max_deg is ruled out. This settles the decompositions that
/// cheirality cannot tell apart, such as the pair twisted by 180 degrees about
/// a baseline along the optical axis (walking straight ahead).
struct TwoViewGravity {
  Eigen::Vector3d up_c1 = Eigen::Vector3d::UnitY();
  Eigen::Vector3d up_c2 = Eigen::Vector3d::UnitY();
  double max_deg = 10.0;
};

/// Relative pose and structure from correspondences pts1[i] <-> pts2[i]
/// (undistorted pixels) of a calibrated camera K. Computes a homography and a
/// fundamental matrix with RANSAC in parallel hypotheses, scores both, picks
/// one, recovers the motion (rejecting ambiguous decompositions; with
/// `gravity`, only among the hypotheses that agree with it) and triangulates;
/// refuses weak baselines (low parallax or too few points).
TwoViewResult reconstructTwoView(const std::vector<Eigen::Vector2d>& pts1,
                                 const std::vector<Eigen::Vector2d>& pts2, const Eigen::Matrix3d& K,
                                 const TwoViewConfig& config, uint32_t seed = 1,
                                 const std::optional<TwoViewGravity>& gravity = std::nullopt);

}  // namespace ecar
