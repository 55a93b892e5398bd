// Local graphs: the device mirror (positions sent once, again after a reset,
// a version change, or once the point left the mirrored queue), the edgeslam
// payload, and the size of the ecar payload per point.
#include "ecar_core/local_graph.h"

#include <gtest/gtest.h>

#include "ecar_core/error.h"

namespace ecar {
namespace {

// A keyframe with `n` keypoints and random descriptors.
KeyFrame keyframeWith(int n, DeviceId device) {
  KeyFrame kf;
  kf.device = device;
  for (int i = 0; i < n; ++i) kf.features.keypoints.emplace_back(10.0f * i, 5.0f, 31.0f, 45.0f);
  kf.features.descriptors = cv::Mat(n, 32, CV_8U);
  cv::randu(kf.features.descriptors, 0, 256);
  return kf;
}

// A map of `keyframes` keyframes of 20 keypoints; keyframe k observes points
// [5k, 5k + 20) at its keypoints 0..19, so neighbours share 15 points.
class LocalGraphTest : public ::testing::Test {
 protected:
  static constexpr int kKeyFrames = 6;
  static constexpr int kPointsPerKeyFrame = 20;

  LocalGraphTest() : map(ScaleInfo::fromConfig(OrbConfig())) {
    auto lock = map.writeLock();
    for (int k = 0; k < kKeyFrames; ++k) {
      KeyFrame kf = keyframeWith(kPointsPerKeyFrame, DeviceId(1 + k % 2));
      kf.T_c_w.translation() = Eigen::Vector3d(-0.1 * k, 0, 0);
      kfs.push_back(map.addKeyFrame(std::move(kf)));
    }
    const int n = 5 * (kKeyFrames - 1) + kPointsPerKeyFrame;
    for (int i = 0; i < n; ++i) {
      points.push_back(map.addPoint(Eigen::Vector3d(0.1 * i, 0.2, 3.0), kfs[0]));
    }
    for (int k = 0; k < kKeyFrames; ++k) {
      for (int j = 0; j < kPointsPerKeyFrame; ++j) map.addObservation(points[5 * k + j], kfs[k], j);
    }
    for (const auto& p : points) map.updatePointStatistics(p);
    for (const auto& k : kfs) map.updateCovisibility(k);
  }

  // A tracked result seeing points [first, first + count).
  TrackResult trackedResult(int first, int count) const {
    TrackResult r;
    r.state = TrackingState::kOk;
    for (int i = first; i < first + count; ++i) {
      cv::KeyPoint kp(12.5f + i, 40.125f, 31.0f, 123.0f, 0.0f, i % 8);
      r.tracked.push_back({points[i], kp, Eigen::Vector3d::Zero()});
    }
    r.local_keyframes = kfs;
    return r;
  }

  static std::vector<MapPointId> positionIds(const LocalGraphData& g) {
    std::vector<MapPointId> ids;
    for (const auto& p : g.positions) ids.push_back(p.id);
    return ids;
  }

  Map map;
  std::vector<KeyFrameId> kfs;
  std::vector<MapPointId> points;
  LocalGraphBuilder builder;
};

TEST_F(LocalGraphTest, PositionsAreSentOnce) {
  DeviceMirror mirror(10);
  const auto g1 = builder.build(map, trackedResult(0, 20), SyncMode::kEcar, &mirror);
  ASSERT_EQ(g1.points.size(), 20u);
  EXPECT_EQ(g1.positions.size(), 20u);
  EXPECT_EQ(g1.points[3].id, points[3]);
  EXPECT_FLOAT_EQ(g1.points[3].u, 15.5f);
  EXPECT_FLOAT_EQ(g1.points[3].v, 40.125f);
  EXPECT_FLOAT_EQ(g1.points[3].angle, 123.0f);
  EXPECT_EQ(g1.points[3].octave, 3);
  EXPECT_NEAR(g1.positions[3].p_w.x(), 0.3f, 1e-6);
  EXPECT_TRUE(g1.keyframes.empty());
  EXPECT_TRUE(g1.map_points.empty());
  // Half of them again, plus 10 new ones: only the new ones carry positions.
  const auto g2 = builder.build(map, trackedResult(10, 20), SyncMode::kEcar, &mirror);
  EXPECT_EQ(g2.points.size(), 20u);
  ASSERT_EQ(g2.positions.size(), 10u);
  EXPECT_EQ(g2.positions.front().id, points[20]);
  EXPECT_EQ(mirror.numKeyFrames(), 2u);
  EXPECT_EQ(mirror.numPoints(), 30u);
}

TEST_F(LocalGraphTest, PositionsAreSentAgainAfterAReset) {
  DeviceMirror mirror(10);
  builder.build(map, trackedResult(0, 20), SyncMode::kEcar, &mirror);
  mirror.reset();
  EXPECT_EQ(mirror.numPoints(), 0u);
  const auto g = builder.build(map, trackedResult(0, 20), SyncMode::kEcar, &mirror);
  EXPECT_EQ(g.positions.size(), 20u);
}

TEST_F(LocalGraphTest, PositionsAreSentAgainAfterAVersionChange) {
  DeviceMirror mirror(10);
  builder.build(map, trackedResult(0, 20), SyncMode::kEcar, &mirror);
  {
    auto lock = map.writeLock();
    MapPoint* p = map.mutablePoint(points[7]);
    p->p_w.z() = 3.5;
    ++p->version;
  }
  const auto g = builder.build(map, trackedResult(0, 20), SyncMode::kEcar, &mirror);
  ASSERT_EQ(g.positions.size(), 1u);
  EXPECT_EQ(g.positions[0].id, points[7]);
  EXPECT_FLOAT_EQ(g.positions[0].p_w.z(), 3.5f);
  // Sent once: the next graph does not repeat it.
  EXPECT_TRUE(builder.build(map, trackedResult(0, 20), SyncMode::kEcar, &mirror).positions.empty());
  // A new version that moved less than the tolerance (1 mm) is not resent.
  {
    auto lock = map.writeLock();
    MapPoint* p = map.mutablePoint(points[7]);
    p->p_w.z() += 0.0004;
    ++p->version;
  }
  EXPECT_TRUE(builder.build(map, trackedResult(0, 20), SyncMode::kEcar, &mirror).positions.empty());
  LocalGraphConfig exact;
  exact.position_tolerance = 0.0;
  DeviceMirror mirror2(10);
  const LocalGraphBuilder strict(exact);
  strict.build(map, trackedResult(0, 20), SyncMode::kEcar, &mirror2);
  {
    auto lock = map.writeLock();
    MapPoint* p = map.mutablePoint(points[7]);
    p->p_w.z() += 0.0004;
    ++p->version;
  }
  EXPECT_EQ(strict.build(map, trackedResult(0, 20), SyncMode::kEcar, &mirror2).positions.size(),
            1u);
}

TEST_F(LocalGraphTest, DepthMovesWithinTheViewTolerancesAreNotResent) {
  LocalGraphConfig config;
  config.position_tolerance_deg = 0.05;
  config.position_tolerance_depth = 0.02;
  const LocalGraphBuilder viewed(config);
  DeviceMirror mirror(10);
  viewed.build(map, trackedResult(0, 20), SyncMode::kEcar, &mirror);  // camera at the origin
  const auto move = [&](int i, const Eigen::Vector3d& d) {
    auto lock = map.writeLock();
    MapPoint* p = map.mutablePoint(points[i]);
    p->p_w += d;
    ++p->version;
  };
  const Eigen::Vector3d ray0 = Eigen::Vector3d(0.0, 0.2, 3.0).normalized();  // point 0
  move(0, 0.03 * ray0);                      // 1% of 3 m in depth: kept
  move(1, Eigen::Vector3d(0.01, 0.0, 0.0));  // 1 cm across at 3 m: 0.19 deg, resent
  const Eigen::Vector3d ray2 = Eigen::Vector3d(0.2, 0.2, 3.0).normalized();
  move(2, 0.09 * ray2);  // 3% in depth: resent
  const auto g = viewed.build(map, trackedResult(0, 20), SyncMode::kEcar, &mirror);
  EXPECT_EQ(positionIds(g), (std::vector<MapPointId>{points[1], points[2]}));
}

TEST_F(LocalGraphTest, PositionsAreSentAgainOnceThePointLeftTheQueue) {
  DeviceMirror mirror(3);
  builder.build(map, trackedResult(0, 10), SyncMode::kEcar, &mirror);  // holds 0..9
  // Three keyframes without points 0..4: the first keyframe is evicted, and
  // with it the points only it held; 5..9 stay (held by the later ones).
  for (int i = 0; i < 3; ++i) builder.build(map, trackedResult(5, 10), SyncMode::kEcar, &mirror);
  EXPECT_EQ(mirror.numKeyFrames(), 3u);
  EXPECT_FALSE(mirror.holds(points[0]));
  EXPECT_TRUE(mirror.holds(points[5]));
  const auto g = builder.build(map, trackedResult(0, 10), SyncMode::kEcar, &mirror);
  std::vector<MapPointId> expected(points.begin(), points.begin() + 5);
  EXPECT_EQ(positionIds(g), expected);
}

TEST_F(LocalGraphTest, LostFramesAndCulledPointsAreLeftOut) {
  DeviceMirror mirror(10);
  TrackResult lost = trackedResult(0, 20);
  lost.state = TrackingState::kLost;
  const auto g0 = builder.build(map, lost, SyncMode::kEcar, &mirror);
  EXPECT_TRUE(g0.points.empty());
  EXPECT_EQ(mirror.numKeyFrames(), 0u);
  {
    auto lock = map.writeLock();
    map.erasePoint(points[2]);
  }
  TrackResult r = trackedResult(0, 20);
  r.tracked.push_back(r.tracked[4]);  // a duplicate id counts once
  const auto g = builder.build(map, r, SyncMode::kEcar, &mirror);
  EXPECT_EQ(g.points.size(), 19u);
  EXPECT_EQ(g.positions.size(), 19u);
  EXPECT_THROW(builder.build(map, r, SyncMode::kEcar, nullptr), Error);
}

TEST_F(LocalGraphTest, EdgeSlamCarriesTheWholeLocalMap) {
  LocalGraphConfig config;
  config.edgeslam_keyframes = 0;
  const LocalGraphBuilder all(config);
  const auto g = all.build(map, trackedResult(0, 20), SyncMode::kEdgeSlam, nullptr);
  EXPECT_TRUE(g.points.empty());
  EXPECT_TRUE(g.positions.empty());
  ASSERT_EQ(g.keyframes.size(), static_cast<size_t>(kKeyFrames));
  EXPECT_EQ(g.map_points.size(), points.size());
  auto lock = map.readLock();
  for (const auto& k : g.keyframes) {
    const KeyFrame* kf = map.keyframe(k.id);
    ASSERT_NE(kf, nullptr);
    EXPECT_EQ(k.device, kf->device);
    EXPECT_TRUE(k.T_w_c.isApprox(kf->T_w_c()));
    EXPECT_EQ(k.points.size(), static_cast<size_t>(kPointsPerKeyFrame));
  }
  for (const auto& m : g.map_points) {
    const MapPoint* p = map.point(m.id);
    ASSERT_NE(p, nullptr);
    EXPECT_TRUE(m.p_w.isApprox(p->p_w.cast<float>()));
    EXPECT_TRUE(m.normal.isApprox(p->normal.cast<float>()));
    EXPECT_GT(m.max_distance, m.min_distance);
    EXPECT_FLOAT_EQ(m.max_distance, p->max_distance);
    EXPECT_TRUE(std::equal(m.descriptor.begin(), m.descriptor.end(), p->descriptor.ptr<uint8_t>()));
  }
  // The default keeps the first 10 local keyframes; here 2 of them.
  config.edgeslam_keyframes = 2;
  const auto g2 =
      LocalGraphBuilder(config).build(map, trackedResult(0, 20), SyncMode::kEdgeSlam, nullptr);
  EXPECT_EQ(g2.keyframes.size(), 2u);
  EXPECT_EQ(g2.map_points.size(), 25u);
}

// Wire bytes of the ecar payload (ecar_msgs: TrackedPoint 10 B, PointPosition
// 14 B, plus a 4-byte array length each) against edgeslam's (MapPointFull
// 68 B, KeyFrameInfo ids 4 B each): a device that keeps tracking the same
// points gets about 10 B per point in ecar mode.
TEST_F(LocalGraphTest, EcarPayloadPerPointIsSmall) {
  DeviceMirror mirror(10);
  const auto bytes = [](const LocalGraphData& g) {
    size_t b = 8 + 10 * g.points.size() + 14 * g.positions.size();
    b += 8 + 68 * g.map_points.size();
    for (const auto& k : g.keyframes) b += 4 + 56 + 4 + 4 * k.points.size() + 4 + 8;
    return b;
  };
  builder.build(map, trackedResult(0, 20), SyncMode::kEcar, &mirror);
  size_t total = 0, tracked = 0;
  for (int i = 0; i < 5; ++i) {
    const auto g = builder.build(map, trackedResult(i, 20), SyncMode::kEcar, &mirror);
    total += bytes(g);
    tracked += g.points.size();
  }
  EXPECT_LE(static_cast<double>(total) / tracked, 20.0);
  const auto edge = builder.build(map, trackedResult(0, 20), SyncMode::kEdgeSlam, nullptr);
  EXPECT_GE(bytes(edge),
            6 * bytes(builder.build(map, trackedResult(0, 20), SyncMode::kEcar, &mirror)));
}

TEST(SyncModeTest, ParsesAndPrints) {
  EXPECT_EQ(parseSyncMode("ecar"), SyncMode::kEcar);
  EXPECT_EQ(parseSyncMode("edgeslam"), SyncMode::kEdgeSlam);
  EXPECT_STREQ(toString(SyncMode::kEdgeSlam), "edgeslam");
  EXPECT_THROW(parseSyncMode("full"), Error);
}

}  // namespace
}  // namespace ecar
