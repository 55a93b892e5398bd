// optimizePose (optimizer.h): the pose-only optimisation of tracking, which the
// server runs four times per upload and every device once per frame.
//
// A 6-parameter problem with a few hundred residuals is too small for a general
// solver: Ceres spent 12 M of the 15 M instructions per upload of this step on
// building problems and its evaluation machinery (callgrind on the corridor,
// ecar_slam_offline --every 4). This is Levenberg-Marquardt written for it: the
// Huber kernel by iteratively reweighted least squares, the 6x6 normal equations
// accumulated in place and solved with Eigen's LDLT, the pose updated on the left
// (R <- Exp(w) R, t <- Exp(w) t + v). The objective is the one the Ceres version
// minimised (tested against it in optimizer_test), so the optimum is the same.
#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include <Eigen/Cholesky>
#include <Eigen/Geometry>

#include "ecar_core/common/geometry.h"
#include "ecar_core/slam/optimizer.h"

namespace ecar {
namespace {

using Matrix6d = Eigen::Matrix<double, 6, 6>;

/// Ceres' defaults, which the previous implementation used.
constexpr double kInitialDamping = 1e-4;     // 1 / initial trust region radius
constexpr double kFunctionTolerance = 1e-6;  // relative cost decrease
constexpr double kParameterTolerance = 1e-8;
constexpr double kGradientTolerance = 1e-10;

struct Pose {
  Eigen::Matrix3d R;
  Eigen::Vector3d t;
};

/// Chi2 (error^2 * inv_sigma2) at the pose, +infinity when the point is not in
/// front of the camera (or anything is NaN).
double chi2(const Intrinsics& K, const PoseObservation& o, const Pose& T) {
  const Eigen::Vector3d p = T.R * o.p_w + T.t;
  if (!(p.z() > kMinProjectionDepth)) return std::numeric_limits<double>::infinity();
  const double ex = K.fx * p.x() / p.z() + K.cx - o.uv.x();
  const double ey = K.fy * p.y() / p.z() + K.cy - o.uv.y();
  const double c = (ex * ex + ey * ey) * o.inv_sigma2;
  return std::isfinite(c) ? c : std::numeric_limits<double>::infinity();
}

/// One round's problem: the observations in `active`, with or without the kernel.
class PoseProblem {
 public:
  PoseProblem(const Intrinsics& K, const std::vector<PoseObservation>& obs,
              const std::vector<int>& active, bool robust, double huber_delta)
      : K_(K), obs_(obs), active_(active), robust_(robust), delta_(huber_delta) {}

  /// 0.5 * sum of rho(|r|^2); +infinity when a point is on the camera plane.
  double cost(const Pose& T) const {
    double sum = 0.0;
    for (const int i : active_) {
      Eigen::Vector2d r;
      if (!residual(obs_[i], T, &r, nullptr)) return std::numeric_limits<double>::infinity();
      sum += rho(r.squaredNorm());
    }
    return 0.5 * sum;
  }

  /// The reweighted normal equations at T: H = sum w J^T J, g = sum w J^T r.
  /// False when a point is on the camera plane.
  bool linearise(const Pose& T, Matrix6d* H, Vector6d* g) const {
    H->setZero();
    g->setZero();
    Eigen::Matrix<double, 2, 6> J;
    for (const int i : active_) {
      Eigen::Vector2d r;
      if (!residual(obs_[i], T, &r, &J)) return false;
      const double w = weight(r.squaredNorm());
      H->noalias() += w * J.transpose() * J;
      g->noalias() += w * J.transpose() * r;
    }
    return true;
  }

 private:
  /// r = sqrt_info * (project(R p_w + t) - uv) and, when J is given, dr/d[w, v]
  /// for the left update p_c <- Exp(w) p_c + v.
  bool residual(const PoseObservation& o, const Pose& T, Eigen::Vector2d* r,
                Eigen::Matrix<double, 2, 6>* J) const {
    const Eigen::Vector3d p = T.R * o.p_w + T.t;
    if (!(p.z() > kMinProjectionDepth || p.z() < -kMinProjectionDepth))
      return false;  // also rejects NaN
    const double s = std::sqrt(o.inv_sigma2);
    const double inv_z = 1.0 / p.z();
    const double u = p.x() * inv_z, v = p.y() * inv_z;
    (*r) << s * (K_.fx * u + K_.cx - o.uv.x()), s * (K_.fy * v + K_.cy - o.uv.y());
    if (J != nullptr) {
      const double sx = s * K_.fx * inv_z, sy = s * K_.fy * inv_z;
      // dr/dp_c = [sx 0 -sx u; 0 sy -sy v]; dp_c/dw = -[p_c]x, dp_c/dv = I.
      (*J) << -sx * u * p.y(), sx * (p.z() + u * p.x()), -sx * p.y(), sx, 0.0, -sx * u,
          -sy * (p.z() + v * p.y()), sy * v * p.x(), sy * p.x(), 0.0, sy, -sy * v;
    }
    return true;
  }

  /// Huber's rho(s) on the squared residual s, as ceres::HuberLoss.
  double rho(double s) const {
    if (!robust_ || s <= delta_ * delta_) return s;
    return 2.0 * delta_ * std::sqrt(s) - delta_ * delta_;
  }
  /// rho'(s): the reweighting of an observation's normal equations.
  double weight(double s) const {
    if (!robust_ || s <= delta_ * delta_) return 1.0;
    return delta_ / std::sqrt(s);
  }

  const Intrinsics& K_;
  const std::vector<PoseObservation>& obs_;
  const std::vector<int>& active_;
  const bool robust_;
  const double delta_;
};

Pose updated(const Pose& T, const Vector6d& step) {
  const Eigen::Matrix3d dR = expSO3(step.head<3>());
  return Pose{dR * T.R, dR * T.t + step.tail<3>()};
}

/// Levenberg-Marquardt on one round's problem from *T, at most `iterations`
/// steps (tried or taken). False when the cost is not finite at the start.
bool minimise(const PoseProblem& problem, int iterations, Pose* T) {
  double cost = problem.cost(*T);
  if (!std::isfinite(cost)) return false;
  double damping = kInitialDamping;
  Matrix6d H;
  Vector6d g;
  bool linearised = false;
  for (int it = 0; it < iterations; ++it) {
    if (!linearised) {
      if (!problem.linearise(*T, &H, &g)) return true;  // cannot move from here
      if (g.lpNorm<Eigen::Infinity>() <= kGradientTolerance) return true;
      linearised = true;
    }
    Matrix6d A = H;
    A.diagonal() += damping * H.diagonal().cwiseMax(1e-6);
    const Eigen::LDLT<Matrix6d> ldlt(A);
    const Vector6d step = -ldlt.solve(g);
    if (ldlt.info() != Eigen::Success || !step.allFinite()) {
      damping *= 10.0;
      continue;
    }
    const Pose candidate = updated(*T, step);
    const double candidate_cost = problem.cost(candidate);
    if (candidate_cost < cost) {
      const double decrease = (cost - candidate_cost) / cost;
      *T = candidate;
      cost = candidate_cost;
      linearised = false;
      damping = std::max(damping / 3.0, 1e-12);
      const double size = T->t.norm() + 1.0;  // the rotation part is O(1)
      if (decrease <= kFunctionTolerance || step.norm() <= kParameterTolerance * size) break;
    } else {
      damping *= 4.0;
      if (damping > 1e16) break;
    }
  }
  return true;
}

}  // namespace

// Rounds as in ORB-SLAM's PoseOptimization, but each round continues from the
// previous estimate. On failure *T_c_w is left as given; the flags are always
// written. final_cost is 0.5 * sum of chi2 over the final inliers.
PoseOptimizerResult optimizePose(const Intrinsics& K, const std::vector<PoseObservation>& obs,
                                 SE3* T_c_w, std::vector<bool>* inliers,
                                 const PoseOptimizerConfig& config) {
  PoseOptimizerResult result;
  const size_t n = obs.size();
  std::vector<bool> flags(n, true);
  if (inliers != nullptr && inliers->size() == n) flags = *inliers;

  // Observations with non-finite data never take part.
  std::vector<bool> valid(n);
  for (size_t i = 0; i < n; ++i) {
    valid[i] = obs[i].p_w.allFinite() && obs[i].uv.allFinite() &&
               std::isfinite(obs[i].inv_sigma2) && obs[i].inv_sigma2 > 0.0;
    if (!valid[i]) flags[i] = false;
  }
  auto writeFlags = [&]() {
    if (inliers != nullptr) *inliers = flags;
  };
  if (T_c_w == nullptr || !isFinite(*T_c_w) || n == 0) {
    writeFlags();
    return result;
  }

  // The rotation is projected onto SO(3) on the way in and out: callers compose
  // poses with Isometry3d::inverse() (a transpose), which amplifies any drift
  // from orthonormality frame after frame (1e-6 grew to 1 in 60 uploads).
  Pose T{nearestRotation(T_c_w->linear()), T_c_w->translation()};
  // Re-tests every valid observation at the current pose; *cost = 0.5 * the
  // summed chi2 of the inliers.
  auto classify = [&](double* cost) {
    *cost = 0.0;
    for (size_t i = 0; i < n; ++i) {
      if (!valid[i]) continue;
      const double c = chi2(K, obs[i], T);
      flags[i] = c <= config.chi2_threshold;
      if (flags[i]) *cost += 0.5 * c;
    }
  };

  const int min_solve = std::max(config.min_inliers, 3);  // 3 points pin a pose down
  std::vector<int> active;
  active.reserve(n);
  bool solved = false;
  double cost = 0.0;
  for (int round = 0; round < config.rounds; ++round) {
    // The kernel is dropped in the last round once earlier rounds have
    // removed the gross outliers.
    const bool robust = round + 1 < config.rounds || config.rounds == 1;
    active.clear();
    for (size_t i = 0; i < n; ++i) {
      if (!flags[i]) continue;
      if (!std::isfinite(chi2(K, obs[i], T))) {
        flags[i] = false;  // behind the camera: cannot start from here
        continue;
      }
      active.push_back(static_cast<int>(i));
    }
    if (static_cast<int>(active.size()) < min_solve) break;
    const PoseProblem problem(K, obs, active, robust, config.huber_delta);
    if (!minimise(problem, std::max(0, config.iterations_per_round), &T)) {
      solved = false;
      break;
    }
    solved = true;
    classify(&cost);
  }

  SE3 out = SE3::Identity();
  out.linear() = nearestRotation(T.R);
  out.translation() = T.t;
  result.num_inliers = static_cast<int>(std::count(flags.begin(), flags.end(), true));
  result.final_cost = cost;
  result.success =
      solved && result.num_inliers >= config.min_inliers && isFinite(out) && std::isfinite(cost);
  if (result.success) *T_c_w = out;
  writeFlags();
  return result;
}

}  // namespace ecar
