// Camera pose from 3D-2D correspondences: EPnP / P3P in RANSAC (OpenCV) and a
// 2-point RANSAC for a known up direction (gravity), each refined on its
// inliers. Pixel inputs are undistorted pixels (ideal pinhole with K).
#pragma once

#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "ecar_core/common/geometry.h"

namespace ecar {

struct PnpConfig {
  int ransac_iterations = 300;
  double reprojection_error = 4.0;  ///< px, inlier threshold
  double confidence = 0.99;
  int min_inliers = 15;
};

struct PnpResult {
  bool success = false;
  SE3 T_c_w = SE3::Identity();
  std::vector<int> inliers;  ///< indices into the inputs
};

/// Camera pose from 3D-2D correspondences (EPnP / P3P in RANSAC, refined on the
/// inliers). Fails (success = false) with fewer than min_inliers inliers.
PnpResult solvePnpRansac(const std::vector<Eigen::Vector3d>& points_w,
                         const std::vector<Eigen::Vector2d>& pixels, const Eigen::Matrix3d& K,
                         const PnpConfig& config);

/// Camera pose from 3D-2D correspondences when the direction of the world's
/// +z axis in the camera frame (`up_c`, from gravity) is known: only the yaw
/// about z and the translation are free, so a RANSAC sample needs 2
/// correspondences (a linear system and a quadratic for the unit yaw vector)
/// and much higher outlier ratios are tolerated than with P3P / EPnP. The
/// returned pose keeps the camera's up axis exactly at `up_c` (least squares
/// over the inliers). Fails with fewer than config.min_inliers inliers.
PnpResult solvePnpGravityRansac(const std::vector<Eigen::Vector3d>& points_w,
                                const std::vector<Eigen::Vector2d>& pixels,
                                const Eigen::Matrix3d& K, const Eigen::Vector3d& up_c,
                                const PnpConfig& config, uint32_t seed = 1);

}  // namespace ecar
