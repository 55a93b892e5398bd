// Benchmark of the Ceres optimisers on synthetic problems the size ORB-SLAM
// meets (one thread unless --threads):
//   ecar_bench_ba [--runs N] [--threads T] [--keyframes K] [--fixed F] [--points P]
//                 [--track L] [--pose-obs M]
// Local BA: K free + F fixed keyframes along a path, P points each seen by up
// to L keyframes (ORB pyramid noise, 5% gross outliers), poses perturbed by
// 5 cm / 0.5 deg and points by 5 cm. Pose optimisation: M observations, 10%
// gross outliers, start 10 cm / 5 deg off. Prints median / p95 wall time.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <random>
#include <string>
#include <vector>

#include <time.h>

#include "ecar_core/common/geometry.h"
#include "ecar_core/eval/trajectory_eval.h"
#include "ecar_core/slam/optimizer.h"

namespace {

using ecar::percentile;

using ecar::BaProblem;
using ecar::SE3;

struct Args {
  int runs = 20, threads = 1, keyframes = 20, fixed = 10, points = 3000, track = 10, pose_obs = 300;
};

constexpr double kWidth = 640.0, kHeight = 480.0;
constexpr double kScaleFactor = 1.2;  // ORB pyramid
constexpr int kLevels = 8;

void usage() {
  std::cerr << "usage: ecar_bench_ba [--runs N] [--threads T] [--keyframes K] [--fixed F] "
               "[--points P] [--track L] [--pose-obs M]\n";
}

ecar::Intrinsics makeK() {
  ecar::Intrinsics K;
  K.fx = K.fy = 500.0;
  K.cx = 320.0;
  K.cy = 240.0;
  return K;
}

Eigen::Vector3d randomUnit(std::mt19937* rng) {
  std::normal_distribution<double> n(0.0, 1.0);
  return Eigen::Vector3d(n(*rng), n(*rng), n(*rng)).normalized();
}

SE3 perturb(const SE3& T_c_w, double trans, double rot_rad, std::mt19937* rng) {
  SE3 T_w_c = T_c_w.inverse();
  T_w_c.linear() = ecar::expSO3(randomUnit(rng) * rot_rad) * T_w_c.linear();
  T_w_c.translation() += randomUnit(rng) * trans;
  return T_w_c.inverse();
}

// A pixel measurement at a random pyramid level: noise and information scale
// with the level as in ORB-SLAM; 5% (or `outlier_ratio`) are moved 20-100 px.
void measure(const Eigen::Vector2d& uv, double outlier_ratio, std::mt19937* rng,
             Eigen::Vector2d* measured, double* inv_sigma2) {
  // ORB-SLAM extracts features per level in proportion to 1 / scale.
  std::vector<double> weights;
  for (int l = 0; l < kLevels; ++l) weights.push_back(std::pow(kScaleFactor, -l));
  std::discrete_distribution<int> level(weights.begin(), weights.end());
  std::normal_distribution<double> noise(0.0, 1.0);
  std::uniform_real_distribution<double> u(0.0, 1.0), gross(20.0, 100.0);
  const double sigma = std::pow(kScaleFactor, level(*rng));
  *inv_sigma2 = 1.0 / (sigma * sigma);
  *measured = uv + sigma * Eigen::Vector2d(noise(*rng), noise(*rng));
  if (u(*rng) < outlier_ratio) {
    const double a = 2.0 * M_PI * u(*rng);
    *measured += gross(*rng) * Eigen::Vector2d(std::cos(a), std::sin(a));
  }
}

bool projectInImage(const ecar::Intrinsics& K, const SE3& T_c_w, const Eigen::Vector3d& p_w,
                    Eigen::Vector2d* uv) {
  const Eigen::Vector3d p_c = T_c_w * p_w;
  if (p_c.z() < 0.5) return false;
  *uv = Eigen::Vector2d(K.fx * p_c.x() / p_c.z() + K.cx, K.fy * p_c.y() / p_c.z() + K.cy);
  return uv->x() >= 0 && uv->y() >= 0 && uv->x() < kWidth && uv->y() < kHeight;
}

// The local window: fixed keyframes first (the older ones), then the free
// ones, 0.3 m apart along a gently curving path.
BaProblem makeLocalWindow(const Args& a, unsigned seed, std::vector<SE3>* truth_out) {
  std::mt19937 rng(seed);
  BaProblem ba;
  const ecar::Intrinsics K = makeK();
  const int nk = a.fixed + a.keyframes;
  std::vector<SE3> truth;
  for (int k = 0; k < nk; ++k) {
    const Eigen::Vector3d eye(0.3 * k, 0.3 * std::sin(0.2 * k), 1.5 + 0.1 * std::cos(0.3 * k));
    const Eigen::Vector3d target = eye + Eigen::Vector3d(2.0 * std::sin(0.1 * k), 10.0, 0.0);
    truth.push_back(ecar::lookAt(eye, target).inverse());
    BaProblem::KeyFrame kf;
    kf.K = K;
    kf.fixed = k < a.fixed;
    kf.T_c_w = kf.fixed ? truth.back() : perturb(truth.back(), 0.05, 0.5 * M_PI / 180.0, &rng);
    ba.keyframes.push_back(kf);
  }
  std::uniform_real_distribution<double> px(-4.0, 0.3 * nk + 4.0), py(4.0, 14.0), pz(-1.5, 4.5);
  std::normal_distribution<double> noise(0.0, 0.05);
  while (static_cast<int>(ba.points.size()) < a.points) {
    const Eigen::Vector3d p_w(px(rng), py(rng), pz(rng));
    std::vector<int> visible;
    std::vector<Eigen::Vector2d> uvs;
    Eigen::Vector2d uv;
    for (int k = 0; k < nk; ++k) {
      if (projectInImage(K, truth[k], p_w, &uv)) {
        visible.push_back(k);
        uvs.push_back(uv);
      }
    }
    if (visible.size() < 2) continue;
    // A track: up to `track` consecutive keyframes among those that see it.
    const int len = std::min<int>(a.track, visible.size());
    const int start = std::uniform_int_distribution<int>(0, visible.size() - len)(rng);
    const int point = static_cast<int>(ba.points.size());
    ba.points.push_back({p_w + Eigen::Vector3d(noise(rng), noise(rng), noise(rng))});
    for (int j = start; j < start + len; ++j) {
      BaProblem::Observation o;
      o.keyframe = visible[j];
      o.point = point;
      measure(uvs[j], 0.05, &rng, &o.uv, &o.inv_sigma2);
      ba.observations.push_back(o);
    }
  }
  *truth_out = truth;
  return ba;
}

// RMS camera-centre error of the free keyframes.
double rmsPositionError(const BaProblem& ba, const std::vector<SE3>& truth) {
  double sum = 0.0;
  int n = 0;
  for (size_t k = 0; k < ba.keyframes.size(); ++k) {
    if (ba.keyframes[k].fixed) continue;
    sum += (ba.keyframes[k].T_c_w.inverse().translation() - truth[k].inverse().translation())
               .squaredNorm();
    ++n;
  }
  return n > 0 ? std::sqrt(sum / n) : 0.0;
}

struct PoseProblem {
  SE3 start;
  std::vector<ecar::PoseObservation> obs;
};

PoseProblem makePoseProblem(int n, unsigned seed) {
  std::mt19937 rng(seed);
  const ecar::Intrinsics K = makeK();
  std::uniform_real_distribution<double> pu(0.0, kWidth), pv(0.0, kHeight), depth(2.0, 15.0);
  const SE3 T_w_c = ecar::lookAt(Eigen::Vector3d(1.0, 2.0, 1.5), Eigen::Vector3d(3.0, 12.0, 1.0));
  PoseProblem problem;
  problem.start = perturb(T_w_c.inverse(), 0.10, 5.0 * M_PI / 180.0, &rng);
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector2d uv(pu(rng), pv(rng));
    ecar::PoseObservation o;
    o.p_w =
        T_w_c * (depth(rng) * Eigen::Vector3d((uv.x() - K.cx) / K.fx, (uv.y() - K.cy) / K.fy, 1.0));
    measure(uv, 0.10, &rng, &o.uv, &o.inv_sigma2);
    problem.obs.push_back(o);
  }
  return problem;
}

// Wall time, and process CPU time (which a loaded machine inflates less).
class Stopwatch {
 public:
  Stopwatch() : wall0_(std::chrono::steady_clock::now()), cpu0_(processCpuMs()) {}
  double wallMs() const {
    return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - wall0_)
        .count();
  }
  double cpuMs() const { return processCpuMs() - cpu0_; }

 private:
  static double processCpuMs() {
    timespec ts;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
    return ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
  }

  std::chrono::steady_clock::time_point wall0_;
  double cpu0_;
};

}  // namespace

int main(int argc, char** argv) {
  Args a;
  for (int i = 1; i < argc; ++i) {
    const std::string k = argv[i];
    if (i + 1 >= argc) {
      usage();
      return 2;
    }
    const int v = std::atoi(argv[++i]);
    if (k == "--runs")
      a.runs = v;
    else if (k == "--threads")
      a.threads = v;
    else if (k == "--keyframes")
      a.keyframes = v;
    else if (k == "--fixed")
      a.fixed = v;
    else if (k == "--points")
      a.points = v;
    else if (k == "--track")
      a.track = v;
    else if (k == "--pose-obs")
      a.pose_obs = v;
    else {
      usage();
      return 2;
    }
  }
  if (a.runs < 1 || a.keyframes < 1 || a.fixed < 0 || a.points < 1 || a.track < 2) {
    usage();
    return 2;
  }

  ecar::BaConfig ba_config;
  ba_config.threads = a.threads;
  std::vector<double> ba_ms, ba_cpu_ms;
  size_t num_obs = 0;
  int outliers = 0;
  double cost_ratio = 0.0, error_before = 0.0, error_after = 0.0;
  for (int run = 0; run < a.runs; ++run) {
    std::vector<SE3> truth;
    BaProblem ba = makeLocalWindow(a, 1000 + run, &truth);
    error_before = rmsPositionError(ba, truth);
    num_obs = ba.observations.size();
    const Stopwatch watch;
    const ecar::BaResult result = ecar::localBundleAdjust(&ba, ba_config);
    ba_ms.push_back(watch.wallMs());
    ba_cpu_ms.push_back(watch.cpuMs());
    outliers = result.num_outliers;
    cost_ratio = result.final_cost / std::max(1e-12, result.initial_cost);
    error_after = rmsPositionError(ba, truth);
    if (!result.converged) std::cerr << "run " << run << ": local BA did not converge\n";
  }
  std::printf(
      "local BA: %d free + %d fixed keyframes, %d points, %zu observations, %d thread(s)\n"
      "  wall median %.1f ms  p95 %.1f ms  min %.1f ms; cpu median %.1f ms  p95 %.1f ms\n"
      "  (%d runs; last: %d outliers, cost x%.4f, keyframe error %.1f -> %.1f mm rms)\n",
      a.keyframes, a.fixed, a.points, num_obs, a.threads, percentile(ba_ms, 0.5),
      percentile(ba_ms, 0.95), percentile(ba_ms, 0.0), percentile(ba_cpu_ms, 0.5),
      percentile(ba_cpu_ms, 0.95), a.runs, outliers, cost_ratio, 1e3 * error_before,
      1e3 * error_after);

  const int pose_runs = 10 * a.runs;
  std::vector<double> pose_ms, pose_cpu_ms;
  int inliers = 0;
  for (int run = 0; run < pose_runs; ++run) {
    const PoseProblem problem = makePoseProblem(a.pose_obs, 2000 + run);
    SE3 T = problem.start;
    std::vector<bool> flags;
    const Stopwatch watch;
    const ecar::PoseOptimizerResult result = ecar::optimizePose(makeK(), problem.obs, &T, &flags);
    pose_ms.push_back(watch.wallMs());
    pose_cpu_ms.push_back(watch.cpuMs());
    inliers = result.num_inliers;
    if (!result.success) std::cerr << "run " << run << ": pose optimisation failed\n";
  }
  std::printf(
      "pose optimisation: %d observations\n"
      "  wall median %.2f ms  p95 %.2f ms  min %.2f ms; cpu median %.2f ms  p95 %.2f ms\n"
      "  (%d runs; last: %d inliers)\n",
      a.pose_obs, percentile(pose_ms, 0.5), percentile(pose_ms, 0.95), percentile(pose_ms, 0.0),
      percentile(pose_cpu_ms, 0.5), percentile(pose_cpu_ms, 0.95), pose_runs, inliers);
  return 0;
}
