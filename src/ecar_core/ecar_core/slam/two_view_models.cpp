// Homography and fundamental matrix estimation for the two-view
// reconstruction: Hartley normalisation, DLT and 8-point fits and refits, the
// ORB-SLAM scores, and LO-RANSAC (see two_view_models.h).
#include "ecar_core/slam/two_view_models.h"

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <random>
#include <utility>
#include <vector>

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <Eigen/SVD>

namespace ecar::two_view_internal {
namespace {

// Local optimisation of a RANSAC model (kLocalOptimizationChi2Scale): at most
// this many refits.
constexpr int kRefitIterations = 4;

/// Hartley normalisation: centroid at the origin, mean distance sqrt(2).
/// Returns T with x_normalised = T * x.
Eigen::Matrix3d normalization(const std::vector<Eigen::Vector2d>& pts) {
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();
  for (const auto& p : pts) mean += p;
  mean /= static_cast<double>(pts.size());
  double dist = 0.0;
  for (const auto& p : pts) dist += (p - mean).norm();
  dist /= static_cast<double>(pts.size());
  const double s = dist > 1e-12 ? std::sqrt(2.0) / dist : 1.0;
  Eigen::Matrix3d T;
  T << s, 0.0, -s * mean.x(), 0.0, s, -s * mean.y(), 0.0, 0.0, 1.0;
  return T;
}

Eigen::Vector2d apply(const Eigen::Matrix3d& T, const Eigen::Vector2d& p) {
  return (T * p.homogeneous()).hnormalized();
}

/// Least-squares null vector of A (N x 9): the eigenvector of A^T A with the
/// smallest eigenvalue (as OpenCV's 8-point; the points are normalised, so
/// squaring the condition number costs no visible accuracy).
Eigen::Matrix<double, 9, 1> nullVector(const Eigen::MatrixXd& A) {
  const Eigen::Matrix<double, 9, 9> AtA = A.transpose() * A;
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 9, 9>> eig(AtA);
  return eig.eigenvectors().col(0);
}

/// Homography x2 ~ H x1 by DLT on the (normalised) points in idx.
Eigen::Matrix3d fitHomography(const std::vector<Eigen::Vector2d>& n1,
                              const std::vector<Eigen::Vector2d>& n2, const std::vector<int>& idx) {
  Eigen::MatrixXd A(2 * idx.size(), 9);
  for (size_t r = 0; r < idx.size(); ++r) {
    const double u1 = n1[idx[r]].x(), v1 = n1[idx[r]].y();
    const double u2 = n2[idx[r]].x(), v2 = n2[idx[r]].y();
    A.row(2 * r) << 0.0, 0.0, 0.0, -u1, -v1, -1.0, v2 * u1, v2 * v1, v2;
    A.row(2 * r + 1) << u1, v1, 1.0, 0.0, 0.0, 0.0, -u2 * u1, -u2 * v1, -u2;
  }
  const Eigen::Matrix<double, 9, 1> h = nullVector(A);
  Eigen::Matrix3d H;
  H << h(0), h(1), h(2), h(3), h(4), h(5), h(6), h(7), h(8);
  return H;
}

/// The homography refit on many points: plain DLT (its algebraic error is
/// close to the transfer error once the points are normalised).
Eigen::Matrix3d refitHomography(const std::vector<Eigen::Vector2d>& n1,
                                const std::vector<Eigen::Vector2d>& n2, const std::vector<int>& idx,
                                const Eigen::Matrix3d& /*Hn*/) {
  return fitHomography(n1, n2, idx);
}

/// Fundamental matrix x2^T F x1 = 0 by the 8-point algorithm on the
/// (normalised) points in idx, each equation scaled by its weight, with rank 2
/// enforced.
Eigen::Matrix3d fitFundamentalWeighted(const std::vector<Eigen::Vector2d>& n1,
                                       const std::vector<Eigen::Vector2d>& n2,
                                       const std::vector<int>& idx,
                                       const std::vector<double>& weights) {
  Eigen::MatrixXd A(std::max<size_t>(idx.size(), 9), 9);
  A.setZero();  // a zero row keeps the 8-point system square without changing it
  for (size_t r = 0; r < idx.size(); ++r) {
    const double u1 = n1[idx[r]].x(), v1 = n1[idx[r]].y();
    const double u2 = n2[idx[r]].x(), v2 = n2[idx[r]].y();
    A.row(r) << u2 * u1, u2 * v1, u2, v2 * u1, v2 * v1, v2, u1, v1, 1.0;
    A.row(r) *= weights[r];
  }
  const Eigen::Matrix<double, 9, 1> f = nullVector(A);
  Eigen::Matrix3d F;
  F << f(0), f(1), f(2), f(3), f(4), f(5), f(6), f(7), f(8);
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(F, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Vector3d s = svd.singularValues();
  s(2) = 0.0;
  return svd.matrixU() * s.asDiagonal() * svd.matrixV().transpose();
}

Eigen::Matrix3d fitFundamental(const std::vector<Eigen::Vector2d>& n1,
                               const std::vector<Eigen::Vector2d>& n2,
                               const std::vector<int>& idx) {
  return fitFundamentalWeighted(n1, n2, idx, std::vector<double>(idx.size(), 1.0));
}

/// The fundamental matrix refit on many points: the 8-point equations
/// reweighted by the Sampson denominators of the previous estimate, which
/// turns the algebraic error into (nearly) the geometric one.
Eigen::Matrix3d refitFundamental(const std::vector<Eigen::Vector2d>& n1,
                                 const std::vector<Eigen::Vector2d>& n2,
                                 const std::vector<int>& idx, const Eigen::Matrix3d& Fn) {
  constexpr int kReweightings = 3;
  Eigen::Matrix3d F = Fn;
  std::vector<double> weights(idx.size(), 1.0);
  for (int k = 0; k < kReweightings; ++k) {
    for (size_t r = 0; r < idx.size(); ++r) {
      const Eigen::Vector3d l2 = F * n1[idx[r]].homogeneous();
      const Eigen::Vector3d l1 = F.transpose() * n2[idx[r]].homogeneous();
      const double d = std::sqrt(l2.head<2>().squaredNorm() + l1.head<2>().squaredNorm());
      weights[r] = d > 1e-12 ? 1.0 / d : 1.0;
    }
    const Eigen::Matrix3d next = fitFundamentalWeighted(n1, n2, idx, weights);
    if (!next.allFinite()) break;
    F = next;
  }
  return F;
}

/// One correspondence's part of a model score, as ORB-SLAM scores: each
/// direction whose chi2 (squared residual over its variance) is below
/// `inlier_chi2` adds kChi2TwoDof - chi2; an inlier passes both. Written so
/// that NaN (a point mapped to infinity) fails.
void scoreCorrespondence(size_t i, double chi1, double chi2, double inlier_chi2, ScoredModel* out) {
  if (std::isfinite(chi1) && std::isfinite(chi2)) out->chi2[i] = std::max(chi1, chi2);
  if (chi1 <= inlier_chi2) out->score += kChi2TwoDof - chi1;
  if (chi2 <= inlier_chi2) out->score += kChi2TwoDof - chi2;
  if (!(chi1 <= inlier_chi2) || !(chi2 <= inlier_chi2)) return;
  out->inliers[i] = true;
  ++out->num_inliers;
}

/// ORB-SLAM's homography score: symmetric transfer error, each direction an
/// inlier below the 2-dof chi2 threshold and contributing (th - chi2).
ScoredModel scoreHomography(const Eigen::Matrix3d& H21, const std::vector<Eigen::Vector2d>& p1,
                            const std::vector<Eigen::Vector2d>& p2, double sigma) {
  ScoredModel out;
  out.M = H21;
  const Eigen::Matrix3d H12 = H21.inverse();
  if (!H21.allFinite() || !H12.allFinite()) return out;
  const double inv_sigma2 = 1.0 / residualVariance(sigma);
  out.score = 0.0;
  out.inliers.assign(p1.size(), false);
  out.chi2.assign(p1.size(), std::numeric_limits<double>::infinity());
  for (size_t i = 0; i < p1.size(); ++i) {
    const Eigen::Vector3d x12 = H12 * p2[i].homogeneous();
    const Eigen::Vector3d x21 = H21 * p1[i].homogeneous();
    const double chi1 = (p1[i] - x12.hnormalized()).squaredNorm() * inv_sigma2;
    const double chi2 = (p2[i] - x21.hnormalized()).squaredNorm() * inv_sigma2;
    scoreCorrespondence(i, chi1, chi2, kChi2TwoDof, &out);
  }
  return out;
}

}  // namespace

/// ORB-SLAM's fundamental score: squared distance to the epipolar line in each
/// image; an inlier below the 1-dof threshold, scored against the 2-dof one so
/// that H and F scores are comparable.
ScoredModel scoreFundamental(const Eigen::Matrix3d& F21, const std::vector<Eigen::Vector2d>& p1,
                             const std::vector<Eigen::Vector2d>& p2, double sigma) {
  ScoredModel out;
  out.M = F21;
  if (!F21.allFinite()) return out;
  const double inv_sigma2 = 1.0 / residualVariance(sigma);
  out.score = 0.0;
  out.inliers.assign(p1.size(), false);
  out.chi2.assign(p1.size(), std::numeric_limits<double>::infinity());
  for (size_t i = 0; i < p1.size(); ++i) {
    const Eigen::Vector3d x1 = p1[i].homogeneous();
    const Eigen::Vector3d x2 = p2[i].homogeneous();
    const Eigen::Vector3d l2 = F21 * x1;  // epipolar line in image 2
    const Eigen::Vector3d l1 = F21.transpose() * x2;
    const double num = x2.dot(l2);  // == x1.dot(l1)
    const double chi2 = num * num / l2.head<2>().squaredNorm() * inv_sigma2;
    const double chi1 = num * num / l1.head<2>().squaredNorm() * inv_sigma2;
    scoreCorrespondence(i, chi1, chi2, kChi2OneDof, &out);
  }
  return out;
}

namespace {

/// k distinct indices in [0, n), drawn from the Mersenne twister directly so
/// that the samples are the same with every standard library.
void drawSample(std::mt19937* rng, int n, int k, std::vector<int>* sample) {
  sample->clear();
  while (static_cast<int>(sample->size()) < k) {
    const int i = static_cast<int>((*rng)() % static_cast<uint32_t>(n));
    if (std::find(sample->begin(), sample->end(), i) == sample->end()) sample->push_back(i);
  }
}

/// RANSAC over minimal samples; every new best model is locally optimised by
/// refits on its inliers (LO-RANSAC). `fit` maps normalised points and
/// indices to a model in normalised coordinates, `refit` does the same from
/// many points given the current model, `denormalize` turns a model into
/// pixels and `score` scores a pixel model.
template <typename Fit, typename Refit, typename Denormalize, typename Score>
ScoredModel ransac(int sample_size, double inlier_chi2, int iterations, uint32_t seed,
                   const std::vector<Eigen::Vector2d>& n1, const std::vector<Eigen::Vector2d>& n2,
                   Fit fit, Refit refit, Denormalize denormalize, Score score) {
  const int n = static_cast<int>(n1.size());
  std::mt19937 rng(seed);
  ScoredModel best;
  double best_sample_score = -1.0;
  std::vector<int> sample, inliers;
  for (int it = 0; it < iterations; ++it) {
    drawSample(&rng, n, sample_size, &sample);
    Eigen::Matrix3d model_n = fit(n1, n2, sample);
    ScoredModel candidate = score(denormalize(model_n));
    // Minimal-sample models are noisy: every sample that beats the best
    // sample so far is refined, and the best refined model is kept.
    if (candidate.score <= best_sample_score) continue;
    best_sample_score = candidate.score;
    for (int lo = 0; lo < kRefitIterations && candidate.num_inliers > 2 * sample_size; ++lo) {
      inliers.clear();
      for (int i = 0; i < n; ++i) {
        if (candidate.chi2[i] < kLocalOptimizationChi2Scale * inlier_chi2) inliers.push_back(i);
      }
      const Eigen::Matrix3d refit_n = refit(n1, n2, inliers, model_n);
      ScoredModel refined = score(denormalize(refit_n));
      if (refined.score <= candidate.score) break;
      candidate = std::move(refined);
      model_n = refit_n;
    }
    if (candidate.score > best.score) best = std::move(candidate);
  }
  return best;
}

}  // namespace

EstimatedModels estimateModels(const std::vector<Eigen::Vector2d>& p1,
                               const std::vector<Eigen::Vector2d>& p2, double sigma, int iterations,
                               uint32_t seed) {
  const Eigen::Matrix3d T1 = normalization(p1);
  const Eigen::Matrix3d T2 = normalization(p2);
  std::vector<Eigen::Vector2d> n1(p1.size()), n2(p2.size());
  for (size_t i = 0; i < p1.size(); ++i) {
    n1[i] = apply(T1, p1[i]);
    n2[i] = apply(T2, p2[i]);
  }
  const Eigen::Matrix3d T2_inv = T2.inverse();
  EstimatedModels out;
  out.homography = ransac(
      4, kChi2TwoDof, iterations, seed, n1, n2, fitHomography, refitHomography,
      [&](const Eigen::Matrix3d& Hn) { return Eigen::Matrix3d(T2_inv * Hn * T1); },
      [&](const Eigen::Matrix3d& H) { return scoreHomography(H, p1, p2, sigma); });
  out.fundamental = ransac(
      8, kChi2OneDof, iterations, seed ^ 0x9e3779b9u, n1, n2, fitFundamental, refitFundamental,
      [&](const Eigen::Matrix3d& Fn) { return Eigen::Matrix3d(T2.transpose() * Fn * T1); },
      [&](const Eigen::Matrix3d& F) { return scoreFundamental(F, p1, p2, sigma); });
  return out;
}

}  // namespace ecar::two_view_internal
