#include "ecar_core/slam/sim3_solver.h"

#include <algorithm>
#include <cmath>
#include <random>

#include <Eigen/Geometry>

namespace ecar {

Sim3 fitSim3(const std::vector<Eigen::Vector3d>& source, const std::vector<Eigen::Vector3d>& target,
             bool fix_scale) {
  const size_t n = std::min(source.size(), target.size());
  Eigen::Matrix3Xd src(3, n), dst(3, n);
  for (size_t i = 0; i < n; ++i) {
    src.col(static_cast<Eigen::Index>(i)) = source[i];
    dst.col(static_cast<Eigen::Index>(i)) = target[i];
  }
  const Eigen::Matrix4d M = Eigen::umeyama(src, dst, !fix_scale);
  Sim3 S;
  const Eigen::Matrix3d sR = M.topLeftCorner<3, 3>();
  S.scale = std::cbrt(sR.determinant());
  S.R = sR / S.scale;
  S.t = M.topRightCorner<3, 1>();
  return S;
}

namespace {

bool usable(const PointPair& p) {
  return p.source.allFinite() && p.target.allFinite() && p.tolerance > 0.0 &&
         std::isfinite(p.tolerance);
}

// Inliers of S; returns their count.
int countInliers(const std::vector<PointPair>& pairs, const Sim3& S, std::vector<bool>* inliers) {
  int n = 0;
  inliers->assign(pairs.size(), false);
  for (size_t i = 0; i < pairs.size(); ++i) {
    if (!usable(pairs[i])) continue;
    if ((S * pairs[i].source - pairs[i].target).squaredNorm() <=
        pairs[i].tolerance * pairs[i].tolerance) {
      (*inliers)[i] = true;
      ++n;
    }
  }
  return n;
}

// Three points spanning a triangle (not nearly on one line).
bool wellSpread(const Eigen::Vector3d& a, const Eigen::Vector3d& b, const Eigen::Vector3d& c) {
  const Eigen::Vector3d u = b - a, v = c - a;
  return u.cross(v).norm() > 1e-3 * u.norm() * v.norm() && u.norm() > 1e-9 && v.norm() > 1e-9;
}

bool validSim3(const Sim3& S) {
  return S.R.allFinite() && S.t.allFinite() && std::isfinite(S.scale) && S.scale > 1e-6 &&
         S.scale < 1e6;
}

}  // namespace

Sim3Estimate estimateSim3(const std::vector<PointPair>& pairs, const Sim3EstimateConfig& config) {
  Sim3Estimate out;
  std::vector<int> candidates;
  for (size_t i = 0; i < pairs.size(); ++i) {
    if (usable(pairs[i])) candidates.push_back(static_cast<int>(i));
  }
  const int need = std::max(3, config.min_inliers);
  if (static_cast<int>(candidates.size()) < need) {
    out.reason =
        std::to_string(candidates.size()) + " usable pairs, " + std::to_string(need) + " needed";
    return out;
  }
  std::mt19937 rng(config.seed);
  std::uniform_int_distribution<size_t> pick(0, candidates.size() - 1);
  std::vector<bool> inliers;
  int best = 0;
  Sim3 best_S;
  std::vector<Eigen::Vector3d> src(3), dst(3);
  for (int it = 0; it < config.iterations; ++it) {
    const int a = candidates[pick(rng)], b = candidates[pick(rng)], c = candidates[pick(rng)];
    if (a == b || a == c || b == c) continue;
    src = {pairs[a].source, pairs[b].source, pairs[c].source};
    dst = {pairs[a].target, pairs[b].target, pairs[c].target};
    if (!wellSpread(src[0], src[1], src[2]) || !wellSpread(dst[0], dst[1], dst[2])) continue;
    const Sim3 S = fitSim3(src, dst, config.fix_scale);
    if (!validSim3(S)) continue;
    const int n = countInliers(pairs, S, &inliers);
    if (n > best) {
      best = n;
      best_S = S;
    }
  }
  if (best < need) {
    out.reason = "best hypothesis has " + std::to_string(best) + " inliers, " +
                 std::to_string(need) + " needed";
    return out;
  }
  // Refit on the inliers, twice (the refit may gain a few).
  Sim3 S = best_S;
  for (int round = 0; round < 2; ++round) {
    countInliers(pairs, S, &inliers);
    src.clear();
    dst.clear();
    for (size_t i = 0; i < pairs.size(); ++i) {
      if (!inliers[i]) continue;
      src.push_back(pairs[i].source);
      dst.push_back(pairs[i].target);
    }
    const Sim3 refit = fitSim3(src, dst, config.fix_scale);
    if (!validSim3(refit)) break;
    std::vector<bool> refit_inliers;
    if (countInliers(pairs, refit, &refit_inliers) < static_cast<int>(src.size())) break;
    S = refit;
  }
  out.num_inliers = countInliers(pairs, S, &out.inliers);
  out.S = S;
  out.success = out.num_inliers >= need;
  if (!out.success) out.reason = "refit kept " + std::to_string(out.num_inliers) + " inliers";
  return out;
}

}  // namespace ecar
