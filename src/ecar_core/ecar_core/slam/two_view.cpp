// Two-view geometry: triangulation, and the reconstruction that picks the
// homography or fundamental model (estimated in two_view_models.cpp),
// decomposes it into motion hypotheses, checks them by triangulation and
// refines a general-scene motion.
#include "ecar_core/slam/two_view.h"

#include <algorithm>
#include <cmath>
#include <functional>
#include <iomanip>
#include <optional>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Cholesky>
#include <Eigen/Geometry>
#include <Eigen/SVD>

#include "ecar_core/slam/two_view_models.h"

namespace ecar {
namespace {

using two_view_internal::EstimatedModels;
using two_view_internal::estimateModels;
using two_view_internal::kChi2OneDof;
using two_view_internal::kLocalOptimizationChi2Scale;
using two_view_internal::residualVariance;
using two_view_internal::ScoredModel;
using two_view_internal::scoreFundamental;

// A triangulated point whose rays meet at less than ~0.36 deg (ORB-SLAM's
// cos 0.99998) has an unreliable depth: it counts for the motion hypothesis
// but is not returned as a valid point.
constexpr double kMinPointParallaxCos = 0.99998;
// Homogeneous coordinate below which a unit-norm DLT solution is at infinity.
constexpr double kMinHomogeneousW = 1e-9;
// The refined motion replaces the hypothesis unless it keeps fewer points
// than this fraction.
constexpr double kMinRefinedPointRatio = 0.95;

/// A relative motion candidate: X_c2 = R X_c1 + t.
struct Motion {
  Eigen::Matrix3d R;
  Eigen::Vector3d t;
};

/// Triangulation of a model's inliers under one motion hypothesis.
struct MotionCheck {
  int num_good = 0;  ///< positive depth in both views, small reprojection error
  /// Good points plus those whose rays are consistent with a point at infinity
  /// (too little parallax to tell their depth, or even its sign): all that the
  /// motion explains. ORB-SLAM counts these too when it asks that the motion
  /// explain 90% of the model's inliers; without them a scene with a distant
  /// background (a street) never initialises.
  int num_consistent = 0;
  std::vector<bool> good;
  std::vector<Eigen::Vector3d> points_c1;
  std::vector<double> parallax_deg;  ///< per point (good points only meaningful)
  /// Parallax of the 50th most parallax-rich good point (all of them when
  /// fewer): ORB-SLAM's statistic, so distant points do not veto a good baseline.
  double median_parallax_deg = 0.0;
};

double median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  const size_t mid = v.size() / 2;
  std::nth_element(v.begin(), v.begin() + mid, v.end());
  return v[mid];
}

MotionCheck checkMotion(const Motion& motion, const std::vector<Eigen::Vector2d>& p1,
                        const std::vector<Eigen::Vector2d>& p2,
                        const std::vector<Eigen::Vector2d>& x1,
                        const std::vector<Eigen::Vector2d>& x2, const std::vector<bool>& inliers,
                        const Eigen::Matrix3d& K, double sigma) {
  MotionCheck out;
  out.good.assign(p1.size(), false);
  out.points_c1.assign(p1.size(), Eigen::Vector3d::Zero());
  out.parallax_deg.assign(p1.size(), 0.0);
  SE3 T_c2_c1 = SE3::Identity();
  T_c2_c1.linear() = motion.R;
  T_c2_c1.translation() = motion.t;
  const Eigen::Vector3d c2_c1 = -motion.R.transpose() * motion.t;
  const double th2 = 4.0 * sigma * sigma;
  std::vector<double> good_parallax;
  for (size_t i = 0; i < p1.size(); ++i) {
    if (!inliers[i]) continue;
    // A point at infinity along ray 1 appears at K R x1 in image 2 (depth sign
    // free: a far point seen with the baseline reversed looks the same).
    const Eigen::Vector3d ray2 = motion.R * x1[i].homogeneous();
    const Eigen::Vector3d at_infinity = K * (ray2.z() < 0.0 ? Eigen::Vector3d(-ray2) : ray2);
    const bool far_consistent =
        at_infinity.z() > 0.0 && (p2[i] - at_infinity.hnormalized()).squaredNorm() <= th2;
    const std::optional<Eigen::Vector3d> p = triangulate(SE3::Identity(), T_c2_c1, x1[i], x2[i]);
    bool good = static_cast<bool>(p);
    if (good) {
      const Eigen::Vector3d p_c2 = T_c2_c1 * *p;
      const double e1 = (p1[i] - (K * *p).hnormalized()).squaredNorm();
      const double e2 = (p2[i] - (K * p_c2).hnormalized()).squaredNorm();
      good = e1 <= th2 && e2 <= th2;
    }
    if (good || far_consistent) ++out.num_consistent;
    if (!good) continue;
    out.good[i] = true;
    out.points_c1[i] = *p;
    out.parallax_deg[i] = parallaxDeg(*p, Eigen::Vector3d::Zero(), c2_c1);
    good_parallax.push_back(out.parallax_deg[i]);
    ++out.num_good;
  }
  std::sort(good_parallax.begin(), good_parallax.end(), std::greater<double>());
  out.median_parallax_deg =
      good_parallax.empty() ? 0.0 : good_parallax[std::min<size_t>(49, good_parallax.size() - 1)];
  return out;
}

/// Orthonormal 3x2 basis of the plane orthogonal to the unit vector t.
Eigen::Matrix<double, 3, 2> tangentBasis(const Eigen::Vector3d& t) {
  const Eigen::Vector3d a =
      std::abs(t.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
  Eigen::Matrix<double, 3, 2> B;
  B.col(0) = t.cross(a).normalized();
  B.col(1) = t.cross(B.col(0));
  return B;
}

/// Motion moved by delta = (rotation increment, translation increment in
/// the tangent plane of t); t stays unit.
Motion retract(const Motion& m, const Eigen::Matrix<double, 5, 1>& delta) {
  Motion out;
  out.R = expSO3(delta.head<3>()) * m.R;
  out.t = (m.t + tangentBasis(m.t) * delta.tail<2>()).normalized();
  return out;
}

/// Sampson residuals (pixels) of the correspondences in idx under the
/// essential matrix [t]x R.
Eigen::VectorXd sampsonResiduals(const Motion& m, const std::vector<Eigen::Vector2d>& p1,
                                 const std::vector<Eigen::Vector2d>& p2,
                                 const std::vector<int>& idx, const Eigen::Matrix3d& K_inv) {
  const Eigen::Matrix3d F = K_inv.transpose() * skew(m.t) * m.R * K_inv;
  Eigen::VectorXd r(idx.size());
  for (size_t k = 0; k < idx.size(); ++k) {
    const Eigen::Vector3d x1 = p1[idx[k]].homogeneous();
    const Eigen::Vector3d x2 = p2[idx[k]].homogeneous();
    const Eigen::Vector3d l2 = F * x1;
    const Eigen::Vector3d l1 = F.transpose() * x2;
    const double d = std::sqrt(l2.head<2>().squaredNorm() + l1.head<2>().squaredNorm());
    r(k) = d > 0.0 ? x2.dot(l2) / d : 0.0;
  }
  return r;
}

/// Robust Levenberg-Marquardt with a numeric Jacobian: minimises the Huber
/// cost of residuals(state) over increments delta of size Dim applied by
/// retract(state, delta). Returns the best state found.
template <int Dim, typename State, typename Residuals, typename Retract>
State levenbergMarquardt(const State& initial, double huber, Residuals residuals, Retract retract) {
  using Delta = Eigen::Matrix<double, Dim, 1>;
  constexpr int kIterations = 30;
  constexpr double kStep = 1e-6;
  auto cost = [huber](const Eigen::VectorXd& r) {
    double c = 0.0;
    for (int k = 0; k < r.size(); ++k) {
      const double a = std::abs(r(k));
      c += a <= huber ? a * a : huber * (2.0 * a - huber);
    }
    return c;
  };
  State state = initial;
  Eigen::VectorXd r = residuals(state);
  double current = cost(r);
  if (!std::isfinite(current)) return initial;
  double lambda = 1e-3;
  for (int it = 0; it < kIterations; ++it) {
    Eigen::MatrixXd J(r.size(), Dim);
    for (int j = 0; j < Dim; ++j) {
      Delta d = Delta::Zero();
      d(j) = kStep;
      J.col(j) =
          (residuals(retract(state, d)) - residuals(retract(state, Delta(-d)))) / (2.0 * kStep);
    }
    Eigen::VectorXd w(r.size());
    for (int k = 0; k < r.size(); ++k) {
      w(k) = std::abs(r(k)) <= huber ? 1.0 : huber / std::abs(r(k));
    }
    const Eigen::Matrix<double, Dim, Dim> A = J.transpose() * w.asDiagonal() * J;
    const Delta g = J.transpose() * w.asDiagonal() * r;
    bool improved = false;
    while (lambda < 1e8) {
      Eigen::Matrix<double, Dim, Dim> damped = A;
      damped.diagonal() *= 1.0 + lambda;
      damped.diagonal().array() += 1e-12;
      const Delta delta = damped.ldlt().solve(-g);
      if (!delta.allFinite()) break;
      const State candidate = retract(state, delta);
      const Eigen::VectorXd r_candidate = residuals(candidate);
      const double c = cost(r_candidate);
      if (c < current) {
        improved = current - c > 1e-10 * current;
        state = candidate;
        r = r_candidate;
        current = c;
        lambda = std::max(lambda * 0.1, 1e-9);
        break;
      }
      lambda *= 10.0;
    }
    if (!improved) break;
  }
  return state;
}

/// Refines a general-scene motion by minimising the Sampson error of its
/// essential matrix (5 dof): the 8-point F ignores that K is known, which
/// costs accuracy in the rotation and the translation direction. The first
/// round uses the correspondences within a loose gate (Huber-weighted); the
/// next ones re-select the inliers under the current motion, so that outliers
/// near an epipolar line do not bias the result. (Not for planar scenes,
/// where E is poorly constrained.)
Motion refineMotion(const Motion& initial, const std::vector<Eigen::Vector2d>& p1,
                    const std::vector<Eigen::Vector2d>& p2, const Eigen::Matrix3d& K,
                    double sigma) {
  constexpr int kRounds = 3;
  const Eigen::Matrix3d K_inv = K.inverse();
  const double inlier2 = kChi2OneDof * residualVariance(sigma);
  std::vector<int> all(p1.size());
  for (size_t i = 0; i < p1.size(); ++i) all[i] = static_cast<int>(i);
  Motion m = initial;
  for (int round = 0; round < kRounds; ++round) {
    const double gate2 = round == 0 ? kLocalOptimizationChi2Scale * inlier2 : inlier2;
    const Eigen::VectorXd r = sampsonResiduals(m, p1, p2, all, K_inv);
    std::vector<int> idx;
    for (int i = 0; i < r.size(); ++i) {
      if (r(i) * r(i) < gate2) idx.push_back(i);
    }
    if (idx.size() < 8) break;
    m = levenbergMarquardt<5>(
        m, std::sqrt(inlier2),
        [&](const Motion& x) { return sampsonResiduals(x, p1, p2, idx, K_inv); }, retract);
  }
  return m;
}

/// The four (R, t) of an essential matrix; t has unit norm.
std::vector<Motion> motionsFromEssential(const Eigen::Matrix3d& E) {
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(E, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d U = svd.matrixU();
  Eigen::Matrix3d V = svd.matrixV();
  if (U.determinant() < 0.0) U = -U;
  if (V.determinant() < 0.0) V = -V;
  Eigen::Matrix3d W;
  W << 0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0;
  const Eigen::Matrix3d R1 = U * W * V.transpose();
  const Eigen::Matrix3d R2 = U * W.transpose() * V.transpose();
  const Eigen::Vector3d t = U.col(2).normalized();
  return {{R1, t}, {R1, -t}, {R2, t}, {R2, -t}};
}

/// The eight (R, t) of a homography by Faugeras' SVD decomposition (as in
/// ORB-SLAM); t has unit norm. Empty when two singular values of K^-1 H K
/// coincide (pure rotation, or a special motion whose decomposition is not
/// discrete).
std::vector<Motion> motionsFromHomography(const Eigen::Matrix3d& H21, const Eigen::Matrix3d& K) {
  std::vector<Motion> motions;
  const Eigen::Matrix3d A = K.inverse() * H21 * K;
  if (!A.allFinite()) return motions;
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(A, Eigen::ComputeFullU | Eigen::ComputeFullV);
  const Eigen::Matrix3d& U = svd.matrixU();
  const Eigen::Matrix3d& V = svd.matrixV();
  const double s = U.determinant() * V.determinant();
  const double d1 = svd.singularValues()(0);
  const double d2 = svd.singularValues()(1);
  const double d3 = svd.singularValues()(2);
  if (!(d3 > 0.0) || d1 / d2 < 1.00001 || d2 / d3 < 1.00001) return motions;
  const double d1s = d1 * d1, d2s = d2 * d2, d3s = d3 * d3;
  const double aux1 = std::sqrt((d1s - d2s) / (d1s - d3s));
  const double aux3 = std::sqrt((d2s - d3s) / (d1s - d3s));
  const double x1[] = {aux1, aux1, -aux1, -aux1};
  const double x3[] = {aux3, -aux3, aux3, -aux3};
  const double root = std::sqrt((d1s - d2s) * (d2s - d3s));
  auto add = [&](const Eigen::Matrix3d& Rp, const Eigen::Vector3d& tp) {
    Motion m;
    m.R = s * U * Rp * V.transpose();
    m.t = (U * tp).normalized();
    if (m.R.allFinite() && m.t.allFinite()) motions.push_back(m);
  };
  // d' = d2.
  const double stheta_abs = root / ((d1 + d3) * d2);
  const double ctheta = (d2s + d1 * d3) / ((d1 + d3) * d2);
  const double stheta[] = {stheta_abs, -stheta_abs, -stheta_abs, stheta_abs};
  for (int i = 0; i < 4; ++i) {
    Eigen::Matrix3d Rp;
    Rp << ctheta, 0.0, -stheta[i], 0.0, 1.0, 0.0, stheta[i], 0.0, ctheta;
    add(Rp, Eigen::Vector3d(x1[i], 0.0, -x3[i]) * (d1 - d3));
  }
  // d' = -d2.
  const double sphi_abs = root / ((d1 - d3) * d2);
  const double cphi = (d1 * d3 - d2s) / ((d1 - d3) * d2);
  const double sphi[] = {sphi_abs, -sphi_abs, -sphi_abs, sphi_abs};
  for (int i = 0; i < 4; ++i) {
    Eigen::Matrix3d Rp;
    Rp << cphi, 0.0, sphi[i], 0.0, -1.0, 0.0, sphi[i], 0.0, -cphi;
    add(Rp, Eigen::Vector3d(x1[i], 0.0, x3[i]) * (d1 + d3));
  }
  return motions;
}

std::string formatDouble(double v, int precision) {
  std::ostringstream os;
  os << std::fixed << std::setprecision(precision) << v;
  return os.str();
}

/// A refusal: the reason, and no valid points (num_valid and parallax_deg
/// are kept as diagnostics).
TwoViewResult refuse(TwoViewResult result, const std::string& reason) {
  result.success = false;
  result.reason = reason;
  std::fill(result.valid.begin(), result.valid.end(), false);
  std::fill(result.points_c1.begin(), result.points_c1.end(), Eigen::Vector3d::Zero());
  return result;
}

}  // namespace

std::optional<Eigen::Vector3d> triangulate(const SE3& T_c1_w, const SE3& T_c2_w,
                                           const Eigen::Vector2d& x1, const Eigen::Vector2d& x2) {
  if (!x1.allFinite() || !x2.allFinite() || !isFinite(T_c1_w) || !isFinite(T_c2_w)) {
    return std::nullopt;
  }
  const Eigen::Matrix<double, 3, 4> P1 = T_c1_w.matrix().topRows<3>();
  const Eigen::Matrix<double, 3, 4> P2 = T_c2_w.matrix().topRows<3>();
  Eigen::Matrix4d A;
  A.row(0) = x1.x() * P1.row(2) - P1.row(0);
  A.row(1) = x1.y() * P1.row(2) - P1.row(1);
  A.row(2) = x2.x() * P2.row(2) - P2.row(0);
  A.row(3) = x2.y() * P2.row(2) - P2.row(1);
  for (int r = 0; r < 4; ++r) {
    const double n = A.row(r).norm();
    if (n > 0.0) A.row(r) /= n;
  }
  const Eigen::JacobiSVD<Eigen::Matrix4d> svd(A, Eigen::ComputeFullV);
  const Eigen::Vector4d X = svd.matrixV().col(3);
  if (!X.allFinite() || std::abs(X(3)) < kMinHomogeneousW) return std::nullopt;
  const Eigen::Vector3d p_w = X.head<3>() / X(3);
  if (!p_w.allFinite()) return std::nullopt;
  if ((T_c1_w * p_w).z() <= 0.0 || (T_c2_w * p_w).z() <= 0.0) return std::nullopt;
  return p_w;
}

double parallaxDeg(const Eigen::Vector3d& p_w, const Eigen::Vector3d& c1_w,
                   const Eigen::Vector3d& c2_w) {
  const Eigen::Vector3d r1 = p_w - c1_w;
  const Eigen::Vector3d r2 = p_w - c2_w;
  // atan2 of |cross| and dot is accurate for the small angles that matter here.
  return std::atan2(r1.cross(r2).norm(), r1.dot(r2)) * 180.0 / M_PI;
}

// valid and points_c1 have one entry per input correspondence (points_c1 is
// zero where valid is false); T_c2_c1 stays identity unless success.
TwoViewResult reconstructTwoView(const std::vector<Eigen::Vector2d>& pts1,
                                 const std::vector<Eigen::Vector2d>& pts2, const Eigen::Matrix3d& K,
                                 const TwoViewConfig& config, uint32_t seed,
                                 const std::optional<TwoViewGravity>& gravity) {
  TwoViewResult result;
  if (pts1.size() != pts2.size()) {
    return refuse(result, "size mismatch: " + std::to_string(pts1.size()) + " vs " +
                              std::to_string(pts2.size()) + " points");
  }
  result.valid.assign(pts1.size(), false);
  result.points_c1.assign(pts1.size(), Eigen::Vector3d::Zero());
  if (!validIntrinsics(K)) return refuse(result, "invalid intrinsics K");
  if (config.ransac_iterations < 1 || !(config.sigma > 0.0) || !std::isfinite(config.sigma)) {
    return refuse(result, "invalid config: ransac_iterations and sigma must be positive");
  }

  // Correspondences with finite pixels; index maps back into the inputs.
  std::vector<int> index;
  std::vector<Eigen::Vector2d> p1, p2;
  for (size_t i = 0; i < pts1.size(); ++i) {
    if (!pts1[i].allFinite() || !pts2[i].allFinite()) continue;
    index.push_back(static_cast<int>(i));
    p1.push_back(pts1[i]);
    p2.push_back(pts2[i]);
  }
  const int n = static_cast<int>(p1.size());
  if (n < std::max(8, config.min_triangulated)) {
    return refuse(result, "too few correspondences: " + std::to_string(n));
  }

  const double sigma = config.sigma;
  const EstimatedModels models = estimateModels(p1, p2, sigma, config.ransac_iterations, seed);
  const ScoredModel& h = models.homography;
  const ScoredModel& f = models.fundamental;
  const double s_h = std::max(h.score, 0.0);
  const double s_f = std::max(f.score, 0.0);
  if (s_h + s_f <= 0.0) return refuse(result, "too few inliers: 0");
  const Eigen::Matrix3d K_inv = K.inverse();
  std::vector<Eigen::Vector2d> x1(n), x2(n);
  for (int i = 0; i < n; ++i) {
    x1[i] = (K_inv * p1[i].homogeneous()).hnormalized();
    x2[i] = (K_inv * p2[i].homogeneous()).hnormalized();
  }
  // The motion hypotheses of one model, each checked by triangulation; the
  // best one unless it is refused (the reason then).
  struct Selected {
    Motion motion;
    MotionCheck check;
    std::string refused;
    bool ambiguous = false;
  };
  const auto select = [&](bool homography) {
    Selected out;
    const ScoredModel& model = homography ? h : f;
    if (model.num_inliers < config.min_triangulated) {
      out.refused = "too few inliers: " + std::to_string(model.num_inliers);
      return out;
    }
    const std::vector<Motion> motions = homography
                                            ? motionsFromHomography(model.M, K)
                                            : motionsFromEssential(K.transpose() * model.M * K);
    std::vector<MotionCheck> checks;
    int against_gravity = 0;
    for (const Motion& m : motions) {
      checks.push_back(checkMotion(m, p1, p2, x1, x2, model.inliers, K, sigma));
      if (gravity) {
        const double c = (m.R * gravity->up_c1.normalized()).dot(gravity->up_c2.normalized());
        if (c < std::cos(gravity->max_deg * M_PI / 180.0) && checks.back().num_good > 0) {
          checks.back().num_good = 0;  // ruled out by the accelerometer
          ++against_gravity;
        }
      }
    }
    int best = -1;
    for (size_t k = 0; k < checks.size(); ++k) {
      if (best < 0 || checks[k].num_good > checks[best].num_good) best = static_cast<int>(k);
    }
    if (best < 0 || checks[best].num_good == 0) {
      out.refused = against_gravity > 0
                        ? "no motion hypothesis agrees with gravity"
                        : "weak baseline or degenerate motion: no hypothesis triangulates points "
                          "in front of both cameras";
      return out;
    }
    int second_good = 0;
    for (size_t k = 0; k < checks.size(); ++k) {
      if (static_cast<int>(k) != best) second_good = std::max(second_good, checks[k].num_good);
    }
    out.motion = motions[best];
    out.check = std::move(checks[best]);
    // Low parallax is checked first: it is the usual cause of the other failures.
    if (out.check.median_parallax_deg < config.min_parallax_deg) {
      out.refused = "weak baseline: parallax " + formatDouble(out.check.median_parallax_deg, 2) +
                    " deg < " + formatDouble(config.min_parallax_deg, 2);
      return out;
    }
    if (second_good > config.ambiguity_ratio * out.check.num_good) {
      out.ambiguous = true;
      out.refused = "ambiguous motion: best hypothesis triangulates " +
                    std::to_string(out.check.num_good) + " points, second " +
                    std::to_string(second_good);
    }
    return out;
  };
  result.used_homography = s_h / (s_h + s_f) > config.homography_ratio;
  Selected selected = select(result.used_homography);
  if (selected.ambiguous && result.used_homography && config.fundamental_breaks_ties) {
    // A plane's two decompositions explain the views equally: the scene is
    // not one plane (walls and floor) but the baseline is still short. The
    // fundamental matrix's motion decides when it is itself unambiguous.
    Selected from_f = select(false);
    if (from_f.refused.empty()) {
      selected = std::move(from_f);
      result.used_homography = false;
    } else {
      selected.refused += " (homography; fundamental: " + from_f.refused + ")";
    }
  }
  result.parallax_deg = selected.check.median_parallax_deg;
  if (!selected.refused.empty()) return refuse(result, selected.refused);
  const ScoredModel& model = result.used_homography ? h : f;
  Motion motion = selected.motion;
  MotionCheck check = std::move(selected.check);

  // From F, the motion is refined with K known (its inliers re-selected under
  // the refined essential matrix), and kept unless that loses points.
  int num_inliers = model.num_inliers;
  if (!result.used_homography) {
    const Motion refined = refineMotion(motion, p1, p2, K, sigma);
    const Eigen::Matrix3d F = K_inv.transpose() * skew(refined.t) * refined.R * K_inv;
    const ScoredModel refined_model = scoreFundamental(F, p1, p2, sigma);
    MotionCheck refined_check =
        checkMotion(refined, p1, p2, x1, x2, refined_model.inliers, K, sigma);
    if (refined_check.num_good >= kMinRefinedPointRatio * check.num_good) {
      motion = refined;
      check = std::move(refined_check);
      num_inliers = refined_model.num_inliers;
    }
  }

  std::vector<double> valid_parallax;
  const double min_point_parallax_deg = std::acos(kMinPointParallaxCos) * 180.0 / M_PI;
  for (int i = 0; i < n; ++i) {
    if (!check.good[i] || check.parallax_deg[i] < min_point_parallax_deg) continue;
    result.valid[index[i]] = true;
    result.points_c1[index[i]] = check.points_c1[i];
    valid_parallax.push_back(check.parallax_deg[i]);
  }
  result.num_valid = static_cast<int>(valid_parallax.size());
  if (result.num_valid < config.min_triangulated) {
    return refuse(result, "too few triangulated points: " + std::to_string(result.num_valid) +
                              " < " + std::to_string(config.min_triangulated));
  }
  // The motion must explain nearly all the model's inliers (valid points, or
  // far points consistent with it), else the model or the hypothesis is wrong.
  if (check.num_consistent < config.min_triangulated_ratio * num_inliers) {
    return refuse(
        result, "too few points explained by the motion: " + std::to_string(check.num_consistent) +
                    " of " + std::to_string(num_inliers) + " inliers");
  }
  result.parallax_deg = median(std::move(valid_parallax));
  result.T_c2_c1.linear() = motion.R;
  result.T_c2_c1.translation() = motion.t;
  result.success = true;
  return result;
}

}  // namespace ecar
