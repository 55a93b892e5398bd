#include "ecar_core/slam/two_view.h"
#include "ecar_core/slam/pnp.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <random>
#include <vector>

#include <gtest/gtest.h>

namespace ecar {
namespace {

constexpr double kWidth = 640.0;
constexpr double kHeight = 480.0;
constexpr double kRadToDeg = 180.0 / M_PI;

Eigen::Matrix3d intrinsics() {
  Eigen::Matrix3d K;
  K << 500.0, 0.0, 320.0, 0.0, 500.0, 240.0, 0.0, 0.0, 1.0;
  return K;
}

bool inImage(const Eigen::Vector2d& u) {
  return u.x() >= 0.0 && u.x() < kWidth && u.y() >= 0.0 && u.y() < kHeight;
}

/// Pose T_c2_c1 of a second camera whose centre is at c2_c1 (in camera 1
/// coordinates), rotated by the axis-angle w.
SE3 secondCamera(const Eigen::Vector3d& c2_c1, const Eigen::Vector3d& w) {
  SE3 T_c1_c2 = SE3::Identity();
  T_c1_c2.linear() = expSO3(w);
  T_c1_c2.translation() = c2_c1;
  return T_c1_c2.inverse();
}

/// Two views of points_c1 with known motion, pixel noise and a fraction of
/// outliers (random pixels in image 2).
struct Scene {
  SE3 T_c2_c1 = SE3::Identity();
  std::vector<Eigen::Vector3d> points_c1;
  std::vector<Eigen::Vector2d> pts1, pts2;
  std::vector<bool> outlier;
};

enum class Structure { kGeneral, kFloor };

/// Points seen by both cameras: kGeneral at depth 2-8 m over the whole image,
/// kFloor on a floor plane 1.5 m below camera 1, which looks 20 deg down.
Scene makeScene(const SE3& T_c2_c1, Structure structure, int n, double noise_px,
                double outlier_ratio, std::mt19937* rng, double min_depth = 2.0,
                double max_depth = 8.0) {
  const Eigen::Matrix3d K = intrinsics();
  std::uniform_real_distribution<double> ux(0.0, kWidth), uy(0.0, kHeight);
  std::uniform_real_distribution<double> depth(min_depth, max_depth), unit(0.0, 1.0);
  std::normal_distribution<double> noise(0.0, noise_px);
  // Floor: points with (R_tilt p).y == 1.5, camera y pointing down.
  const Eigen::Matrix3d R_tilt = expSO3(Eigen::Vector3d(-20.0 / kRadToDeg, 0.0, 0.0));
  const Eigen::Vector3d floor_normal_c1 = R_tilt.transpose() * Eigen::Vector3d::UnitY();
  Scene s;
  s.T_c2_c1 = T_c2_c1;
  while (static_cast<int>(s.points_c1.size()) < n) {
    const Eigen::Vector3d ray = K.inverse() * Eigen::Vector3d(ux(*rng), uy(*rng), 1.0);
    Eigen::Vector3d p_c1;
    if (structure == Structure::kGeneral) {
      p_c1 = ray * depth(*rng);
    } else {
      const double denom = floor_normal_c1.dot(ray);
      if (denom <= 1e-3) continue;
      p_c1 = ray * (1.5 / denom);
      if (p_c1.z() < min_depth || p_c1.z() > max_depth) continue;
    }
    const Eigen::Vector3d p_c2 = T_c2_c1 * p_c1;
    if (p_c2.z() <= 0.1) continue;
    const Eigen::Vector2d u1 = (K * p_c1).hnormalized();
    const Eigen::Vector2d u2 = (K * p_c2).hnormalized();
    if (!inImage(u1) || !inImage(u2)) continue;
    const bool outlier = unit(*rng) < outlier_ratio;
    s.points_c1.push_back(p_c1);
    s.pts1.push_back(u1 + Eigen::Vector2d(noise(*rng), noise(*rng)));
    s.pts2.push_back(outlier ? Eigen::Vector2d(ux(*rng), uy(*rng))
                             : Eigen::Vector2d(u2 + Eigen::Vector2d(noise(*rng), noise(*rng))));
    s.outlier.push_back(outlier);
  }
  return s;
}

double angleDeg(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return std::atan2(a.cross(b).norm(), a.dot(b)) * kRadToDeg;
}

double medianOf(std::vector<double> v) {
  if (v.empty()) return std::numeric_limits<double>::infinity();
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

/// Checks the recovered motion against the truth, and the structure up to
/// scale (least-squares scale, median relative point error). With 1 px noise
/// a point's depth is uncertain by several percent at these baselines (and a
/// sideways translation is hard to tell from a rotation), so the structure is
/// compared both with the points triangulated from the same noisy pixels with
/// the true motion (the algorithm's own error) and with the noise-free truth
/// under a noise-limited bound.
void expectMotionAndStructure(const Scene& s, const TwoViewResult& r, double max_rot_deg,
                              double max_trans_deg, double max_error_vs_true_motion,
                              double max_error_vs_truth) {
  const Eigen::Matrix3d dR = r.T_c2_c1.linear().transpose() * s.T_c2_c1.linear();
  EXPECT_LT(rotationAngle(dR) * kRadToDeg, max_rot_deg);
  EXPECT_NEAR(r.T_c2_c1.translation().norm(), 1.0, 1e-9);
  EXPECT_LT(angleDeg(r.T_c2_c1.translation(), s.T_c2_c1.translation()), max_trans_deg);

  ASSERT_EQ(r.valid.size(), s.pts1.size());
  ASSERT_EQ(r.points_c1.size(), s.pts1.size());
  const Eigen::Matrix3d K_inv = intrinsics().inverse();
  const double baseline = s.T_c2_c1.translation().norm();
  std::vector<std::pair<Eigen::Vector3d, Eigen::Vector3d>> pairs;  // (estimate, true-motion)
  std::vector<Eigen::Vector3d> truth;
  int valid_outliers = 0, valid_inliers = 0, inliers = 0;
  for (size_t i = 0; i < s.pts1.size(); ++i) {
    inliers += s.outlier[i] ? 0 : 1;
    if (!r.valid[i]) continue;
    (s.outlier[i] ? valid_outliers : valid_inliers)++;
    if (s.outlier[i]) continue;
    const std::optional<Eigen::Vector3d> p =
        triangulate(SE3::Identity(), s.T_c2_c1, (K_inv * s.pts1[i].homogeneous()).hnormalized(),
                    (K_inv * s.pts2[i].homogeneous()).hnormalized());
    if (!p) continue;
    pairs.emplace_back(r.points_c1[i], *p);
    truth.push_back(s.points_c1[i]);
  }
  EXPECT_EQ(r.num_valid, valid_inliers + valid_outliers);
  EXPECT_GT(valid_inliers, 0.75 * inliers);
  EXPECT_LE(valid_outliers, 0.02 * r.num_valid);
  ASSERT_GT(pairs.size(), 10u);
  double num = 0.0, den = 0.0;
  for (const auto& [estimate, reference] : pairs) {
    num += estimate.dot(reference);
    den += estimate.squaredNorm();
  }
  const double scale = num / den;
  EXPECT_NEAR(scale, baseline, 0.15 * baseline);  // structure in units of |t| = 1
  std::vector<double> vs_true_motion, vs_truth;
  for (size_t k = 0; k < pairs.size(); ++k) {
    const Eigen::Vector3d p = scale * pairs[k].first;
    vs_true_motion.push_back((p - pairs[k].second).norm() / pairs[k].second.norm());
    vs_truth.push_back((p - truth[k]).norm() / truth[k].norm());
  }
  EXPECT_LT(medianOf(vs_true_motion), max_error_vs_true_motion);
  EXPECT_LT(medianOf(vs_truth), max_error_vs_truth);
  std::printf(
      "rotation error %.3f deg, translation direction error %.3f deg, scale %.4f (baseline %.4f), "
      "median point error %.4f vs true-motion triangulation, %.4f vs truth\n",
      rotationAngle(dR) * kRadToDeg, angleDeg(r.T_c2_c1.translation(), s.T_c2_c1.translation()),
      scale, baseline, medianOf(vs_true_motion), medianOf(vs_truth));
}

TEST(TriangulateTest, RecoversPointsWithoutNoise) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  SE3 T_c1_w = SE3::Identity();
  T_c1_w.linear() = expSO3(Eigen::Vector3d(0.1, -0.2, 0.05));
  T_c1_w.translation() = Eigen::Vector3d(0.5, -1.0, 2.0);
  const SE3 T_c2_w =
      secondCamera(Eigen::Vector3d(0.4, 0.1, 0.05), Eigen::Vector3d(0.0, 0.05, 0.0)) * T_c1_w;
  for (int k = 0; k < 100; ++k) {
    const Eigen::Vector3d p_c1(2.0 * u(rng), 1.5 * u(rng), 5.0 + 3.0 * u(rng));
    const Eigen::Vector3d p_w = T_c1_w.inverse() * p_c1;
    const Eigen::Vector2d x1 = (T_c1_w * p_w).hnormalized();
    const Eigen::Vector2d x2 = (T_c2_w * p_w).hnormalized();
    const std::optional<Eigen::Vector3d> p = triangulate(T_c1_w, T_c2_w, x1, x2);
    ASSERT_TRUE(p.has_value());
    EXPECT_LT((*p - p_w).norm(), 1e-9 * p_w.norm()) << p_w.transpose();
  }
}

TEST(TriangulateTest, RejectsPointsBehindAtInfinityAndNonFinite) {
  const SE3 T_c1_w = SE3::Identity();
  const SE3 T_c2_w = secondCamera(Eigen::Vector3d(1.0, 0.0, 0.0), Eigen::Vector3d::Zero());
  // Behind both cameras: the projections of a point at z = -4.
  const Eigen::Vector3d behind(0.3, 0.2, -4.0);
  EXPECT_FALSE(triangulate(T_c1_w, T_c2_w, behind.hnormalized(), (T_c2_w * behind).hnormalized()));
  // In front of camera 1, behind camera 2 (camera 2 rotated by 180 deg).
  const SE3 T_c2_w_flipped =
      secondCamera(Eigen::Vector3d(1.0, 0.0, 0.0), Eigen::Vector3d(0.0, M_PI, 0.0));
  const Eigen::Vector3d front(0.3, 0.2, 4.0);
  ASSERT_LT((T_c2_w_flipped * front).z(), 0.0);
  EXPECT_FALSE(triangulate(T_c1_w, T_c2_w_flipped, front.hnormalized(),
                           (T_c2_w_flipped * front).hnormalized()));
  // Same bearing from two translated cameras: parallel rays, point at infinity.
  const Eigen::Vector2d x(0.1, 0.2);
  EXPECT_FALSE(triangulate(T_c1_w, T_c2_w, x, x));
  const double nan = std::numeric_limits<double>::quiet_NaN();
  EXPECT_FALSE(triangulate(T_c1_w, T_c2_w, Eigen::Vector2d(nan, 0.0), x));
  // The same point in front of both is accepted.
  EXPECT_TRUE(triangulate(T_c1_w, T_c2_w, front.hnormalized(), (T_c2_w * front).hnormalized()));
}

TEST(TriangulateTest, ParallaxAngle) {
  EXPECT_NEAR(parallaxDeg(Eigen::Vector3d(0.0, 0.0, 1.0), Eigen::Vector3d(-1.0, 0.0, 0.0),
                          Eigen::Vector3d(1.0, 0.0, 0.0)),
              90.0, 1e-12);
  EXPECT_NEAR(parallaxDeg(Eigen::Vector3d(0.0, 0.0, 100.0), Eigen::Vector3d(-0.5, 0.0, 0.0),
                          Eigen::Vector3d(0.5, 0.0, 0.0)),
              2.0 * std::atan(0.5 / 100.0) * kRadToDeg, 1e-12);
  EXPECT_EQ(
      parallaxDeg(Eigen::Vector3d(1.0, 2.0, 3.0), Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero()),
      0.0);
}

TEST(TwoViewTest, GeneralSceneChoosesFundamental) {
  std::mt19937 rng(7);
  const SE3 T_c2_c1 =
      secondCamera(Eigen::Vector3d(0.3, 0.0, 0.0), Eigen::Vector3d(0.0, -2.0 / kRadToDeg, 0.0));
  const Scene s = makeScene(T_c2_c1, Structure::kGeneral, 300, 1.0, 0.1, &rng);
  const TwoViewResult r = reconstructTwoView(s.pts1, s.pts2, intrinsics(), TwoViewConfig());
  ASSERT_TRUE(r.success) << r.reason;
  EXPECT_FALSE(r.used_homography);
  EXPECT_GT(r.parallax_deg, 1.0);
  expectMotionAndStructure(s, r, 0.5, 2.0, 0.04, 0.05);
}

TEST(TwoViewTest, GeneralSceneWithoutNoiseIsExact) {
  std::mt19937 rng(5);
  const SE3 T_c2_c1 =
      secondCamera(Eigen::Vector3d(0.3, 0.0, 0.0), Eigen::Vector3d(0.0, -2.0 / kRadToDeg, 0.0));
  const Scene s = makeScene(T_c2_c1, Structure::kGeneral, 200, 0.0, 0.1, &rng);
  // A small sigma: with sigma = 1 px, the odd outlier within 1-2 px of its
  // epipolar line is (rightly) an inlier and tilts this sideways translation
  // by a fraction of a degree.
  TwoViewConfig config;
  config.sigma = 0.01;
  const TwoViewResult r = reconstructTwoView(s.pts1, s.pts2, intrinsics(), config);
  ASSERT_TRUE(r.success) << r.reason;
  EXPECT_FALSE(r.used_homography);
  expectMotionAndStructure(s, r, 1e-3, 1e-2, 1e-4, 1e-4);
}

TEST(TwoViewTest, GeneralSceneForwardMotion) {
  std::mt19937 rng(8);
  const SE3 T_c2_c1 =
      secondCamera(Eigen::Vector3d(0.15, -0.05, 0.5), Eigen::Vector3d(0.01, 3.0 / kRadToDeg, 0.0));
  const Scene s = makeScene(T_c2_c1, Structure::kGeneral, 300, 1.0, 0.1, &rng);
  const TwoViewResult r = reconstructTwoView(s.pts1, s.pts2, intrinsics(), TwoViewConfig());
  ASSERT_TRUE(r.success) << r.reason;
  EXPECT_FALSE(r.used_homography);
  expectMotionAndStructure(s, r, 0.5, 2.0, 0.04, 0.06);
}

// A car driving forward down a street: near points give the baseline, but
// most points are far (parallax below the noise, depth sign unknown). The
// motion explains them as points at infinity: they must not veto it.
TEST(TwoViewTest, ForwardMotionWithDistantBackground) {
  std::mt19937 rng(21);
  const SE3 T_c2_c1 =
      secondCamera(Eigen::Vector3d(0.02, 0.0, 1.0), Eigen::Vector3d(0.0, 1.0 / kRadToDeg, 0.0));
  Scene s = makeScene(T_c2_c1, Structure::kGeneral, 120, 1.0, 0.05, &rng, 5.0, 20.0);
  const Scene far = makeScene(T_c2_c1, Structure::kGeneral, 180, 1.0, 0.05, &rng, 150.0, 400.0);
  s.points_c1.insert(s.points_c1.end(), far.points_c1.begin(), far.points_c1.end());
  s.pts1.insert(s.pts1.end(), far.pts1.begin(), far.pts1.end());
  s.pts2.insert(s.pts2.end(), far.pts2.begin(), far.pts2.end());
  s.outlier.insert(s.outlier.end(), far.outlier.begin(), far.outlier.end());
  const TwoViewResult r = reconstructTwoView(s.pts1, s.pts2, intrinsics(), TwoViewConfig());
  ASSERT_TRUE(r.success) << r.reason;
  EXPECT_FALSE(r.used_homography);
  // Forward, not backward: the camera centre moves along +z of camera 1.
  const Eigen::Vector3d c2_c1 = -r.T_c2_c1.linear().transpose() * r.T_c2_c1.translation();
  EXPECT_GT(c2_c1.z(), 0.95);
  EXPECT_LT(angleDeg(r.T_c2_c1.translation(), T_c2_c1.translation()), 3.0);
  // The near points are the valid ones; the far ones are not returned.
  int near_valid = 0, far_valid = 0;
  for (size_t i = 0; i < s.pts1.size(); ++i) {
    if (!r.valid[i] || s.outlier[i]) continue;
    (i < 120 ? near_valid : far_valid)++;
  }
  EXPECT_GT(near_valid, 80);
  EXPECT_LT(far_valid, 20);
}

TEST(TwoViewTest, PlanarSceneChoosesHomography) {
  std::mt19937 rng(11);
  const SE3 T_c2_c1 =
      secondCamera(Eigen::Vector3d(0.3, 0.0, 0.0), Eigen::Vector3d(0.0, -3.0 / kRadToDeg, 0.0));
  const Scene s = makeScene(T_c2_c1, Structure::kFloor, 300, 1.0, 0.1, &rng);
  const TwoViewResult r = reconstructTwoView(s.pts1, s.pts2, intrinsics(), TwoViewConfig());
  ASSERT_TRUE(r.success) << r.reason;
  EXPECT_TRUE(r.used_homography);
  expectMotionAndStructure(s, r, 0.5, 2.0, 0.04, 0.05);
}

TEST(TwoViewTest, PlanarSceneWithoutNoiseIsExact) {
  std::mt19937 rng(12);
  const SE3 T_c2_c1 =
      secondCamera(Eigen::Vector3d(0.3, 0.0, 0.0), Eigen::Vector3d(0.0, -3.0 / kRadToDeg, 0.0));
  const Scene s = makeScene(T_c2_c1, Structure::kFloor, 200, 0.0, 0.1, &rng);
  TwoViewConfig config;
  config.sigma = 0.01;
  const TwoViewResult r = reconstructTwoView(s.pts1, s.pts2, intrinsics(), config);
  ASSERT_TRUE(r.success) << r.reason;
  EXPECT_TRUE(r.used_homography);
  expectMotionAndStructure(s, r, 1e-3, 1e-2, 1e-4, 1e-4);
}

// A homography has two decompositions that put every point in front of both
// cameras when the camera moves diagonally over the floor: no clear winner.
TEST(TwoViewTest, PlanarTwofoldAmbiguityIsRefused) {
  std::mt19937 rng(11);
  const SE3 T_c2_c1 =
      secondCamera(Eigen::Vector3d(0.3, 0.0, 0.3), Eigen::Vector3d(0.0, -3.0 / kRadToDeg, 0.0));
  const Scene s = makeScene(T_c2_c1, Structure::kFloor, 200, 1.0, 0.1, &rng);
  const TwoViewResult r = reconstructTwoView(s.pts1, s.pts2, intrinsics(), TwoViewConfig());
  EXPECT_FALSE(r.success);
  EXPECT_TRUE(r.used_homography);
  EXPECT_NE(r.reason.find("ambiguous"), std::string::npos) << r.reason;
}

// Points of a corridor seen from camera 1 (y down): walls at x = -1.2 and
// 1.2 m, the floor 1.5 m below, the end wall `end_m` ahead.
Scene corridorScene(const SE3& T_c2_c1, double end_m, double noise_px, std::mt19937* rng,
                    double keep_near = 1.0) {
  const Eigen::Matrix3d K = intrinsics();
  std::uniform_real_distribution<double> ux(0.0, kWidth), uy(0.0, kHeight);
  std::normal_distribution<double> noise(0.0, noise_px);
  Scene s;
  s.T_c2_c1 = T_c2_c1;
  while (s.points_c1.size() < 300) {
    const Eigen::Vector3d ray = K.inverse() * Eigen::Vector3d(ux(*rng), uy(*rng), 1.0);
    double t = end_m / ray.z();
    if (ray.x() < 0) t = std::min(t, -1.2 / ray.x());
    if (ray.x() > 0) t = std::min(t, 1.2 / ray.x());
    if (ray.y() > 0) t = std::min(t, 1.5 / ray.y());
    if (t * ray.z() < end_m - 1e-9 &&
        std::uniform_real_distribution<double>(0, 1)(*rng) > keep_near)
      continue;
    const Eigen::Vector3d p_c1 = t * ray;
    const Eigen::Vector3d p_c2 = T_c2_c1 * p_c1;
    if (p_c1.z() < 0.5 || p_c2.z() < 0.5) continue;
    const Eigen::Vector2d u1 = (K * p_c1).hnormalized(), u2 = (K * p_c2).hnormalized();
    if (!inImage(u1) || !inImage(u2)) continue;
    s.points_c1.push_back(p_c1);
    s.pts1.push_back(u1 + Eigen::Vector2d(noise(*rng), noise(*rng)));
    s.pts2.push_back(u2 + Eigen::Vector2d(noise(*rng), noise(*rng)));
    s.outlier.push_back(false);
  }
  return s;
}

// Walking 20 cm down a corridor towards its end wall 4 m ahead, most points
// on that wall (a third of those on the side walls and floor kept): the
// homography scores best and its two decompositions tie, but the scene is
// not one plane, so the fundamental matrix's motion decides (before, this
// was refused as ambiguous until the device had walked on for seconds).
TEST(TwoViewTest, CorridorShortBaselineTieIsDecidedByTheFundamental) {
  std::mt19937 rng(31);
  const SE3 T_c2_c1 =
      secondCamera(Eigen::Vector3d(0.03, 0.01, 0.2), Eigen::Vector3d(0.0, 0.5 / kRadToDeg, 0.0));
  const Scene s = corridorScene(T_c2_c1, 4.0, 1.0, &rng, 0.3);
  const TwoViewResult r = reconstructTwoView(s.pts1, s.pts2, intrinsics(), TwoViewConfig());
  ASSERT_TRUE(r.success) << r.reason;
  EXPECT_FALSE(r.used_homography);
  const Eigen::Matrix3d dR = r.T_c2_c1.linear().transpose() * T_c2_c1.linear();
  EXPECT_LT(rotationAngle(dR) * kRadToDeg, 0.3);
  EXPECT_LT(angleDeg(r.T_c2_c1.translation(), T_c2_c1.translation()), 5.0);
  EXPECT_GT(r.num_valid, 150);
}

// The accelerometer's up direction in each view rules out hypotheses that
// rotate it: the true motion passes, a reading 40 degrees off refuses all.
TEST(TwoViewTest, GravityRulesOutMotionsThatRotateUp) {
  std::mt19937 rng(7);
  const SE3 T_c2_c1 =
      secondCamera(Eigen::Vector3d(0.3, 0.0, 0.0), Eigen::Vector3d(0.0, -2.0 / kRadToDeg, 0.0));
  const Scene s = makeScene(T_c2_c1, Structure::kGeneral, 300, 1.0, 0.1, &rng);
  const Eigen::Vector3d up_c1 = Eigen::Vector3d(0.0, -1.0, 0.1).normalized();
  TwoViewGravity agrees{up_c1, T_c2_c1.linear() * up_c1, 10.0};
  const TwoViewResult r =
      reconstructTwoView(s.pts1, s.pts2, intrinsics(), TwoViewConfig(), 1, agrees);
  ASSERT_TRUE(r.success) << r.reason;
  expectMotionAndStructure(s, r, 0.5, 2.0, 0.04, 0.05);
  TwoViewGravity disagrees = agrees;
  disagrees.up_c2 = expSO3(Eigen::Vector3d(40.0 / kRadToDeg, 0.0, 0.0)) * agrees.up_c2;
  const TwoViewResult bad =
      reconstructTwoView(s.pts1, s.pts2, intrinsics(), TwoViewConfig(), 1, disagrees);
  EXPECT_FALSE(bad.success);
  EXPECT_NE(bad.reason.find("gravity"), std::string::npos) << bad.reason;
}

TEST(TwoViewTest, DeterministicForASeed) {
  std::mt19937 rng(7);
  const SE3 T_c2_c1 = secondCamera(Eigen::Vector3d(0.3, 0.0, 0.0), Eigen::Vector3d::Zero());
  const Scene s = makeScene(T_c2_c1, Structure::kGeneral, 150, 1.0, 0.1, &rng);
  const TwoViewResult a = reconstructTwoView(s.pts1, s.pts2, intrinsics(), TwoViewConfig(), 5);
  const TwoViewResult b = reconstructTwoView(s.pts1, s.pts2, intrinsics(), TwoViewConfig(), 5);
  ASSERT_TRUE(a.success) << a.reason;
  EXPECT_TRUE(a.T_c2_c1.isApprox(b.T_c2_c1, 0.0));
  EXPECT_EQ(a.valid, b.valid);
}

void expectWeakBaselineRefused(const TwoViewResult& r) {
  EXPECT_FALSE(r.success);
  EXPECT_TRUE(r.reason.find("parallax") != std::string::npos ||
              r.reason.find("baseline") != std::string::npos)
      << r.reason;
}

TEST(TwoViewTest, PureRotationIsRefused) {
  std::mt19937 rng(13);
  const SE3 T_c2_c1 =
      secondCamera(Eigen::Vector3d::Zero(), Eigen::Vector3d(0.02, 5.0 / kRadToDeg, 0.0));
  const Scene s = makeScene(T_c2_c1, Structure::kGeneral, 200, 1.0, 0.1, &rng);
  const TwoViewResult r = reconstructTwoView(s.pts1, s.pts2, intrinsics(), TwoViewConfig());
  expectWeakBaselineRefused(r);
}

TEST(TwoViewTest, CentimetreBaselineAtFiveMetresIsRefused) {
  std::mt19937 rng(17);
  const SE3 T_c2_c1 = secondCamera(Eigen::Vector3d(0.01, 0.0, 0.0), Eigen::Vector3d::Zero());
  const Scene s = makeScene(T_c2_c1, Structure::kGeneral, 200, 1.0, 0.1, &rng, 4.5, 5.5);
  const TwoViewResult r = reconstructTwoView(s.pts1, s.pts2, intrinsics(), TwoViewConfig());
  expectWeakBaselineRefused(r);
  EXPECT_LT(r.parallax_deg, 1.0);
  ASSERT_EQ(r.valid.size(), s.pts1.size());
  EXPECT_EQ(std::count(r.valid.begin(), r.valid.end(), true), 0);
}

TEST(TwoViewTest, FewCorrespondencesAreRefused) {
  std::mt19937 rng(19);
  const SE3 T_c2_c1 = secondCamera(Eigen::Vector3d(0.3, 0.0, 0.0), Eigen::Vector3d::Zero());
  const Scene s = makeScene(T_c2_c1, Structure::kGeneral, 40, 1.0, 0.0, &rng);
  const TwoViewResult r = reconstructTwoView(s.pts1, s.pts2, intrinsics(), TwoViewConfig());
  EXPECT_FALSE(r.success);
  EXPECT_NE(r.reason.find("too few"), std::string::npos) << r.reason;
}

TEST(TwoViewTest, DegenerateInputFailsCleanly) {
  const Eigen::Matrix3d K = intrinsics();
  const TwoViewConfig config;
  const double nan = std::numeric_limits<double>::quiet_NaN();
  EXPECT_FALSE(reconstructTwoView({}, {}, K, config).success);
  const std::vector<Eigen::Vector2d> three(3, Eigen::Vector2d(1.0, 2.0));
  const std::vector<Eigen::Vector2d> four(4, Eigen::Vector2d(1.0, 2.0));
  const TwoViewResult mismatch = reconstructTwoView(three, four, K, config);
  EXPECT_FALSE(mismatch.success);
  EXPECT_NE(mismatch.reason.find("mismatch"), std::string::npos) << mismatch.reason;
  const std::vector<Eigen::Vector2d> nans(100, Eigen::Vector2d(nan, 1.0));
  EXPECT_FALSE(reconstructTwoView(nans, nans, K, config).success);
  // Every correspondence at the same pixel: no spread, no model.
  const std::vector<Eigen::Vector2d> same(100, Eigen::Vector2d(100.0, 100.0));
  EXPECT_FALSE(reconstructTwoView(same, same, K, config).success);
  // Identical images: zero motion.
  std::mt19937 rng(23);
  const Scene s = makeScene(SE3::Identity(), Structure::kGeneral, 100, 0.0, 0.0, &rng);
  expectWeakBaselineRefused(reconstructTwoView(s.pts1, s.pts1, K, config));
  EXPECT_FALSE(reconstructTwoView(s.pts1, s.pts2, Eigen::Matrix3d::Zero(), config).success);
}

TEST(TwoViewTest, NanCorrespondencesAreSkipped) {
  std::mt19937 rng(29);
  const SE3 T_c2_c1 =
      secondCamera(Eigen::Vector3d(0.3, 0.0, 0.0), Eigen::Vector3d(0.0, -2.0 / kRadToDeg, 0.0));
  Scene s = makeScene(T_c2_c1, Structure::kGeneral, 200, 1.0, 0.0, &rng);
  const double nan = std::numeric_limits<double>::quiet_NaN();
  for (size_t i = 0; i < s.pts1.size(); i += 10) s.pts2[i].x() = nan;
  const TwoViewResult r = reconstructTwoView(s.pts1, s.pts2, intrinsics(), TwoViewConfig());
  ASSERT_TRUE(r.success) << r.reason;
  for (size_t i = 0; i < s.pts1.size(); i += 10) EXPECT_FALSE(r.valid[i]);
  EXPECT_GT(r.num_valid, 150);
}

/// World points seen by a camera at T_c_w, with noise and outliers.
struct PnpScene {
  SE3 T_c_w = SE3::Identity();
  std::vector<Eigen::Vector3d> points_w;
  std::vector<Eigen::Vector2d> pixels;
  std::vector<bool> outlier;
};

PnpScene makePnpScene(int n, double outlier_ratio, std::mt19937* rng) {
  PnpScene s;
  s.T_c_w = lookAt(Eigen::Vector3d(1.0, -2.0, 1.5), Eigen::Vector3d(6.0, 1.0, 0.5)).inverse();
  Scene view = makeScene(SE3::Identity(), Structure::kGeneral, n, 1.0, 0.0, rng);
  std::uniform_real_distribution<double> ux(0.0, kWidth), uy(0.0, kHeight), unit(0.0, 1.0);
  for (int i = 0; i < n; ++i) {
    s.points_w.push_back(s.T_c_w.inverse() * view.points_c1[i]);
    const bool outlier = unit(*rng) < outlier_ratio;
    s.pixels.push_back(outlier ? Eigen::Vector2d(ux(*rng), uy(*rng)) : view.pts1[i]);
    s.outlier.push_back(outlier);
  }
  return s;
}

TEST(PnpTest, RecoversPoseWithOutliers) {
  std::mt19937 rng(31);
  const PnpScene s = makePnpScene(200, 0.3, &rng);
  const PnpResult r = solvePnpRansac(s.points_w, s.pixels, intrinsics(), PnpConfig());
  ASSERT_TRUE(r.success);
  const SE3 dT = r.T_c_w * s.T_c_w.inverse();
  EXPECT_LT(dT.translation().norm(), 0.01);
  EXPECT_LT((r.T_c_w.inverse().translation() - s.T_c_w.inverse().translation()).norm(), 0.01);
  EXPECT_LT(rotationAngle(dT.linear()) * kRadToDeg, 0.2);
  int true_inliers = 0, wrong = 0;
  for (int i : r.inliers) (s.outlier[i] ? wrong : true_inliers)++;
  const int num_outliers = static_cast<int>(std::count(s.outlier.begin(), s.outlier.end(), true));
  EXPECT_GT(true_inliers, 0.95 * (200 - num_outliers));
  EXPECT_LE(wrong, 3);
}

TEST(PnpTest, GravityPnpRecoversPoseWithNinetyPercentOutliers) {
  std::mt19937 rng(41);
  const PnpScene s = makePnpScene(400, 0.9, &rng);
  // The world z axis in the camera frame, as an accelerometer would give it.
  const Eigen::Vector3d up_c = s.T_c_w.linear() * Eigen::Vector3d::UnitZ();
  PnpConfig config;
  config.ransac_iterations = 1000;
  const PnpResult r = solvePnpGravityRansac(s.points_w, s.pixels, intrinsics(), up_c, config, 3);
  ASSERT_TRUE(r.success);
  const SE3 dT = r.T_c_w * s.T_c_w.inverse();
  EXPECT_LT((r.T_c_w.inverse().translation() - s.T_c_w.inverse().translation()).norm(), 0.02);
  EXPECT_LT(rotationAngle(dT.linear()) * kRadToDeg, 0.3);
  // The up axis is kept exactly.
  EXPECT_GT((r.T_c_w.linear() * Eigen::Vector3d::UnitZ()).dot(up_c), 1.0 - 1e-9);
  int wrong = 0;
  for (int i : r.inliers) wrong += s.outlier[i] ? 1 : 0;
  EXPECT_GT(static_cast<int>(r.inliers.size()) - wrong, 30);
  EXPECT_LE(wrong, 3);
  // Without enough inliers, or with a wrong up direction, it fails.
  const std::vector<Eigen::Vector3d> p10(s.points_w.begin(), s.points_w.begin() + 10);
  const std::vector<Eigen::Vector2d> u10(s.pixels.begin(), s.pixels.begin() + 10);
  EXPECT_FALSE(solvePnpGravityRansac(p10, u10, intrinsics(), up_c, config).success);
  const Eigen::Vector3d tilted = (up_c + Eigen::Vector3d(0.3, 0.0, 0.0)).normalized();
  EXPECT_FALSE(solvePnpGravityRansac(s.points_w, s.pixels, intrinsics(), tilted, config).success);
}

TEST(PnpTest, TooFewPointsOrInliersFail) {
  std::mt19937 rng(37);
  const Eigen::Matrix3d K = intrinsics();
  const PnpScene s = makePnpScene(30, 0.0, &rng);
  const std::vector<Eigen::Vector3d> p3(s.points_w.begin(), s.points_w.begin() + 3);
  const std::vector<Eigen::Vector2d> u3(s.pixels.begin(), s.pixels.begin() + 3);
  PnpConfig lenient;
  lenient.min_inliers = 0;
  EXPECT_FALSE(solvePnpRansac(p3, u3, K, lenient).success);
  // Ten good points are below the default min_inliers (15).
  const std::vector<Eigen::Vector3d> p10(s.points_w.begin(), s.points_w.begin() + 10);
  const std::vector<Eigen::Vector2d> u10(s.pixels.begin(), s.pixels.begin() + 10);
  EXPECT_FALSE(solvePnpRansac(p10, u10, K, PnpConfig()).success);
  EXPECT_TRUE(solvePnpRansac(p10, u10, K, lenient).success);
  // Only outliers: random pixels.
  const PnpScene junk = makePnpScene(30, 1.0, &rng);
  EXPECT_FALSE(solvePnpRansac(junk.points_w, junk.pixels, K, PnpConfig()).success);
}

TEST(PnpTest, DegenerateInputFailsCleanly) {
  const Eigen::Matrix3d K = intrinsics();
  EXPECT_FALSE(solvePnpRansac({}, {}, K, PnpConfig()).success);
  std::mt19937 rng(41);
  PnpScene s = makePnpScene(50, 0.0, &rng);
  std::vector<Eigen::Vector2d> fewer(s.pixels.begin(), s.pixels.end() - 1);
  EXPECT_FALSE(solvePnpRansac(s.points_w, fewer, K, PnpConfig()).success);
  const double nan = std::numeric_limits<double>::quiet_NaN();
  std::vector<Eigen::Vector2d> nans(s.pixels.size(), Eigen::Vector2d(nan, nan));
  EXPECT_FALSE(solvePnpRansac(s.points_w, nans, K, PnpConfig()).success);
  // A few NaN among good correspondences are skipped.
  for (size_t i = 0; i < s.pixels.size(); i += 7) s.pixels[i].y() = nan;
  const PnpResult r = solvePnpRansac(s.points_w, s.pixels, K, PnpConfig());
  ASSERT_TRUE(r.success);
  for (int i : r.inliers) EXPECT_NE(i % 7, 0);
  // All points identical: no pose.
  const std::vector<Eigen::Vector3d> same_w(20, Eigen::Vector3d(1.0, 2.0, 3.0));
  const std::vector<Eigen::Vector2d> same_u(20, Eigen::Vector2d(100.0, 100.0));
  EXPECT_FALSE(solvePnpRansac(same_w, same_u, K, PnpConfig()).success);
}

}  // namespace
}  // namespace ecar
