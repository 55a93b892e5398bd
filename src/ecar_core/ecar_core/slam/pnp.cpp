#include "ecar_core/slam/pnp.h"

#include <algorithm>
#include <cmath>
#include <functional>
#include <iomanip>
#include <limits>
#include <random>
#include <sstream>

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <Eigen/LU>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <opencv2/core/eigen.hpp>
namespace ecar {

PnpResult solvePnpRansac(const std::vector<Eigen::Vector3d>& points_w,
                         const std::vector<Eigen::Vector2d>& pixels, const Eigen::Matrix3d& K,
                         const PnpConfig& config) {
  PnpResult result;
  if (points_w.size() != pixels.size() || !validIntrinsics(K)) return result;
  if (config.ransac_iterations < 1 || !(config.reprojection_error > 0.0)) return result;
  std::vector<int> index;
  std::vector<cv::Point3d> object;
  std::vector<cv::Point2d> image;
  for (size_t i = 0; i < points_w.size(); ++i) {
    if (!points_w[i].allFinite() || !pixels[i].allFinite()) continue;
    index.push_back(static_cast<int>(i));
    object.emplace_back(points_w[i].x(), points_w[i].y(), points_w[i].z());
    image.emplace_back(pixels[i].x(), pixels[i].y());
  }
  const int min_inliers = std::max(4, config.min_inliers);
  if (static_cast<int>(object.size()) < min_inliers) return result;

  cv::Mat K_cv;
  cv::eigen2cv(K, K_cv);
  cv::Mat rvec, tvec;
  std::vector<int> inliers;
  // The pose, the inliers under it (in front of the camera, reprojection
  // error below the threshold) and a Levenberg-Marquardt refinement on them.
  auto select_inliers = [&]() {
    cv::Mat R_cv;
    cv::Rodrigues(rvec, R_cv);
    Eigen::Matrix3d R;
    Eigen::Vector3d t;
    cv::cv2eigen(R_cv, R);
    cv::cv2eigen(tvec, t);
    inliers.clear();
    const double th2 = config.reprojection_error * config.reprojection_error;
    for (size_t i = 0; i < object.size(); ++i) {
      const Eigen::Vector3d p_c = R * Eigen::Vector3d(object[i].x, object[i].y, object[i].z) + t;
      if (p_c.z() <= 0.0) continue;
      const Eigen::Vector2d u = (K * p_c).hnormalized();
      if ((u - Eigen::Vector2d(image[i].x, image[i].y)).squaredNorm() < th2) {
        inliers.push_back(static_cast<int>(i));
      }
    }
  };
  auto refine = [&]() {
    std::vector<cv::Point3d> obj_in;
    std::vector<cv::Point2d> img_in;
    for (int i : inliers) {
      obj_in.push_back(object[i]);
      img_in.push_back(image[i]);
    }
    cv::solvePnPRefineLM(obj_in, img_in, K_cv, cv::noArray(), rvec, tvec);
  };
  try {
    const bool ok =
        cv::solvePnPRansac(object, image, K_cv, cv::noArray(), rvec, tvec, false,
                           config.ransac_iterations, static_cast<float>(config.reprojection_error),
                           config.confidence, inliers, cv::SOLVEPNP_EPNP);
    if (!ok || static_cast<int>(inliers.size()) < 4) return result;
    rvec.convertTo(rvec, CV_64F);
    tvec.convertTo(tvec, CV_64F);
    for (int round = 0; round < 2; ++round) {
      refine();
      select_inliers();
      if (static_cast<int>(inliers.size()) < 4) return result;
    }
  } catch (const cv::Exception&) {
    return result;
  }
  if (static_cast<int>(inliers.size()) < min_inliers) return result;

  cv::Mat R_cv;
  cv::Rodrigues(rvec, R_cv);
  Eigen::Matrix3d R;
  Eigen::Vector3d t;
  cv::cv2eigen(R_cv, R);
  cv::cv2eigen(tvec, t);
  if (!R.allFinite() || !t.allFinite()) return result;
  result.T_c_w.linear() = R;
  result.T_c_w.translation() = t;
  for (int i : inliers) result.inliers.push_back(index[i]);
  result.success = true;
  return result;
}

namespace {

// Gravity-constrained PnP. With R_c_w = A Rz(yaw) (A maps the world z axis to
// up_c) and q = A^T p_c = Rz(yaw) p_w + tau, a bearing g = A^T K^-1 (u, v, 1)
// satisfies g x q = 0: three equations (rank 2) linear in
// x = (cos yaw, sin yaw, tau_x, tau_y, tau_z) plus a constant from p_w.z.
void gravityRows(const Eigen::Vector3d& g, const Eigen::Vector3d& p,
                 Eigen::Matrix<double, 3, 6>* rows) {
  // q = M x + q0, the columns of M and q0 as the last column.
  Eigen::Matrix<double, 3, 6> M;
  M << p.x(), -p.y(), 1, 0, 0, 0,  //
      p.y(), p.x(), 0, 1, 0, 0,    //
      0, 0, 0, 0, 1, p.z();
  Eigen::Matrix3d G;  // [g]x
  G << 0, -g.z(), g.y(), g.z(), 0, -g.x(), -g.y(), g.x(), 0;
  *rows = G * M;
}

// The two independent rows of a correspondence's three (g . (g x q) = 0:
// the row of g's largest component is the combination of the others).
void independentRows(const Eigen::Matrix<double, 3, 6>& rows, const Eigen::Vector3d& g,
                     Eigen::Matrix<double, 4, 6>* out, int at) {
  int drop = 0;
  g.cwiseAbs().maxCoeff(&drop);
  for (int r = 0, k = 0; r < 3; ++r) {
    if (r != drop) out->row(at + k++) = rows.row(r);
  }
}

// Solutions x (c^2 + s^2 = 1) of the stacked system [B | d] (x, 1) = 0 of two
// correspondences (four independent rows): its null space is two-dimensional,
// found by a pivoted LU (with a 6x6 Jacobi SVD instead the whole RANSAC took
// 3.9 times the instructions, callgrind on the offline atlas run). A
// degenerate sample (a lower rank) gives none.
int solveTwoPoint(const Eigen::Matrix<double, 4, 6>& A, Eigen::Matrix<double, 5, 1> out[2]) {
  const Eigen::FullPivLU<Eigen::Matrix<double, 4, 6>> lu(A);
  if (lu.rank() != 4) return 0;
  const Eigen::Matrix<double, 6, Eigen::Dynamic, 0, 6, 6> kernel = lu.kernel();
  Eigen::Matrix<double, 6, 1> v1 = kernel.col(0).normalized(), v2 = kernel.col(1).normalized();
  if (std::abs(v1(5)) < std::abs(v2(5))) std::swap(v1, v2);
  if (std::abs(v1(5)) < 1e-12) return 0;
  const Eigen::Matrix<double, 6, 1> u = v1 / v1(5);
  const Eigen::Matrix<double, 6, 1> n = v2 - v2(5) * u;
  // (u0 + l n0)^2 + (u1 + l n1)^2 = 1.
  const double a = n(0) * n(0) + n(1) * n(1);
  const double b = 2.0 * (u(0) * n(0) + u(1) * n(1));
  const double c = u(0) * u(0) + u(1) * u(1) - 1.0;
  int count = 0;
  auto emit = [&](double l) {
    const Eigen::Matrix<double, 6, 1> x = u + l * n;
    if (x.allFinite()) out[count++] = x.head<5>();
  };
  if (a < 1e-12) {
    if (std::abs(b) > 1e-12) emit(-c / b);
    return count;
  }
  const double disc = b * b - 4.0 * a * c;
  if (disc < 0.0) {
    emit(-b / (2.0 * a));  // closest to the unit circle
    return count;
  }
  const double r = std::sqrt(disc);
  emit((-b + r) / (2.0 * a));
  emit((-b - r) / (2.0 * a));
  return count;
}

// The pose of a solution x; the yaw vector is normalised.
SE3 gravityPose(const Eigen::Matrix3d& A, const Eigen::Matrix<double, 5, 1>& x) {
  const double norm = std::hypot(x(0), x(1));
  const double c = x(0) / norm, s = x(1) / norm;
  Eigen::Matrix3d Rz;
  Rz << c, -s, 0, s, c, 0, 0, 0, 1;
  SE3 T = SE3::Identity();
  T.linear() = A * Rz;
  T.translation() = A * x.tail<3>();
  return T;
}

}  // namespace

PnpResult solvePnpGravityRansac(const std::vector<Eigen::Vector3d>& points_w,
                                const std::vector<Eigen::Vector2d>& pixels,
                                const Eigen::Matrix3d& K, const Eigen::Vector3d& up_c,
                                const PnpConfig& config, uint32_t seed) {
  PnpResult result;
  if (points_w.size() != pixels.size() || !validIntrinsics(K)) return result;
  if (config.ransac_iterations < 1 || !(config.reprojection_error > 0.0)) return result;
  if (!up_c.allFinite() || up_c.norm() < 1e-9) return result;
  // A: a rotation whose third column is up_c.
  const Eigen::Vector3d z = up_c.normalized();
  Eigen::Vector3d x_axis =
      std::abs(z.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
  x_axis = (x_axis - x_axis.dot(z) * z).normalized();
  Eigen::Matrix3d A;
  A.col(0) = x_axis;
  A.col(1) = z.cross(x_axis);
  A.col(2) = z;
  const Eigen::Matrix3d K_inv = K.inverse();

  std::vector<int> index;
  std::vector<Eigen::Vector3d> P, g;
  for (size_t i = 0; i < points_w.size(); ++i) {
    if (!points_w[i].allFinite() || !pixels[i].allFinite()) continue;
    index.push_back(static_cast<int>(i));
    P.push_back(points_w[i]);
    g.push_back((A.transpose() * (K_inv * pixels[i].homogeneous())).normalized());
  }
  const int n = static_cast<int>(P.size());
  const int min_inliers = std::max(3, config.min_inliers);
  if (n < min_inliers) return result;

  const double th2 = config.reprojection_error * config.reprojection_error;
  auto inliersOf = [&](const SE3& T, std::vector<int>* inl) {
    inl->clear();
    for (int i = 0; i < n; ++i) {
      const Eigen::Vector3d p_c = T * P[i];
      if (p_c.z() <= 1e-6) continue;
      const Eigen::Vector2d u = (K * p_c).hnormalized();
      if ((u - pixels[index[i]]).squaredNorm() < th2) inl->push_back(i);
    }
  };
  // Least squares over a set of correspondences (x with a free norm of the
  // yaw vector, normalised afterwards).
  auto refit = [&](const std::vector<int>& set, Eigen::Matrix<double, 5, 1>* x) {
    Eigen::Matrix<double, 5, 5> H = Eigen::Matrix<double, 5, 5>::Zero();
    Eigen::Matrix<double, 5, 1> b = Eigen::Matrix<double, 5, 1>::Zero();
    Eigen::Matrix<double, 3, 6> rows;
    for (int i : set) {
      gravityRows(g[i], P[i], &rows);
      H += rows.leftCols<5>().transpose() * rows.leftCols<5>();
      b -= rows.leftCols<5>().transpose() * rows.col(5);
    }
    const Eigen::Matrix<double, 5, 1> sol = H.ldlt().solve(b);
    if (!sol.allFinite() || std::hypot(sol(0), sol(1)) < 1e-9) return false;
    *x = sol;
    return true;
  };

  std::mt19937 rng(seed);
  std::vector<int> best_inliers, inl;
  SE3 best_T = SE3::Identity();
  int iterations = config.ransac_iterations;
  Eigen::Matrix<double, 3, 6> r1, r2;
  Eigen::Matrix<double, 4, 6> stacked;
  Eigen::Matrix<double, 5, 1> sols[2];
  for (int it = 0; it < iterations; ++it) {
    const int a = static_cast<int>(rng() % n);
    int b = static_cast<int>(rng() % (n - 1));
    if (b >= a) ++b;
    gravityRows(g[a], P[a], &r1);
    gravityRows(g[b], P[b], &r2);
    independentRows(r1, g[a], &stacked, 0);
    independentRows(r2, g[b], &stacked, 2);
    const int k = solveTwoPoint(stacked, sols);
    for (int s = 0; s < k; ++s) {
      const SE3 T = gravityPose(A, sols[s]);
      inliersOf(T, &inl);
      if (inl.size() > best_inliers.size()) {
        best_inliers = inl;
        best_T = T;
        // Adaptive iteration count for a 2-point sample.
        const double w = static_cast<double>(inl.size()) / n;
        const double denom = std::log(std::max(1e-12, 1.0 - w * w));
        if (denom < 0.0) {
          const double needed = std::log(1.0 - config.confidence) / denom;
          iterations = std::min(iterations, std::max(it + 1, static_cast<int>(std::ceil(needed))));
        }
      }
    }
  }
  if (static_cast<int>(best_inliers.size()) < min_inliers) return result;
  // Refit on the inliers, twice (the inlier set may grow).
  for (int round = 0; round < 2; ++round) {
    Eigen::Matrix<double, 5, 1> x;
    if (!refit(best_inliers, &x)) break;
    const SE3 T = gravityPose(A, x);
    inliersOf(T, &inl);
    if (inl.size() < best_inliers.size()) break;
    best_inliers = inl;
    best_T = T;
  }
  if (static_cast<int>(best_inliers.size()) < min_inliers) return result;
  result.success = true;
  result.T_c_w = best_T;
  for (int i : best_inliers) result.inliers.push_back(index[i]);
  return result;
}

}  // namespace ecar
