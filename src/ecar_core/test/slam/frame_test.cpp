// FeatureGrid finds exactly the keypoints a scan of all of them finds, for any
// radius and octave bounds, also after a rebuild and for points outside the box.
#include <algorithm>
#include <cmath>
#include <limits>
#include <random>

#include <gtest/gtest.h>

#include "ecar_core/slam/frame.h"

namespace ecar {
namespace {

struct Points {
  std::vector<Eigen::Vector2d> uv;
  std::vector<cv::KeyPoint> kps;
};

Points randomPoints(size_t n, uint32_t seed) {
  std::mt19937 rng(seed);
  // Some outside the 640 x 480 box (-20 .. 660, -20 .. 500) on purpose.
  std::uniform_real_distribution<double> u(-20.0, 660.0), v(-20.0, 500.0);
  std::uniform_int_distribution<int> octave(0, 7);
  Points p;
  for (size_t i = 0; i < n; ++i) {
    p.uv.emplace_back(u(rng), v(rng));
    cv::KeyPoint kp;
    kp.pt = cv::Point2f(static_cast<float>(p.uv.back().x()), static_cast<float>(p.uv.back().y()));
    kp.octave = octave(rng);
    p.kps.push_back(kp);
  }
  return p;
}

std::vector<int> scan(const Points& p, double u, double v, double r, int min_level, int max_level) {
  std::vector<int> out;
  for (size_t i = 0; i < p.uv.size(); ++i) {
    const Eigen::Vector2d& q = p.uv[i];
    if (!(q.x() >= 0 && q.x() < 640 && q.y() >= 0 && q.y() < 480)) continue;  // outside the box
    const int o = p.kps[i].octave;
    if ((min_level >= 0 && o < min_level) || (max_level >= 0 && o > max_level)) continue;
    // The grid compares in float (its entries' precision).
    const double du = static_cast<float>(q.x()) - u, dv = static_cast<float>(q.y()) - v;
    if (du * du + dv * dv <= r * r) out.push_back(static_cast<int>(i));
  }
  return out;
}

std::vector<int> sorted(std::vector<int> v) {
  std::sort(v.begin(), v.end());
  return v;
}

TEST(FeatureGridTest, QueriesFindWhatAScanOfEveryPointFinds) {
  FeatureGrid grid;
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-60.0, 700.0), v(-60.0, 540.0), r(0.5, 80.0);
  std::vector<int> found;
  for (const size_t n : {size_t{2000}, size_t{300}, size_t{0}, size_t{1}}) {  // rebuilds
    const Points p = randomPoints(n, static_cast<uint32_t>(n) + 1);
    grid.build(p.uv, p.kps, 0.0, 0.0, 640.0, 480.0);
    size_t hits = 0;
    for (int q = 0; q < 400; ++q) {
      const double qu = u(rng), qv = v(rng), qr = r(rng);
      const int min_level = q % 3 == 0 ? -1 : q % 4, max_level = q % 5 == 0 ? -1 : 2 + q % 6;
      grid.query(qu, qv, qr, min_level, max_level, &found);
      const std::vector<int> expected = scan(p, qu, qv, qr, min_level, max_level);
      ASSERT_EQ(sorted(found), expected)
          << n << " points, query " << q << " at (" << qu << ", " << qv << ") r " << qr;
      hits += found.size();
    }
    if (n >= 300) {
      EXPECT_GT(hits, 400u) << "the queries must find points to test anything";
    }
  }
}

TEST(FeatureGridTest, PointsOutsideTheBoxOrNotFiniteAreLeftOut) {
  Points p;
  const double nan = std::numeric_limits<double>::quiet_NaN();
  for (const Eigen::Vector2d& q :
       {Eigen::Vector2d(10, 10), Eigen::Vector2d(nan, 10), Eigen::Vector2d(10, nan),
        Eigen::Vector2d(-1, 10), Eigen::Vector2d(640, 10), Eigen::Vector2d(12, 12)}) {
    p.uv.push_back(q);
    p.kps.emplace_back(cv::Point2f(0, 0), 1.0f);
  }
  FeatureGrid grid;
  grid.build(p.uv, p.kps, 0.0, 0.0, 640.0, 480.0);
  std::vector<int> found;
  grid.query(10, 10, 1000, -1, -1, &found);
  EXPECT_EQ(sorted(found), (std::vector<int>{0, 5}));
  grid.query(nan, 10, 5, -1, -1, &found);
  EXPECT_TRUE(found.empty());
  grid.clear();
  grid.query(10, 10, 5, -1, -1, &found);
  EXPECT_TRUE(found.empty());
}

TEST(FeatureGridTest, AFramesGridIsTwoBlocksWhateverItsSize) {
  const Points p = randomPoints(2000, 3);
  FeatureGrid grid;
  grid.build(p.uv, p.kps, 0.0, 0.0, 640.0, 480.0);
  // 40 x 30 cells: their starts and at most the 2000 entries (16 bytes each).
  EXPECT_LE(grid.memoryBytes(), 1201 * sizeof(uint32_t) + 2000 * 16);
  const FeatureGrid copy = grid;
  std::vector<int> a, b;
  grid.query(320, 240, 50, -1, -1, &a);
  copy.query(320, 240, 50, -1, -1, &b);
  EXPECT_EQ(a, b);
  EXPECT_FALSE(a.empty());
}

}  // namespace
}  // namespace ecar
