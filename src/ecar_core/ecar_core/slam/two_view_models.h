// Private to the two-view reconstruction (two_view.cpp): the homography and
// fundamental matrix of a set of correspondences, each estimated by its own
// LO-RANSAC and scored as ORB-SLAM scores them.
#pragma once

#include <cstdint>
#include <vector>

#include <Eigen/Core>

namespace ecar::two_view_internal {

// Chi-square 95% quantiles: one degree of freedom (distance to an epipolar
// line) and two degrees of freedom (a transferred point).
constexpr double kChi2OneDof = 3.841;
constexpr double kChi2TwoDof = 5.991;
// Local optimisation of a RANSAC model: refits on the points within a looser
// threshold (this multiple of the inlier chi2), kept while the score improves.
constexpr double kLocalOptimizationChi2Scale = 4.0;

/// A model (H21 or F21, pixels of image 1 to image 2) and its ORB-SLAM score.
struct ScoredModel {
  Eigen::Matrix3d M = Eigen::Matrix3d::Zero();
  double score = -1.0;
  std::vector<bool> inliers;
  int num_inliers = 0;
  std::vector<double> chi2;  ///< per point, the larger of the two directions
};

/// Variance of a transfer or epipolar residual: both keypoints carry pixel
/// noise sigma, so the residual's variance is 2 sigma^2 (ORB-SLAM divides by
/// sigma^2 alone, which rejects ~20% of true matches when sigma is the real
/// noise and puts planar scenes on the H/F decision boundary).
inline double residualVariance(double sigma) { return 2.0 * sigma * sigma; }

/// ORB-SLAM's fundamental score: squared distance to the epipolar line in each
/// image; an inlier below the 1-dof threshold, scored against the 2-dof one so
/// that H and F scores are comparable.
ScoredModel scoreFundamental(const Eigen::Matrix3d& F21, const std::vector<Eigen::Vector2d>& p1,
                             const std::vector<Eigen::Vector2d>& p2, double sigma);

/// The homography and the fundamental matrix of the correspondences, each by
/// its own RANSAC on Hartley-normalised points (separate random streams
/// derived from the seed, so each is reproducible on its own).
struct EstimatedModels {
  ScoredModel homography;
  ScoredModel fundamental;
};

EstimatedModels estimateModels(const std::vector<Eigen::Vector2d>& p1,
                               const std::vector<Eigen::Vector2d>& p2, double sigma, int iterations,
                               uint32_t seed);

}  // namespace ecar::two_view_internal
