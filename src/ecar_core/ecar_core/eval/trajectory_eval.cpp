#include "ecar_core/eval/trajectory_eval.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

#include <Eigen/Geometry>
#include <Eigen/SVD>

#include "ecar_core/common/error.h"

namespace ecar {

namespace {

constexpr double kRadToDeg = 180.0 / M_PI;

std::string formatNumber(double value) {
  std::ostringstream out;
  out << value;
  return out.str();
}

// Rotation angle in degrees, accurate for small angles too (acos of the trace
// loses half the digits near identity, and RPE rotations are small).
double rotationAngleDeg(const Eigen::Matrix3d& R) {
  const Eigen::Quaterniond q(R);
  return 2.0 * std::atan2(q.vec().norm(), std::abs(q.w())) * kRadToDeg;
}

// True when the points all lie within a relative 1e-12 of their mean.
bool allCoincident(double variance, const Eigen::Vector3d& mean) {
  const double tolerance = 1e-12 * std::max(1.0, mean.norm());
  return std::sqrt(variance) <= tolerance;
}

// Matches est to gt by timestamp and checks there are enough matches for the
// requested alignment. `what` ("ATE", "RPE") prefixes the error text.
std::vector<std::pair<size_t, size_t>> matchPoses(const Trajectory& gt, const Trajectory& est,
                                                  const EvalOptions& options,
                                                  const std::string& what) {
  const auto matches = associate(timestamps(gt), timestamps(est), options.max_dt);
  const size_t needed = options.alignment == Alignment::kNone ? 1 : 3;
  if (matches.size() >= needed) return matches;
  const std::string purpose = options.alignment == Alignment::kNone ? "" : " to align";
  if (std::min(gt.size(), est.size()) < needed) {
    throw Error(what + ": need at least " + std::to_string(needed) + " poses" + purpose + ", got " +
                std::to_string(gt.size()) + " in the ground truth and " +
                std::to_string(est.size()) + " in the estimate");
  }
  throw Error(what + ": only " + std::to_string(matches.size()) + " of " +
              std::to_string(est.size()) + " estimated poses have a ground-truth pose (of " +
              std::to_string(gt.size()) + ") within max_dt = " + formatNumber(options.max_dt) +
              " s; need at least " + std::to_string(needed) + purpose +
              " (do the timestamps use the same clock?)");
}

// S_w_v fitted on the matched positions (identity for kNone).
Sim3 fitAlignment(const Trajectory& gt, const Trajectory& est,
                  const std::vector<std::pair<size_t, size_t>>& matches, Alignment alignment) {
  if (alignment == Alignment::kNone) return Sim3();
  std::vector<Eigen::Vector3d> p_v, p_w;
  p_v.reserve(matches.size());
  p_w.reserve(matches.size());
  for (const auto& [i, j] : matches) {
    p_w.push_back(gt[i].T_w_c.translation());
    p_v.push_back(est[j].T_w_c.translation());
  }
  try {
    return umeyama(p_v, p_w, alignment == Alignment::kSim3);
  } catch (const Error& e) {
    throw Error(
        "aligning the estimate onto the ground truth: " + std::string(e.what()) +
        " (evaluate without alignment if the estimate is already in the ground-truth frame)");
  }
}

}  // namespace

std::vector<double> rotationSpreadDeg(const std::vector<Eigen::Matrix3d>& rotations) {
  std::vector<double> out;
  if (rotations.empty()) return out;
  Eigen::Matrix3d sum = Eigen::Matrix3d::Zero();
  for (const auto& R : rotations) sum += R;
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(sum, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d D = Eigen::Matrix3d::Identity();
  D(2, 2) = (svd.matrixU() * svd.matrixV().transpose()).determinant() < 0 ? -1.0 : 1.0;
  const Eigen::Matrix3d mean = svd.matrixU() * D * svd.matrixV().transpose();
  for (const auto& R : rotations) {
    out.push_back(Eigen::AngleAxisd(R * mean.transpose()).angle() * 180.0 / M_PI);
  }
  return out;
}

Sim3 umeyama(const std::vector<Eigen::Vector3d>& src, const std::vector<Eigen::Vector3d>& dst,
             bool with_scale) {
  if (src.size() != dst.size()) {
    throw Error("umeyama: src has " + std::to_string(src.size()) + " points but dst has " +
                std::to_string(dst.size()));
  }
  if (src.size() < 3) {
    throw Error("umeyama: need at least 3 point pairs, got " + std::to_string(src.size()));
  }
  const size_t n = src.size();
  Eigen::Vector3d mu_src = Eigen::Vector3d::Zero(), mu_dst = Eigen::Vector3d::Zero();
  for (size_t i = 0; i < n; ++i) {
    if (!src[i].allFinite() || !dst[i].allFinite()) {
      throw Error("umeyama: point pair " + std::to_string(i) + " is not finite");
    }
    mu_src += src[i];
    mu_dst += dst[i];
  }
  mu_src /= static_cast<double>(n);
  mu_dst /= static_cast<double>(n);

  // Cross-covariance Sigma = 1/n sum (dst - mu_dst)(src - mu_src)^T (Umeyama eq. 38).
  Eigen::Matrix3d sigma = Eigen::Matrix3d::Zero();
  double var_src = 0.0, var_dst = 0.0;
  for (size_t i = 0; i < n; ++i) {
    const Eigen::Vector3d d_src = src[i] - mu_src;
    const Eigen::Vector3d d_dst = dst[i] - mu_dst;
    sigma += d_dst * d_src.transpose();
    var_src += d_src.squaredNorm();
    var_dst += d_dst.squaredNorm();
  }
  sigma /= static_cast<double>(n);
  var_src /= static_cast<double>(n);
  var_dst /= static_cast<double>(n);
  if (allCoincident(var_src, mu_src))
    throw Error("umeyama: degenerate input, all src points coincide");
  if (allCoincident(var_dst, mu_dst))
    throw Error("umeyama: degenerate input, all dst points coincide");

  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(sigma, Eigen::ComputeFullU | Eigen::ComputeFullV);
  const Eigen::Vector3d sv = svd.singularValues();
  // The rotation is unique only when rank(Sigma) >= 2 (Umeyama, Lemma).
  if (!(sv(1) > 1e-10 * sv(0))) {
    throw Error(
        "umeyama: degenerate input, the points are collinear so the rotation is not unique");
  }
  Eigen::Vector3d s_diag(1.0, 1.0, 1.0);
  if (svd.matrixU().determinant() * svd.matrixV().determinant() < 0.0) s_diag(2) = -1.0;

  Sim3 S;
  S.R = svd.matrixU() * s_diag.asDiagonal() * svd.matrixV().transpose();
  S.scale = with_scale ? sv.dot(s_diag) / var_src : 1.0;
  S.t = mu_dst - S.scale * (S.R * mu_src);
  return S;
}

void validate(const EvalOptions& options) {
  if (options.alignment != Alignment::kNone && options.alignment != Alignment::kSE3 &&
      options.alignment != Alignment::kSim3) {
    throw Error("EvalOptions.alignment has an invalid value");
  }
  if (!std::isfinite(options.max_dt) || options.max_dt < 0.0) {
    throw Error("EvalOptions.max_dt must be finite and >= 0 (seconds), got " +
                formatNumber(options.max_dt));
  }
  if (!std::isfinite(options.rpe_delta) || options.rpe_delta <= 0.0) {
    throw Error("EvalOptions.rpe_delta must be finite and > 0, got " +
                formatNumber(options.rpe_delta));
  }
  switch (options.rpe_unit) {
    case EvalOptions::kFrames:
      if (options.rpe_delta != std::floor(options.rpe_delta)) {
        throw Error("EvalOptions.rpe_delta must be a whole number of frames, got " +
                    formatNumber(options.rpe_delta));
      }
      break;
    case EvalOptions::kSeconds:
    case EvalOptions::kMeters:
      break;
    default:
      throw Error("EvalOptions.rpe_unit has an invalid value");
  }
}

ErrorStats computeStats(const std::vector<double>& errors) {
  ErrorStats stats;
  stats.n = errors.size();
  if (errors.empty()) {
    const double nan = std::numeric_limits<double>::quiet_NaN();
    stats.rmse = stats.mean = stats.median = stats.std = stats.min = stats.max = nan;
    return stats;
  }
  std::vector<double> sorted = errors;
  std::sort(sorted.begin(), sorted.end());
  const double n = static_cast<double>(sorted.size());
  double sum = 0.0, sum_sq = 0.0;
  for (const double e : sorted) {
    sum += e;
    sum_sq += e * e;
  }
  stats.mean = sum / n;
  stats.rmse = std::sqrt(sum_sq / n);
  double sum_dev_sq = 0.0;
  for (const double e : sorted) sum_dev_sq += (e - stats.mean) * (e - stats.mean);
  stats.std = std::sqrt(sum_dev_sq / n);
  const size_t mid = sorted.size() / 2;
  stats.median = sorted.size() % 2 == 1 ? sorted[mid] : 0.5 * (sorted[mid - 1] + sorted[mid]);
  stats.min = sorted.front();
  stats.max = sorted.back();
  return stats;
}

AteResult computeAte(const Trajectory& gt, const Trajectory& est, const EvalOptions& options) {
  validate(options);
  AteResult result;
  result.matches = matchPoses(gt, est, options, "ATE");
  result.alignment = fitAlignment(gt, est, result.matches, options.alignment);
  result.errors.reserve(result.matches.size());
  for (const auto& [i, j] : result.matches) {
    const Eigen::Vector3d p_w = gt[i].T_w_c.translation();
    const Eigen::Vector3d p_w_est = result.alignment * Eigen::Vector3d(est[j].T_w_c.translation());
    result.errors.push_back((p_w - p_w_est).norm());
  }
  result.translation = computeStats(result.errors);
  return result;
}

RpeResult computeRpe(const Trajectory& gt, const Trajectory& est, const EvalOptions& options) {
  validate(options);
  auto matches = matchPoses(gt, est, options, "RPE");
  const double scale = options.alignment == Alignment::kSim3
                           ? fitAlignment(gt, est, matches, options.alignment).scale
                           : 1.0;
  std::stable_sort(matches.begin(), matches.end(), [&gt](const auto& a, const auto& b) {
    return gt[a.first].timestamp < gt[b.first].timestamp;
  });

  // Matched poses in gt time order, and the coordinate rpe_delta is measured in.
  const size_t m = matches.size();
  std::vector<SE3> T_w_c(m), T_v_c(m);
  std::vector<double> key(m);
  for (size_t k = 0; k < m; ++k) {
    const StampedPose& g = gt[matches[k].first];
    T_w_c[k] = g.T_w_c;
    T_v_c[k] = est[matches[k].second].T_w_c;
    T_v_c[k].translation() *= scale;
    switch (options.rpe_unit) {
      case EvalOptions::kFrames:
        key[k] = static_cast<double>(k);
        break;
      case EvalOptions::kSeconds:
        key[k] = g.timestamp;
        break;
      case EvalOptions::kMeters:
        key[k] = k == 0 ? 0.0
                        : key[k - 1] + (T_w_c[k].translation() - T_w_c[k - 1].translation()).norm();
        break;
    }
  }
  // Slack so that stamps exactly rpe_delta apart are not lost to rounding.
  const double slack = options.rpe_unit == EvalOptions::kSeconds  ? 1e-6
                       : options.rpe_unit == EvalOptions::kMeters ? 1e-9
                                                                  : 0.0;

  std::vector<double> trans_errors, rot_errors_deg;
  for (size_t a = 0; a < m; ++a) {
    const auto it =
        std::lower_bound(key.begin() + a + 1, key.end(), key[a] + options.rpe_delta - slack);
    if (it == key.end()) break;  // keys are sorted: no later start has a partner either
    const size_t b = static_cast<size_t>(it - key.begin());
    const SE3 gt_rel = T_w_c[a].inverse() * T_w_c[b];
    const SE3 est_rel = T_v_c[a].inverse() * T_v_c[b];
    const SE3 E = gt_rel.inverse() * est_rel;
    trans_errors.push_back(E.translation().norm());
    rot_errors_deg.push_back(rotationAngleDeg(E.linear()));
  }
  RpeResult result;
  result.translation = computeStats(trans_errors);
  result.rotation_deg = computeStats(rot_errors_deg);
  return result;
}

Trajectory applyAlignment(const Trajectory& traj, const Sim3& S) {
  Trajectory out;
  out.reserve(traj.size());
  for (const StampedPose& pose : traj) {
    StampedPose mapped;
    mapped.timestamp = pose.timestamp;
    mapped.T_w_c = S.transformPose(pose.T_w_c);
    out.push_back(mapped);
  }
  return out;
}

std::string toString(Alignment alignment) {
  switch (alignment) {
    case Alignment::kNone:
      return "none";
    case Alignment::kSE3:
      return "se3";
    case Alignment::kSim3:
      return "sim3";
  }
  return "invalid";
}

std::string toString(EvalOptions::RpeUnit unit) {
  switch (unit) {
    case EvalOptions::kFrames:
      return "frames";
    case EvalOptions::kSeconds:
      return "seconds";
    case EvalOptions::kMeters:
      return "meters";
  }
  return "invalid";
}

namespace {
nlohmann::json numberOrNull(double value) {
  return std::isfinite(value) ? nlohmann::json(value) : nlohmann::json(nullptr);
}
}  // namespace

double percentile(std::vector<double> values, double p) {
  if (values.empty()) return 0.0;
  std::sort(values.begin(), values.end());
  const double clamped = std::clamp(p, 0.0, 1.0);
  return values[static_cast<size_t>(clamped * (values.size() - 1) + 0.5)];
}

nlohmann::json toJson(const ErrorStats& stats) {
  return {{"n", stats.n},
          {"rmse", numberOrNull(stats.rmse)},
          {"mean", numberOrNull(stats.mean)},
          {"median", numberOrNull(stats.median)},
          {"std", numberOrNull(stats.std)},
          {"min", numberOrNull(stats.min)},
          {"max", numberOrNull(stats.max)}};
}

nlohmann::json toJson(const Sim3& S) {
  nlohmann::json rotation = nlohmann::json::array();
  for (int r = 0; r < 3; ++r) rotation.push_back({S.R(r, 0), S.R(r, 1), S.R(r, 2)});
  return {{"scale", S.scale}, {"rotation", rotation}, {"translation", {S.t.x(), S.t.y(), S.t.z()}}};
}

nlohmann::json toJson(const EvalOptions& options) {
  return {{"alignment", toString(options.alignment)},
          {"max_dt", options.max_dt},
          {"rpe_delta", options.rpe_delta},
          {"rpe_unit", toString(options.rpe_unit)}};
}

nlohmann::json toJson(const AteResult& ate, bool with_errors) {
  nlohmann::json j = {{"matched", ate.matches.size()},
                      {"translation", toJson(ate.translation)},
                      {"alignment", toJson(ate.alignment)}};
  if (with_errors) j["errors"] = ate.errors;
  return j;
}

nlohmann::json toJson(const RpeResult& rpe) {
  return {{"translation", toJson(rpe.translation)}, {"rotation_deg", toJson(rpe.rotation_deg)}};
}

}  // namespace ecar
