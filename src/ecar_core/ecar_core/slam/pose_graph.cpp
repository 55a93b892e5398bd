#include "ecar_core/slam/pose_graph.h"

#include <algorithm>
#include <array>
#include <cmath>

#include <ceres/ceres.h>
#include <ceres/rotation.h>

namespace ecar {
namespace {

/// Residual of one edge on nodes [aa, t] + [log s] each.
struct SimilarityEdgeError {
  SimilarityEdgeError(const Sim3& measured, double weight)
      : R_m_(measured.R), t_m_(measured.t), log_s_m_(std::log(measured.scale)), w_(weight) {}

  template <typename T>
  bool operator()(const T* pose_i, const T* log_s_i, const T* pose_j, const T* log_s_j,
                  T* residual) const {
    T R_i[9], R_j[9];  // column major
    ceres::AngleAxisToRotationMatrix(pose_i, R_i);
    ceres::AngleAxisToRotationMatrix(pose_j, R_j);
    const auto Ri = [&](int r, int c) { return R_i[c * 3 + r]; };
    const auto Rj = [&](int r, int c) { return R_j[c * 3 + r]; };
    // R_ij = R_i R_j^T; error E = R_m^T R_ij.
    T R_ij[3][3];
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) {
        R_ij[r][c] = Ri(r, 0) * Rj(c, 0) + Ri(r, 1) * Rj(c, 1) + Ri(r, 2) * Rj(c, 2);
      }
    }
    T E[9];  // column major
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) {
        E[c * 3 + r] =
            T(R_m_(0, r)) * R_ij[0][c] + T(R_m_(1, r)) * R_ij[1][c] + T(R_m_(2, r)) * R_ij[2][c];
      }
    }
    T aa[3];
    ceres::RotationMatrixToAngleAxis(E, aa);
    // t_ij = t_i - s_ij R_ij t_j, s_ij = s_i / s_j.
    const T s_ij = ceres::exp(log_s_i[0] - log_s_j[0]);
    for (int r = 0; r < 3; ++r) {
      const T rotated = R_ij[r][0] * pose_j[3] + R_ij[r][1] * pose_j[4] + R_ij[r][2] * pose_j[5];
      residual[3 + r] = T(w_) * (pose_i[3 + r] - s_ij * rotated - T(t_m_[r]));
      residual[r] = T(w_) * aa[r];
    }
    residual[6] = T(w_) * (log_s_i[0] - log_s_j[0] - T(log_s_m_));
    return true;
  }

  Eigen::Matrix3d R_m_;
  Eigen::Vector3d t_m_;
  double log_s_m_, w_;
};

bool finite(const Sim3& S) {
  return S.R.allFinite() && S.t.allFinite() && std::isfinite(S.scale) && S.scale > 0.0;
}

}  // namespace

Sim3 similarityOf(const SE3& T_c_w) {
  Sim3 S;
  S.R = T_c_w.linear();
  S.t = T_c_w.translation();
  return S;
}

SE3 metricPose(const Sim3& S_c_w) {
  SE3 T = SE3::Identity();
  // Corrections compose similarities (loops, merges, seam refits): a pose
  // leaves as a rotation, whatever rounding the products gathered.
  T.linear() = nearestRotation(S_c_w.R);
  T.translation() = S_c_w.t / S_c_w.scale;
  return T;
}

Sim3 relative(const Sim3& S_a_w, const Sim3& S_b_w) { return S_a_w * S_b_w.inverse(); }

PoseGraphResult optimizePoseGraph(const std::vector<Sim3>& S_c_w, const std::vector<bool>& fixed,
                                  const std::vector<PoseGraphEdge>& edges,
                                  const PoseGraphConfig& config) {
  PoseGraphResult result;
  result.S_c_w = S_c_w;
  const int n = static_cast<int>(S_c_w.size());
  if (n == 0) return result;
  std::vector<std::array<double, 6>> poses(n);
  std::vector<double> log_s(n);
  for (int i = 0; i < n; ++i) {
    if (!finite(S_c_w[i])) return result;
    const Eigen::AngleAxisd aa(S_c_w[i].R);
    Eigen::Map<Eigen::Vector3d>(poses[i].data()) = aa.angle() * aa.axis();
    Eigen::Map<Eigen::Vector3d>(poses[i].data() + 3) = S_c_w[i].t;
    log_s[i] = std::log(S_c_w[i].scale);
  }
  ceres::Problem problem;
  std::vector<bool> used(n, false);
  for (const PoseGraphEdge& e : edges) {
    if (e.from < 0 || e.from >= n || e.to < 0 || e.to >= n || e.from == e.to) continue;
    if (!finite(e.S_from_to) || !(e.weight > 0.0) || !std::isfinite(e.weight)) continue;
    auto* cost = new ceres::AutoDiffCostFunction<SimilarityEdgeError, 7, 6, 1, 6, 1>(
        new SimilarityEdgeError(e.S_from_to, e.weight));
    problem.AddResidualBlock(cost, nullptr, poses[e.from].data(), &log_s[e.from],
                             poses[e.to].data(), &log_s[e.to]);
    used[e.from] = used[e.to] = true;
  }
  bool any_fixed = false;
  for (int i = 0; i < n; ++i)
    any_fixed |= i < static_cast<int>(fixed.size()) && fixed[i] && used[i];
  for (int i = 0; i < n; ++i) {
    if (!used[i]) continue;
    const bool is_fixed =
        (i < static_cast<int>(fixed.size()) && fixed[i]) || (!any_fixed && i == 0);
    if (is_fixed) problem.SetParameterBlockConstant(poses[i].data());
    if (is_fixed || config.fix_scale) problem.SetParameterBlockConstant(&log_s[i]);
  }
  if (problem.NumResidualBlocks() == 0) return result;
  ceres::Solver::Options options;
  options.max_num_iterations = config.iterations;
  options.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
  if (!ceres::IsSparseLinearAlgebraLibraryTypeAvailable(
          options.sparse_linear_algebra_library_type)) {
    options.linear_solver_type = ceres::DENSE_QR;
  }
  options.num_threads = config.threads;
  options.logging_type = ceres::SILENT;
  ceres::Solver::Summary summary;
  ceres::Solve(options, &problem, &summary);
  result.initial_cost = summary.initial_cost;
  result.final_cost = summary.final_cost;
  if (!summary.IsSolutionUsable()) return result;
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector3d w = Eigen::Map<const Eigen::Vector3d>(poses[i].data());
    Sim3 S;
    S.R = expSO3(w);
    S.t = Eigen::Map<const Eigen::Vector3d>(poses[i].data() + 3);
    S.scale = std::exp(log_s[i]);
    if (!finite(S)) return result;
    result.S_c_w[i] = S;
  }
  result.converged = true;
  return result;
}

}  // namespace ecar
