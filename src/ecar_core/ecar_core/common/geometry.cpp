#include "ecar_core/common/geometry.h"

#include <cmath>

namespace ecar {

Sim3 Sim3::operator*(const Sim3& o) const {
  Sim3 r;
  r.scale = scale * o.scale;
  r.R = R * o.R;
  r.t = scale * (R * o.t) + t;
  return r;
}

Sim3 Sim3::inverse() const {
  Sim3 r;
  r.scale = 1.0 / scale;
  r.R = R.transpose();
  r.t = -(r.scale * (r.R * t));
  return r;
}

SE3 Sim3::transformPose(const SE3& T_w_c) const {
  SE3 out = SE3::Identity();
  out.linear() = R * T_w_c.linear();
  out.translation() = (*this) * Eigen::Vector3d(T_w_c.translation());
  return out;
}

Eigen::Matrix4d Sim3::matrix() const {
  Eigen::Matrix4d m = Eigen::Matrix4d::Identity();
  m.topLeftCorner<3, 3>() = scale * R;
  m.topRightCorner<3, 1>() = t;
  return m;
}

Eigen::Matrix3d skew(const Eigen::Vector3d& v) {
  Eigen::Matrix3d m;
  m << 0, -v.z(), v.y(), v.z(), 0, -v.x(), -v.y(), v.x(), 0;
  return m;
}

Eigen::Matrix3d nearestRotation(const Eigen::Matrix3d& M) {
  return Eigen::Quaterniond(M).normalized().toRotationMatrix();
}

Eigen::Matrix3d expSO3(const Eigen::Vector3d& w) {
  const double theta = w.norm();
  if (theta < 1e-10) return Eigen::Matrix3d::Identity() + skew(w);
  return Eigen::AngleAxisd(theta, w / theta).toRotationMatrix();
}

Eigen::Vector3d logSO3(const Eigen::Matrix3d& R) {
  const Eigen::AngleAxisd aa(R);
  return aa.angle() * aa.axis();
}

namespace {
// V(w) = I + (1 - cos t)/t^2 [w]x + (t - sin t)/t^3 [w]x^2, the left Jacobian of SO(3).
Eigen::Matrix3d leftJacobianSO3(const Eigen::Vector3d& w) {
  const double theta = w.norm();
  const Eigen::Matrix3d W = skew(w);
  if (theta < 1e-8) return Eigen::Matrix3d::Identity() + 0.5 * W;
  const double t2 = theta * theta;
  return Eigen::Matrix3d::Identity() + (1.0 - std::cos(theta)) / t2 * W +
         (theta - std::sin(theta)) / (t2 * theta) * W * W;
}
}  // namespace

SE3 expSE3(const Vector6d& xi) {
  SE3 T = SE3::Identity();
  const Eigen::Vector3d w = xi.head<3>();
  T.linear() = expSO3(w);
  T.translation() = leftJacobianSO3(w) * xi.tail<3>();
  return T;
}

Vector6d logSE3(const SE3& T) {
  Vector6d xi;
  const Eigen::Vector3d w = logSO3(T.linear());
  xi.head<3>() = w;
  xi.tail<3>() = leftJacobianSO3(w).inverse() * T.translation();
  return xi;
}

SE3 makeSE3(const Eigen::Quaterniond& q, const Eigen::Vector3d& t) {
  SE3 T = SE3::Identity();
  T.linear() = q.normalized().toRotationMatrix();
  T.translation() = t;
  return T;
}

double rotationAngle(const Eigen::Matrix3d& R) {
  const double c = std::max(-1.0, std::min(1.0, 0.5 * (R.trace() - 1.0)));
  return std::acos(c);
}

SE3 interpolate(const SE3& a, const SE3& b, double alpha) {
  const Eigen::Quaterniond qa(a.linear()), qb(b.linear());
  SE3 T = SE3::Identity();
  T.linear() = qa.slerp(alpha, qb).toRotationMatrix();
  T.translation() = (1.0 - alpha) * a.translation() + alpha * b.translation();
  return T;
}

SE3 lookAt(const Eigen::Vector3d& eye, const Eigen::Vector3d& target, const Eigen::Vector3d& up_w) {
  Eigen::Vector3d z = (target - eye).normalized();
  Eigen::Vector3d x = z.cross(up_w);  // right = forward x up (up is -y in the image)
  if (x.norm() < 1e-9) x = z.unitOrthogonal();
  x.normalize();
  const Eigen::Vector3d y = z.cross(x);
  SE3 T = SE3::Identity();
  T.linear().col(0) = x;
  T.linear().col(1) = y;
  T.linear().col(2) = z;
  T.translation() = eye;
  return T;
}

bool isFinite(const SE3& T) { return T.matrix().allFinite(); }

bool validIntrinsics(const Eigen::Matrix3d& K) {
  return K.allFinite() && K(0, 0) > 0.0 && K(1, 1) > 0.0 && K(2, 0) == 0.0 && K(2, 1) == 0.0 &&
         K(2, 2) == 1.0;
}

}  // namespace ecar
