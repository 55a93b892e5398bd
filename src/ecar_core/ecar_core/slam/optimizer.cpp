#include "ecar_core/slam/optimizer.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <memory>

#include <ceres/rotation.h>

namespace ecar {
namespace {

/// sqrt_info * (project(R(aa) p_w + t) - uv); false when the point is on (or
/// too near) the camera plane.
template <typename T>
bool reprojectionResidual(const Intrinsics& K, const Eigen::Vector2d& uv, double sqrt_info,
                          const T* pose, const T* p_w, T* residual) {
  T p_c[3];
  ceres::AngleAxisRotatePoint(pose, p_w, p_c);
  p_c[0] += pose[3];
  p_c[1] += pose[4];
  p_c[2] += pose[5];
  if (!(p_c[2] > T(kMinProjectionDepth) || p_c[2] < T(-kMinProjectionDepth)))
    return false;  // also rejects NaN
  const T inv_z = T(1.0) / p_c[2];
  residual[0] = sqrt_info * (K.fx * p_c[0] * inv_z + (K.cx - uv.x()));
  residual[1] = sqrt_info * (K.fy * p_c[1] * inv_z + (K.cy - uv.y()));
  return true;
}

bool isFiniteVector(const Eigen::Ref<const Eigen::VectorXd>& v) { return v.allFinite(); }

bool isValidInformation(double inv_sigma2) { return std::isfinite(inv_sigma2) && inv_sigma2 > 0.0; }

/// Chi2 (error^2 * inv_sigma2) of one observation, +infinity when the point
/// is not in front of the camera (or anything is NaN).
double chi2(const Intrinsics& K, const Eigen::Vector2d& uv, double inv_sigma2, const double* pose,
            const double* p_w) {
  double p_c[3];
  ceres::AngleAxisRotatePoint(pose, p_w, p_c);
  const double z = p_c[2] + pose[5];
  if (!(z > kMinProjectionDepth)) return std::numeric_limits<double>::infinity();
  const double ex = K.fx * (p_c[0] + pose[3]) / z + K.cx - uv.x();
  const double ey = K.fy * (p_c[1] + pose[4]) / z + K.cy - uv.y();
  const double c = (ex * ex + ey * ey) * inv_sigma2;
  return std::isfinite(c) ? c : std::numeric_limits<double>::infinity();
}

/// Options shared by both optimisers: quiet, single-threaded unless asked.
ceres::Solver::Options quietOptions(int max_iterations, int threads) {
  ceres::Solver::Options options;
  options.max_num_iterations = std::max(0, max_iterations);
  options.num_threads = std::max(1, threads);
#if CERES_VERSION_MAJOR < 2
  options.num_linear_solver_threads = options.num_threads;  // Ceres 1.x only
#endif
  options.minimizer_progress_to_stdout = false;
  options.logging_type = ceres::SILENT;
  return options;
}

/// The residual blocks are owned by the caller (built once, reused across
/// passes), so problems built on them must not delete them.
ceres::Problem::Options borrowingProblemOptions() {
  ceres::Problem::Options options;
  options.cost_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  options.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  return options;
}

/// R = exp([w]x) (Rodrigues) and the left Jacobian of SO(3) at w,
/// J_l = I + (1 - cos t) / t^2 [w]x + (t - sin t) / t^3 [w]x^2, for which
/// d(R(w) p)/dw = -[R p]x J_l. Series expansions below t = 1e-2.
void rotationAndLeftJacobian(const double* w_ptr, Eigen::Matrix3d* R, Eigen::Matrix3d* J_l) {
  const Eigen::Map<const Eigen::Vector3d> w(w_ptr);
  const double t2 = w.squaredNorm();
  double a, b, c;  // sin t / t, (1 - cos t) / t^2, (t - sin t) / t^3
  if (t2 < 1e-4) {
    a = 1.0 - t2 / 6.0 * (1.0 - t2 / 20.0);
    b = 0.5 - t2 / 24.0 * (1.0 - t2 / 30.0);
    c = 1.0 / 6.0 - t2 / 120.0 * (1.0 - t2 / 42.0);
  } else {
    const double t = std::sqrt(t2);
    const double s = std::sin(t), h = std::sin(0.5 * t);
    a = s / t;
    b = 2.0 * h * h / t2;
    c = (t - s) / (t2 * t);
  }
  Eigen::Matrix3d W;
  W << 0.0, -w.z(), w.y(), w.z(), 0.0, -w.x(), -w.y(), w.x(), 0.0;
  const Eigen::Matrix3d W2 = W * W;
  *R = Eigen::Matrix3d::Identity() + a * W + b * W2;
  if (J_l != nullptr) *J_l = Eigen::Matrix3d::Identity() + b * W + c * W2;
}

/// Residual and analytic Jacobians (row-major, either may be null) of
/// sqrt_info * (project(R(aa) p_w + t) - uv) in the pose [aa, t] and in p_w.
bool evaluateReprojection(const Intrinsics& K, const Eigen::Vector2d& uv, double sqrt_info,
                          const double* pose, const double* p_w_ptr, double* residual,
                          double* J_pose, double* J_point) {
  if (J_pose == nullptr && J_point == nullptr) {
    return reprojectionResidual(K, uv, sqrt_info, pose, p_w_ptr, residual);
  }
  Eigen::Matrix3d R, J_l;
  rotationAndLeftJacobian(pose, &R, J_pose != nullptr ? &J_l : nullptr);
  const Eigen::Vector3d Rp = R * Eigen::Map<const Eigen::Vector3d>(p_w_ptr);
  const Eigen::Vector3d p_c = Rp + Eigen::Map<const Eigen::Vector3d>(pose + 3);
  if (!(p_c.z() > kMinProjectionDepth || p_c.z() < -kMinProjectionDepth)) return false;
  const double inv_z = 1.0 / p_c.z();
  const double u = p_c.x() * inv_z, v = p_c.y() * inv_z;
  residual[0] = sqrt_info * (K.fx * u + (K.cx - uv.x()));
  residual[1] = sqrt_info * (K.fy * v + (K.cy - uv.y()));
  Eigen::Matrix<double, 2, 3> dr_dp_c;
  const double sx = sqrt_info * K.fx * inv_z, sy = sqrt_info * K.fy * inv_z;
  dr_dp_c << sx, 0.0, -sx * u, 0.0, sy, -sy * v;
  if (J_pose != nullptr) {
    Eigen::Map<Eigen::Matrix<double, 2, 6, Eigen::RowMajor>> J(J_pose);
    Eigen::Matrix3d Rp_x;
    Rp_x << 0.0, -Rp.z(), Rp.y(), Rp.z(), 0.0, -Rp.x(), -Rp.y(), Rp.x(), 0.0;
    J.leftCols<3>().noalias() = -(dr_dp_c * Rp_x) * J_l;
    J.rightCols<3>() = dr_dp_c;
  }
  if (J_point != nullptr) {
    Eigen::Map<Eigen::Matrix<double, 2, 3, Eigen::RowMajor>> J(J_point);
    J.noalias() = dr_dp_c * R;
  }
  return true;
}

/// ReprojectionError with analytic Jacobians (about 4x faster to evaluate
/// than autodiff, which is what local BA spends most of its time on).
class AnalyticReprojectionError : public ceres::SizedCostFunction<2, 6, 3> {
 public:
  explicit AnalyticReprojectionError(const ReprojectionError& f) : f_(f) {}
  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override {
    return evaluateReprojection(f_.K_, f_.uv_, f_.sqrt_info_, parameters[0], parameters[1],
                                residuals, jacobians != nullptr ? jacobians[0] : nullptr,
                                jacobians != nullptr ? jacobians[1] : nullptr);
  }

 private:
  const ReprojectionError f_;
};

/// PoseOnlyReprojectionError with analytic Jacobians.
class AnalyticPoseOnlyReprojectionError : public ceres::SizedCostFunction<2, 6> {
 public:
  explicit AnalyticPoseOnlyReprojectionError(const PoseOnlyReprojectionError& f) : f_(f) {}
  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override {
    return evaluateReprojection(f_.K_, f_.uv_, f_.sqrt_info_, parameters[0], f_.p_w_.data(),
                                residuals, jacobians != nullptr ? jacobians[0] : nullptr, nullptr);
  }

 private:
  const PoseOnlyReprojectionError f_;
};

}  // namespace

template <typename T>
bool ReprojectionError::operator()(const T* pose, const T* point, T* residual) const {
  return reprojectionResidual(K_, uv_, sqrt_info_, pose, point, residual);
}

template <typename T>
bool PoseOnlyReprojectionError::operator()(const T* pose, T* residual) const {
  const T p_w[3] = {T(p_w_.x()), T(p_w_.y()), T(p_w_.z())};
  return reprojectionResidual(K_, uv_, sqrt_info_, pose, p_w, residual);
}

// The double and Jet versions are available to callers (tests, numeric
// differentiation, ceres::AutoDiffCostFunction on these functors).
template bool ReprojectionError::operator()<double>(const double*, const double*, double*) const;
template bool ReprojectionError::operator()<ceres::Jet<double, 9>>(const ceres::Jet<double, 9>*,
                                                                   const ceres::Jet<double, 9>*,
                                                                   ceres::Jet<double, 9>*) const;
template bool PoseOnlyReprojectionError::operator()<double>(const double*, double*) const;
template bool PoseOnlyReprojectionError::operator()<ceres::Jet<double, 6>>(
    const ceres::Jet<double, 6>*, ceres::Jet<double, 6>*) const;

// Analytic Jacobians; the templated operator() is the reference they are
// tested against.
template <typename T>
bool GravityPriorError::operator()(const T* pose, T* residual) const {
  // R(aa) e_z: the map's up axis in the camera frame.
  const T z_w[3] = {T(0.0), T(0.0), T(1.0)};
  T up[3];
  ceres::AngleAxisRotatePoint(pose, z_w, up);
  for (int i = 0; i < 3; ++i) residual[i] = (up[i] - up_c_[i]) * inv_sigma_;
  return true;
}

template bool GravityPriorError::operator()<double>(const double*, double*) const;

ceres::CostFunction* GravityPriorError::Create(const Eigen::Vector3d& up_c, double sigma_rad) {
  return new ceres::AutoDiffCostFunction<GravityPriorError, 3, 6>(
      new GravityPriorError(up_c, sigma_rad));
}

ceres::CostFunction* ReprojectionError::Create(const Eigen::Vector2d& uv, double sqrt_info,
                                               const Intrinsics& K) {
  return new AnalyticReprojectionError(ReprojectionError(uv, sqrt_info, K));
}

ceres::CostFunction* PoseOnlyReprojectionError::Create(const Eigen::Vector3d& p_w,
                                                       const Eigen::Vector2d& uv, double sqrt_info,
                                                       const Intrinsics& K) {
  return new AnalyticPoseOnlyReprojectionError(PoseOnlyReprojectionError(p_w, uv, sqrt_info, K));
}

template <typename T>
bool OdometryTranslationError::operator()(const T* from, const T* to, T* residual) const {
  // Centre of `to`: -R_to^T t_to (rotation by the negated angle-axis).
  const T minus_t[3] = {-to[3], -to[4], -to[5]};
  const T inverse_rotation[3] = {-to[0], -to[1], -to[2]};
  T centre[3];
  ceres::AngleAxisRotatePoint(inverse_rotation, minus_t, centre);
  T in_from[3];
  ceres::AngleAxisRotatePoint(from, centre, in_from);
  for (int i = 0; i < 3; ++i) residual[i] = (in_from[i] + from[3 + i] - t_[i]) * inv_sigma_;
  return true;
}

template bool OdometryTranslationError::operator()<double>(const double*, const double*,
                                                           double*) const;

ceres::CostFunction* OdometryTranslationError::Create(const Eigen::Vector3d& t_from_to,
                                                      double sigma) {
  return new ceres::AutoDiffCostFunction<OdometryTranslationError, 3, 6, 6>(
      new OdometryTranslationError(t_from_to, sigma));
}

void poseToParams(const SE3& T, double* params6) {
  const Eigen::AngleAxisd aa(T.linear());  // identity: angle 0, any axis
  Eigen::Map<Eigen::Vector3d> w(params6), t(params6 + 3);
  w = aa.angle() * aa.axis();
  t = T.translation();
}

SE3 paramsToPose(const double* params6) {
  const Eigen::Map<const Eigen::Vector3d> w(params6);
  const double angle = w.norm();
  SE3 T = SE3::Identity();
  if (angle > std::numeric_limits<double>::epsilon()) {
    T.linear() = Eigen::AngleAxisd(angle, w / angle).toRotationMatrix();
  } else {
    // First order: exact to machine precision at this angle.
    T.linear() << 1.0, -w.z(), w.y(), w.z(), 1.0, -w.x(), -w.y(), w.x(), 1.0;
  }
  T.translation() = Eigen::Map<const Eigen::Vector3d>(params6 + 3);
  return T;
}

namespace {

/// Local BA state: parameter blocks, their initial values and one cost
/// function per usable observation.
class LocalBa {
 public:
  LocalBa(BaProblem* problem, const BaConfig& config) : ba_(*problem), config_(config) {}

  BaResult run();

 private:
  /// Builds a problem on the observations with active_[i] set and solves it;
  /// false when there is nothing to solve or Ceres failed.
  bool solve(bool robust, int iterations);
  /// active_[i] = observation i is in front and below the chi2 threshold.
  void classify();
  double cost(const std::vector<std::array<double, 6>>& poses,
              const std::vector<std::array<double, 3>>& points) const;

  BaProblem& ba_;
  const BaConfig& config_;
  std::vector<std::array<double, 6>> poses_, poses0_;
  std::vector<std::array<double, 3>> points_, points0_;
  std::vector<std::unique_ptr<ceres::CostFunction>> costs_;  // null: unusable observation
  std::vector<bool> active_;
  std::vector<std::unique_ptr<ceres::CostFunction>> gravity_;   // per keyframe, null: no prior
  std::vector<std::unique_ptr<ceres::CostFunction>> odometry_;  // per edge, null: unusable
};

BaResult LocalBa::run() {
  BaResult result;
  const int nk = static_cast<int>(ba_.keyframes.size());
  const int np = static_cast<int>(ba_.points.size());
  const size_t no = ba_.observations.size();

  poses_.resize(nk);
  std::vector<bool> pose_ok(nk);
  for (int k = 0; k < nk; ++k) {
    const Intrinsics& K = ba_.keyframes[k].K;
    // A pose whose camera is unusable cannot be evaluated: its observations are outliers.
    pose_ok[k] = isFinite(ba_.keyframes[k].T_c_w) && K.fx > 0 && K.fy > 0 && std::isfinite(K.fx) &&
                 std::isfinite(K.fy) && std::isfinite(K.cx) && std::isfinite(K.cy);
    if (pose_ok[k]) poseToParams(ba_.keyframes[k].T_c_w, poses_[k].data());
  }
  points_.resize(np);
  std::vector<bool> point_ok(np);
  for (int p = 0; p < np; ++p) {
    point_ok[p] = isFiniteVector(ba_.points[p].p_w);
    Eigen::Map<Eigen::Vector3d>(points_[p].data()) = ba_.points[p].p_w;
  }
  poses0_ = poses_;
  points0_ = points_;

  // Observations that cannot be evaluated (bad index or data, behind the
  // camera at the start) are outliers from the outset.
  costs_.resize(no);
  active_.assign(no, false);
  for (size_t i = 0; i < no; ++i) {
    BaProblem::Observation& o = ba_.observations[i];
    o.outlier = true;
    if (o.keyframe < 0 || o.keyframe >= nk || o.point < 0 || o.point >= np) continue;
    if (!pose_ok[o.keyframe] || !point_ok[o.point]) continue;
    if (!isFiniteVector(o.uv) || !isValidInformation(o.inv_sigma2)) continue;
    if (!std::isfinite(chi2(ba_.keyframes[o.keyframe].K, o.uv, o.inv_sigma2,
                            poses_[o.keyframe].data(), points_[o.point].data()))) {
      continue;
    }
    costs_[i].reset(
        ReprojectionError::Create(o.uv, std::sqrt(o.inv_sigma2), ba_.keyframes[o.keyframe].K));
    active_[i] = true;
  }
  // Gravity priors on free keyframes with a usable up direction.
  gravity_.resize(nk);
  const double sigma_rad = config_.gravity_sigma_deg * M_PI / 180.0;
  if (sigma_rad > 0.0 && std::isfinite(sigma_rad)) {
    for (int k = 0; k < nk; ++k) {
      const auto& up = ba_.keyframes[k].up_c;
      if (ba_.keyframes[k].fixed || !pose_ok[k] || !up || !up->allFinite() || up->norm() < 0.5) {
        continue;
      }
      gravity_[k].reset(GravityPriorError::Create(*up, sigma_rad));
    }
  }
  // Odometry edges between usable poses, at least one of them free.
  odometry_.resize(ba_.odometry.size());
  for (size_t e = 0; e < ba_.odometry.size(); ++e) {
    const BaProblem::OdometryEdge& edge = ba_.odometry[e];
    if (edge.from < 0 || edge.from >= nk || edge.to < 0 || edge.to >= nk || edge.from == edge.to) {
      continue;
    }
    if (!pose_ok[edge.from] || !pose_ok[edge.to] || !edge.t_from_to.allFinite() ||
        !(edge.sigma > 0.0) || !std::isfinite(edge.sigma)) {
      continue;
    }
    if (ba_.keyframes[edge.from].fixed && ba_.keyframes[edge.to].fixed) continue;
    odometry_[e].reset(OdometryTranslationError::Create(edge.t_from_to, edge.sigma));
  }

  bool usable = solve(true, config_.iterations_first);
  if (usable) {
    classify();
    if (config_.iterations_second > 0) {
      usable = solve(false, config_.iterations_second);
      if (usable) classify();
    }
  }
  if (!usable) {  // a failed solve leaves the problem as it was
    poses_ = poses0_;
    points_ = points0_;
    classify();
  }

  // Blocks that no final inlier constrains keep their input values.
  std::vector<bool> kf_seen(nk, false), point_seen(np, false);
  for (size_t i = 0; i < no; ++i) {
    if (!active_[i]) continue;
    kf_seen[ba_.observations[i].keyframe] = true;
    point_seen[ba_.observations[i].point] = true;
  }
  for (int k = 0; k < nk; ++k) {
    if (!kf_seen[k]) poses_[k] = poses0_[k];
  }
  for (int p = 0; p < np; ++p) {
    if (!point_seen[p]) points_[p] = points0_[p];
  }

  for (int k = 0; k < nk; ++k) {
    if (kf_seen[k] && !ba_.keyframes[k].fixed) {
      ba_.keyframes[k].T_c_w = paramsToPose(poses_[k].data());
    }
  }
  for (int p = 0; p < np; ++p) {
    if (point_seen[p]) ba_.points[p].p_w = Eigen::Map<const Eigen::Vector3d>(points_[p].data());
  }
  for (size_t i = 0; i < no; ++i) {
    ba_.observations[i].outlier = !active_[i];
    if (!active_[i]) ++result.num_outliers;
  }
  result.initial_cost = cost(poses0_, points0_);
  result.final_cost = cost(poses_, points_);
  result.converged = usable && std::isfinite(result.final_cost);
  return result;
}

bool LocalBa::solve(bool robust, int iterations) {
  ceres::Problem::Options problem_options = borrowingProblemOptions();
  ceres::Problem problem(problem_options);
  ceres::HuberLoss huber(config_.huber_delta);
  ceres::HuberLoss gravity_huber(config_.gravity_huber);
  std::vector<bool> in_problem_kf(poses_.size(), false), in_problem_point(points_.size(), false);
  int num_residuals = 0;
  for (size_t i = 0; i < costs_.size(); ++i) {
    if (!active_[i]) continue;
    const BaProblem::Observation& o = ba_.observations[i];
    problem.AddResidualBlock(costs_[i].get(), robust ? &huber : nullptr, poses_[o.keyframe].data(),
                             points_[o.point].data());
    in_problem_kf[o.keyframe] = true;
    in_problem_point[o.point] = true;
    ++num_residuals;
  }
  if (num_residuals == 0) return false;
  for (size_t k = 0; k < gravity_.size(); ++k) {
    if (gravity_[k] && in_problem_kf[k]) {
      problem.AddResidualBlock(gravity_[k].get(), &gravity_huber, poses_[k].data());
    }
  }
  ceres::HuberLoss odometry_huber(config_.odometry_huber);
  for (size_t e = 0; e < odometry_.size(); ++e) {
    const BaProblem::OdometryEdge& edge = ba_.odometry[e];
    if (odometry_[e] && in_problem_kf[edge.from] && in_problem_kf[edge.to]) {
      problem.AddResidualBlock(odometry_[e].get(), &odometry_huber, poses_[edge.from].data(),
                               poses_[edge.to].data());
    }
  }

  // Schur complement: points first, then the poses.
  auto* ordering = new ceres::ParameterBlockOrdering;
  int free_keyframes = 0;
  for (size_t p = 0; p < points_.size(); ++p) {
    if (in_problem_point[p]) ordering->AddElementToGroup(points_[p].data(), 0);
  }
  for (size_t k = 0; k < poses_.size(); ++k) {
    if (!in_problem_kf[k]) continue;
    ordering->AddElementToGroup(poses_[k].data(), 1);
    if (ba_.keyframes[k].fixed) {
      problem.SetParameterBlockConstant(poses_[k].data());
    } else {
      ++free_keyframes;
    }
  }
  ceres::Solver::Options options = quietOptions(iterations, config_.threads);
  options.linear_solver_ordering.reset(ordering);
  // The reduced camera matrix is small: dense Cholesky on it beats the sparse
  // machinery up to ~100 free keyframes (measured: 80 free keyframes, 6000
  // points, 7% fewer instructions with DENSE_SCHUR).
  constexpr int kMaxDenseKeyframes = 100;
  options.linear_solver_type = ceres::DENSE_SCHUR;
  if (free_keyframes > kMaxDenseKeyframes && ceres::IsSparseLinearAlgebraLibraryTypeAvailable(
                                                 options.sparse_linear_algebra_library_type)) {
    options.linear_solver_type = ceres::SPARSE_SCHUR;
  }
  ceres::Solver::Summary summary;
  ceres::Solve(options, &problem, &summary);
  return summary.IsSolutionUsable();
}

void LocalBa::classify() {
  for (size_t i = 0; i < costs_.size(); ++i) {
    if (!costs_[i]) continue;
    const BaProblem::Observation& o = ba_.observations[i];
    active_[i] = chi2(ba_.keyframes[o.keyframe].K, o.uv, o.inv_sigma2, poses_[o.keyframe].data(),
                      points_[o.point].data()) <= config_.chi2_threshold;
  }
}

double LocalBa::cost(const std::vector<std::array<double, 6>>& poses,
                     const std::vector<std::array<double, 3>>& points) const {
  double total = 0.0;
  for (size_t i = 0; i < costs_.size(); ++i) {
    if (!active_[i]) continue;
    const BaProblem::Observation& o = ba_.observations[i];
    total += 0.5 * chi2(ba_.keyframes[o.keyframe].K, o.uv, o.inv_sigma2, poses[o.keyframe].data(),
                        points[o.point].data());
  }
  return total;
}

}  // namespace

// ORB-SLAM's LocalBundleAdjustment on plain arrays. After the second pass
// every observation is re-tested (as ORB-SLAM does before erasing
// observations from its map), so `outlier` is the final classification.
// initial_cost / final_cost are 0.5 * sum of chi2 over the final inliers, at
// the input and at the output values (comparable, no robust kernel).
// converged: the last Ceres solve returned a usable solution (converged or
// hit its iteration limit); otherwise the problem is left unchanged.
BaResult localBundleAdjust(BaProblem* problem, const BaConfig& config) {
  if (problem == nullptr) return BaResult();
  return LocalBa(problem, config).run();
}

}  // namespace ecar
