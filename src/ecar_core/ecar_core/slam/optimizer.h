// Non-linear least squares: pose-only optimisation for tracking (a dedicated
// Levenberg-Marquardt on the 6x6 normal equations, pose_optimizer.cpp: Ceres'
// per-problem overhead was 4/5 of its cost) and local bundle adjustment for
// mapping, with Ceres. Poses are T_c_w (world to camera), parameterised for
// Ceres as [angle-axis (3), translation (3)] blocks, so no manifold is needed
// (works with Ceres 1.14 and 2.x). Pixels are undistorted.
#pragma once

#include <cstdint>
#include <optional>
#include <vector>

#include <ceres/ceres.h>
#include <Eigen/Core>

#include "ecar_core/common/camera.h"
#include "ecar_core/common/geometry.h"

namespace ecar {

/// Points closer to the camera plane than this cannot be projected: a step
/// that brings one there is rejected. Points behind the camera project
/// (mirrored) so that one wild point does not veto a whole step; the
/// optimisers flag them as outliers afterwards, as ORB-SLAM does. Shared by
/// bundle adjustment (optimizer.cpp) and pose-only optimisation
/// (pose_optimizer.cpp).
inline constexpr double kMinProjectionDepth = 1e-6;

/// One observation of a fixed 3D point in the camera being optimised.
struct PoseObservation {
  Eigen::Vector3d p_w;
  Eigen::Vector2d uv;       ///< undistorted pixel
  double inv_sigma2 = 1.0;  ///< 1 / (pyramid scale^2): information of the measurement
};

struct PoseOptimizerConfig {
  int rounds = 4;  ///< optimise, classify outliers, repeat
  int iterations_per_round = 10;
  double chi2_threshold = 5.991;  ///< 95% of chi2 with 2 dof, on error^2 * inv_sigma2
  double huber_delta = 2.4477;    ///< sqrt(5.991)
  int min_inliers = 10;           ///< fewer: the result is flagged as failed
};

struct PoseOptimizerResult {
  bool success = false;
  int num_inliers = 0;
  double final_cost = 0.0;
};

/// Refines T_c_w from its observations with a Huber kernel; over several
/// rounds observations with chi2 above the threshold are marked outliers and
/// left out (but re-tested each round). `inliers` gets one flag per observation.
/// Observations start as inliers unless (*inliers)[i] is false on entry with
/// the same size. Thread-safe (no shared state).
PoseOptimizerResult optimizePose(const Intrinsics& K, const std::vector<PoseObservation>& obs,
                                 SE3* T_c_w, std::vector<bool>* inliers,
                                 const PoseOptimizerConfig& config = PoseOptimizerConfig());

/// A local bundle adjustment problem on plain arrays (the map copies its local
/// window in, runs this without holding locks, and writes the result back).
struct BaProblem {
  struct KeyFrame {
    SE3 T_c_w;
    Intrinsics K;  ///< the keyframe's own camera (devices differ)
    bool fixed = false;
    /// Measured up direction (unit, camera frame; the accelerometer's gravity
    /// reading normalised) where the map's z axis is up: with
    /// BaConfig::gravity_sigma_deg > 0 it adds a gravity prior on the pose.
    std::optional<Eigen::Vector3d> up_c;
  };
  struct Point {
    Eigen::Vector3d p_w;
  };
  struct Observation {
    int keyframe;  ///< index into keyframes
    int point;     ///< index into points
    Eigen::Vector2d uv;
    double inv_sigma2 = 1.0;
    bool outlier = false;  ///< set by localBundleAdjust
  };
  /// A device's odometry between two of its keyframes: where keyframe `to`'s
  /// camera centre lies in keyframe `from`'s camera frame (metres). Only in a
  /// metric map; it holds the map's scale to the devices' odometry.
  struct OdometryEdge {
    int from = 0, to = 0;  ///< indices into keyframes
    Eigen::Vector3d t_from_to = Eigen::Vector3d::Zero();
    double sigma = 0.01;  ///< m, standard deviation of the measurement
  };
  std::vector<KeyFrame> keyframes;
  std::vector<Point> points;
  std::vector<Observation> observations;
  std::vector<OdometryEdge> odometry;
};

struct BaConfig {
  int iterations_first = 5;    ///< with the robust kernel
  int iterations_second = 10;  ///< after removing outliers
  double chi2_threshold = 5.991;
  double huber_delta = 2.4477;
  int threads = 1;
  /// Standard deviation (degrees) of the gravity prior on free keyframes that
  /// carry `up_c`: residual (R_c_w e_z - up_c) / sigma. Reprojections alone
  /// leave the slow tilt of a long monocular map (a corridor bends by tenths
  /// of a degree over 30 m) weakly observed; gravity fixes roll and pitch.
  /// 0 disables the prior.
  double gravity_sigma_deg = 0.3;
  /// Huber threshold of the gravity residual in sigmas: a reading disturbed by
  /// the device's acceleration pulls no harder than this.
  double gravity_huber = 3.0;
  /// Huber threshold of the odometry residuals in sigmas (a slipping odometry
  /// pulls no harder than this).
  double odometry_huber = 3.0;
};

struct BaResult {
  int num_outliers = 0;
  double initial_cost = 0.0, final_cost = 0.0;
  bool converged = false;
};

/// Optimises the free keyframe poses and all points in place. Observations
/// whose chi2 exceeds the threshold after the first pass, or that end behind
/// their camera, are flagged `outlier` and left out of the second pass.
BaResult localBundleAdjust(BaProblem* problem, const BaConfig& config = BaConfig());

/// Residual functors (exposed so their Jacobians are tested).
/// Reprojection of a free point into a free pose [aa, t]: 2 residuals,
/// sqrt(inv_sigma2) * (project(R(aa) p + t) - uv).
struct ReprojectionError {
  ReprojectionError(const Eigen::Vector2d& uv, double sqrt_info, const Intrinsics& K)
      : uv_(uv), sqrt_info_(sqrt_info), K_(K) {}
  template <typename T>
  bool operator()(const T* pose, const T* point, T* residual) const;
  /// Cost function on blocks (pose [6], point [3]) with analytic Jacobians
  /// (tested against autodiff on operator()); ownership passes to the caller.
  static ceres::CostFunction* Create(const Eigen::Vector2d& uv, double sqrt_info,
                                     const Intrinsics& K);
  Eigen::Vector2d uv_;
  double sqrt_info_;
  Intrinsics K_;
};

/// Reprojection of a fixed point into a free pose [aa, t]: optimizePose's
/// objective as a Ceres cost function (its reference in the tests).
struct PoseOnlyReprojectionError {
  PoseOnlyReprojectionError(const Eigen::Vector3d& p_w, const Eigen::Vector2d& uv, double sqrt_info,
                            const Intrinsics& K)
      : p_w_(p_w), uv_(uv), sqrt_info_(sqrt_info), K_(K) {}
  template <typename T>
  bool operator()(const T* pose, T* residual) const;
  /// Cost function on one block (pose [6]) with analytic Jacobians (tested
  /// against autodiff on operator()); ownership passes to the caller.
  static ceres::CostFunction* Create(const Eigen::Vector3d& p_w, const Eigen::Vector2d& uv,
                                     double sqrt_info, const Intrinsics& K);
  Eigen::Vector3d p_w_;
  Eigen::Vector2d uv_;
  double sqrt_info_;
  Intrinsics K_;
};

/// Odometry between two poses [aa, t] (T_c_w): 3 residuals,
/// (T_from_w * centre(to) - t_from_to) / sigma.
struct OdometryTranslationError {
  OdometryTranslationError(const Eigen::Vector3d& t_from_to, double sigma)
      : t_(t_from_to), inv_sigma_(1.0 / sigma) {}
  template <typename T>
  bool operator()(const T* from, const T* to, T* residual) const;
  /// Autodiff cost function on two blocks (poses [6]); ownership passes to the caller.
  static ceres::CostFunction* Create(const Eigen::Vector3d& t_from_to, double sigma);
  Eigen::Vector3d t_;
  double inv_sigma_;
};

/// Gravity prior on a free pose [aa, t] (T_c_w): 3 residuals,
/// (R(aa) e_z - up_c) / sigma_rad, about the tilt angle in sigmas.
struct GravityPriorError {
  GravityPriorError(const Eigen::Vector3d& up_c, double sigma_rad)
      : up_c_(up_c.normalized()), inv_sigma_(1.0 / sigma_rad) {}
  template <typename T>
  bool operator()(const T* pose, T* residual) const;
  /// Autodiff cost function on one block (pose [6]); ownership passes to the caller.
  static ceres::CostFunction* Create(const Eigen::Vector3d& up_c, double sigma_rad);
  Eigen::Vector3d up_c_;
  double inv_sigma_;
};

/// SE3 <-> [angle-axis, translation].
void poseToParams(const SE3& T, double* params6);
SE3 paramsToPose(const double* params6);

}  // namespace ecar
