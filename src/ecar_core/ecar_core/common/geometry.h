// Rigid (SE(3)) and similarity (Sim(3)) transforms on Eigen.
//
// Naming follows the frames: T_w_c maps camera coordinates into the world,
// p_w = T_w_c * p_c. Tangent vectors are ordered (rotation, translation).
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace ecar {

using SE3 = Eigen::Isometry3d;
using Vector6d = Eigen::Matrix<double, 6, 1>;

/// A similarity transform p' = scale * R * p + t.
struct Sim3 {
  double scale = 1.0;
  Eigen::Matrix3d R = Eigen::Matrix3d::Identity();
  Eigen::Vector3d t = Eigen::Vector3d::Zero();

  Eigen::Vector3d operator*(const Eigen::Vector3d& p) const { return scale * (R * p) + t; }
  Sim3 operator*(const Sim3& o) const;
  Sim3 inverse() const;
  /// Applies the similarity to a pose T_w_c: rotation composes, position maps.
  SE3 transformPose(const SE3& T_w_c) const;
  Eigen::Matrix4d matrix() const;
};

/// Skew-symmetric matrix [v]x with [v]x * u = v x u.
Eigen::Matrix3d skew(const Eigen::Vector3d& v);

/// Rotation from an axis-angle vector (Rodrigues), and back.
Eigen::Matrix3d expSO3(const Eigen::Vector3d& w);
Eigen::Vector3d logSO3(const Eigen::Matrix3d& R);

/// The rotation nearest to a nearly orthonormal matrix (through its unit
/// quaternion): products of rotations drift off SO(3) by rounding, and
/// composing with a transpose as the inverse amplifies the drift.
Eigen::Matrix3d nearestRotation(const Eigen::Matrix3d& M);

/// SE(3) exponential/logarithm with xi = (w, v): rotation R = exp(w),
/// translation t = V(w) v.
SE3 expSE3(const Vector6d& xi);
Vector6d logSE3(const SE3& T);

/// Builds a pose from a quaternion (x, y, z, w order as in TUM files) and a translation.
SE3 makeSE3(const Eigen::Quaterniond& q, const Eigen::Vector3d& t);

/// Rotation angle of R in radians, in [0, pi].
double rotationAngle(const Eigen::Matrix3d& R);

/// Geodesic interpolation between two poses, alpha in [0, 1].
SE3 interpolate(const SE3& a, const SE3& b, double alpha);

/// Rotation that makes the camera at `eye` look at `target` with image "up"
/// as close as possible to `up_w`, in the optical convention (x right, y down,
/// z forward). Returns T_w_c.
SE3 lookAt(const Eigen::Vector3d& eye, const Eigen::Vector3d& target,
           const Eigen::Vector3d& up_w = Eigen::Vector3d::UnitZ());

/// True when every coefficient is finite.
bool isFinite(const SE3& T);

/// True when K is an ideal pinhole's intrinsic matrix: finite, positive focal
/// lengths, last row (0, 0, 1).
bool validIntrinsics(const Eigen::Matrix3d& K);

}  // namespace ecar
