#include "ecar_core/slam/seam_refit.h"

#include <cmath>
#include <limits>
#include <memory>
#include <vector>

#include <ceres/ceres.h>
#include <ceres/rotation.h>

#include "ecar_core/slam/pose_graph.h"

namespace ecar {
namespace {

/// One cross observation: pixel uv of a keyframe (R_c_w, t_c_w, K) seeing a
/// world point p. `moved_camera`: the keyframe moves with D (the point stays),
/// otherwise the point moves with D (the keyframe stays).
struct CrossObservation {
  Eigen::Matrix3d R;
  Eigen::Vector3d t, p;
  Intrinsics K;
  Eigen::Vector2d uv;
  double inv_sigma2 = 1.0;
  bool moved_camera = false;
};

/// D as [angle-axis (3), translation (3)] and [log scale] about the pivot c:
/// D(x) = c + s R (x - c) + t. A moved camera sees p as its old self saw
/// D^-1(p), a fixed camera sees the moved point D(p).
struct CrossReprojection {
  CrossReprojection(const CrossObservation& o, const Eigen::Vector3d& c) : o_(o), c_(c) {}

  template <typename T>
  bool operator()(const T* d, const T* log_s, T* residual) const {
    using V3 = Eigen::Matrix<T, 3, 1>;
    const V3 c = c_.cast<T>(), t(d[3], d[4], d[5]), p = o_.p.cast<T>();
    const T s = ceres::exp(log_s[0]);
    V3 q;
    if (o_.moved_camera) {
      const V3 x = (p - c - t) / s;
      const T minus_w[3] = {-d[0], -d[1], -d[2]};
      ceres::AngleAxisRotatePoint(minus_w, x.data(), q.data());
      q += c;
    } else {
      const V3 x = p - c;
      ceres::AngleAxisRotatePoint(d, x.data(), q.data());
      q = c + s * q + t;
    }
    const V3 x_c = o_.R.cast<T>() * q + o_.t.cast<T>();
    const T sqrt_info = T(std::sqrt(o_.inv_sigma2));
    residual[0] = sqrt_info * (T(o_.K.fx) * x_c[0] / x_c[2] + T(o_.K.cx) - T(o_.uv.x()));
    residual[1] = sqrt_info * (T(o_.K.fy) * x_c[1] / x_c[2] + T(o_.K.cy) - T(o_.uv.y()));
    return true;
  }

  CrossObservation o_;
  Eigen::Vector3d c_;
};

Sim3 similarityFrom(const double d[7], const Eigen::Vector3d& c) {
  // D(x) = s R x + (c - s R c + t)
  Sim3 D;
  D.scale = std::exp(d[6]);
  D.R = expSO3(Eigen::Vector3d(d[0], d[1], d[2]));
  D.t = c - D.scale * (D.R * c) + Eigen::Vector3d(d[3], d[4], d[5]);
  return D;
}

/// Squared, information-weighted reprojection error of o under D (D_inverse
/// its inverse; infinite behind the camera).
double chi2(const CrossObservation& o, const Sim3& D, const Sim3& D_inverse) {
  const Eigen::Vector3d x = o.R * (o.moved_camera ? D_inverse * o.p : D * o.p) + o.t;
  if (x.z() <= 0) return std::numeric_limits<double>::infinity();
  const Eigen::Vector2d e(o.K.fx * x.x() / x.z() + o.K.cx - o.uv.x(),
                          o.K.fy * x.y() / x.z() + o.K.cy - o.uv.y());
  return e.squaredNorm() * o.inv_sigma2;
}

}  // namespace

SeamRefit refitSeam(Map* map, const std::unordered_set<KeyFrameId>& moved_keyframes,
                    const std::unordered_set<MapPointId>& moved_points, bool fix_scale,
                    const SeamRefitConfig& config) {
  SeamRefit out;
  std::vector<CrossObservation> obs;
  std::unordered_set<KeyFrameId> seeing;
  Eigen::Vector3d pivot = Eigen::Vector3d::Zero();
  for (const MapPointId pid : map->pointIds()) {
    const MapPoint* p = map->point(pid);
    const bool point_moved = moved_points.count(pid) > 0;
    for (const auto& [kid, idx] : p->observations) {
      const bool camera_moved = moved_keyframes.count(kid) > 0;
      if (camera_moved == point_moved) continue;  // D leaves this one as it is
      const KeyFrame* k = map->keyframe(kid);
      if (!k) continue;
      CrossObservation o;
      o.R = k->T_c_w.linear();
      o.t = k->T_c_w.translation();
      o.p = p->p_w;
      o.K = k->K();
      o.uv = k->features.undistorted[idx];
      o.inv_sigma2 = map->scale().inv_sigma2[k->features.keypoints[idx].octave];
      o.moved_camera = camera_moved;
      obs.push_back(o);
      pivot += p->p_w;
      seeing.insert(kid);
    }
  }
  out.observations = static_cast<int>(obs.size());
  if (obs.size() < static_cast<size_t>(config.min_inliers) ||
      static_cast<int>(seeing.size()) < config.min_keyframes) {
    return out;
  }
  pivot /= static_cast<double>(obs.size());

  double d[7] = {0, 0, 0, 0, 0, 0, 0};
  std::vector<bool> inlier(obs.size(), true);
  const auto rms = [&](const double* at) {
    const Sim3 D = similarityFrom(at, pivot), D_inverse = D.inverse();
    double sum = 0.0;
    int n = 0;
    for (size_t i = 0; i < obs.size(); ++i) {
      if (!inlier[i]) continue;
      sum += chi2(obs[i], D, D_inverse) / obs[i].inv_sigma2;
      ++n;
    }
    return n ? std::sqrt(sum / n) : 0.0;
  };
  const auto classify = [&]() {
    const Sim3 D = similarityFrom(d, pivot), D_inverse = D.inverse();
    int n = 0;
    for (size_t i = 0; i < obs.size(); ++i) {
      inlier[i] = chi2(obs[i], D, D_inverse) < config.chi2_threshold;
      n += inlier[i];
    }
    return n;
  };
  classify();
  for (int round = 0; round < config.rounds; ++round) {
    ceres::Problem problem;
    for (size_t i = 0; i < obs.size(); ++i) {
      if (round > 0 && !inlier[i]) continue;
      problem.AddResidualBlock(
          new ceres::AutoDiffCostFunction<CrossReprojection, 2, 6, 1>(
              new CrossReprojection(obs[i], pivot)),
          round + 1 < config.rounds ? new ceres::HuberLoss(config.huber_delta) : nullptr, d, d + 6);
    }
    if (problem.NumResidualBlocks() == 0) return out;
    if (fix_scale) problem.SetParameterBlockConstant(d + 6);
    ceres::Solver::Options options;
    options.linear_solver_type = ceres::DENSE_QR;
    options.max_num_iterations = config.iterations;
    options.num_threads = 1;
    ceres::Solver::Summary summary;
    ceres::Solve(options, &problem, &summary);
    out.inliers = classify();
  }
  out.D = similarityFrom(d, pivot);
  // Judged on the final inliers, before and after.
  const double identity[7] = {0, 0, 0, 0, 0, 0, 0};
  out.rms_after_px = rms(d);
  out.rms_before_px = rms(identity);
  if (out.inliers < config.min_inliers ||
      rotationAngle(out.D.R) * 180.0 / M_PI > config.max_rotation_deg ||
      std::abs(out.D.scale - 1.0) > config.max_scale_change ||
      out.rms_after_px >= out.rms_before_px) {
    return out;
  }
  const Sim3 D_inverse = out.D.inverse();
  for (const KeyFrameId kid : moved_keyframes) {
    KeyFrame* k = map->mutableKeyFrame(kid);
    if (k) k->T_c_w = metricPose(similarityOf(k->T_c_w) * D_inverse);
  }
  for (const MapPointId pid : moved_points) {
    MapPoint* p = map->mutablePoint(pid);
    if (!p) continue;
    p->p_w = out.D * p->p_w;
    ++p->version;
  }
  map->bumpRevision();
  out.applied = true;
  return out;
}

}  // namespace ecar
