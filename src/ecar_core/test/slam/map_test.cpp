// The map's bookkeeping: observations recorded on both sides, covisibility,
// erasing and replacing points (and following a fused point to the one it
// became), and the consistency check itself.
#include "ecar_core/slam/map.h"

#include <gtest/gtest.h>

namespace ecar {
namespace {

// A keyframe with `n` keypoints (no image needed for the bookkeeping).
KeyFrame keyframeWith(int n) {
  KeyFrame kf;
  kf.camera = std::make_shared<const PinholeCamera>(CameraParams());
  for (int i = 0; i < n; ++i) kf.features.keypoints.emplace_back(10.0f * i, 5.0f, 31.0f);
  kf.features.descriptors = cv::Mat(n, 32, CV_8U);
  cv::randu(kf.features.descriptors, 0, 256);
  return kf;
}

class MapTest : public ::testing::Test {
 protected:
  MapTest() : map(ScaleInfo::fromConfig(OrbConfig())) {
    auto lock = map.writeLock();
    k1 = map.addKeyFrame(keyframeWith(10));
    k2 = map.addKeyFrame(keyframeWith(10));
  }
  Map map;
  KeyFrameId k1, k2;
};

TEST_F(MapTest, ObservationsAreRecordedOnBothSides) {
  auto lock = map.writeLock();
  const MapPointId p = map.addPoint(Eigen::Vector3d(0, 0, 2), k1);
  map.addObservation(p, k1, 3);
  map.addObservation(p, k2, 4);
  EXPECT_EQ(map.keyframe(k1)->points[3], p);
  EXPECT_EQ(map.point(p)->observations.at(k2), 4);
  EXPECT_EQ(map.checkConsistency(), "");
  map.updateCovisibility(k1);
  EXPECT_EQ(map.keyframe(k1)->covisibility.at(k2), 1);
  EXPECT_EQ(map.keyframe(k2)->covisibility.at(k1), 1);
}

TEST_F(MapTest, CovisibilityHopsCountTheLinksOfTheShortestChain) {
  // A chain k1 - k2 - k3 - k4 (each pair shares a point), and k5 alone.
  auto lock = map.writeLock();
  const KeyFrameId k3 = map.addKeyFrame(keyframeWith(10));
  const KeyFrameId k4 = map.addKeyFrame(keyframeWith(10));
  const KeyFrameId k5 = map.addKeyFrame(keyframeWith(10));
  const std::vector<std::pair<KeyFrameId, KeyFrameId>> links = {{k1, k2}, {k2, k3}, {k3, k4}};
  int row = 0;
  for (const auto& [a, b] : links) {
    const MapPointId p = map.addPoint(Eigen::Vector3d(0, 0, 2), a);
    map.addObservation(p, a, row);
    map.addObservation(p, b, row + 1);
    row += 2;
  }
  for (const KeyFrameId k : {k1, k2, k3, k4}) map.updateCovisibility(k);
  EXPECT_EQ(map.covisibilityHops(k1, k1, 3), 0);
  EXPECT_EQ(map.covisibilityHops(k1, k2, 3), 1);
  EXPECT_EQ(map.covisibilityHops(k1, k3, 3), 2);
  EXPECT_EQ(map.covisibilityHops(k4, k1, 3), 3);
  EXPECT_EQ(map.covisibilityHops(k1, k4, 2), 3);  // farther than searched: max_hops + 1
  EXPECT_EQ(map.covisibilityHops(k1, k5, 10), 11);
  EXPECT_EQ(map.covisibilityHops(k1, KeyFrameId(999), 3), 4);
  // A shortcut k1 - k4 makes them neighbours.
  const MapPointId q = map.addPoint(Eigen::Vector3d(0, 0, 2), k1);
  map.addObservation(q, k1, 9);
  map.addObservation(q, k4, 9);
  map.updateCovisibility(k1);
  EXPECT_EQ(map.covisibilityHops(k1, k4, 3), 1);
  EXPECT_EQ(map.covisibilityHops(k2, k4, 3), 2);
}

TEST_F(MapTest, ObservingAgainAtAnotherKeypointMovesTheObservation) {
  auto lock = map.writeLock();
  const MapPointId p = map.addPoint(Eigen::Vector3d(0, 0, 2), k1);
  map.addObservation(p, k1, 3);
  map.addObservation(p, k2, 4);
  map.addObservation(p, k1, 7);  // the same point matched to another keypoint
  EXPECT_FALSE(map.keyframe(k1)->points[3].valid());
  EXPECT_EQ(map.keyframe(k1)->points[7], p);
  EXPECT_EQ(map.checkConsistency(), "");
}

TEST_F(MapTest, ObservingATakenKeypointReleasesThePreviousPoint) {
  auto lock = map.writeLock();
  const KeyFrameId k3 = map.addKeyFrame(keyframeWith(10));
  const MapPointId a = map.addPoint(Eigen::Vector3d(0, 0, 2), k1);
  map.addObservation(a, k1, 1);
  map.addObservation(a, k2, 1);
  map.addObservation(a, k3, 1);
  const MapPointId b = map.addPoint(Eigen::Vector3d(1, 0, 2), k1);
  map.addObservation(b, k1, 2);
  map.addObservation(b, k2, 2);
  map.addObservation(b, k3, 1);  // takes keypoint 1 of k3 from a
  EXPECT_EQ(map.keyframe(k3)->points[1], b);
  EXPECT_EQ(map.point(a)->observations.count(k3), 0u);
  EXPECT_EQ(map.point(a)->observations.size(), 2u);
  EXPECT_EQ(map.checkConsistency(), "");
  // A point left with one observation carries no structure and is dropped.
  const MapPointId c = map.addPoint(Eigen::Vector3d(2, 0, 2), k1);
  map.addObservation(c, k1, 5);
  map.addObservation(c, k2, 5);
  map.addObservation(b, k2, 5);  // b moves to keypoint 5 of k2: c keeps only k1
  EXPECT_EQ(map.point(c), nullptr);
  EXPECT_FALSE(map.keyframe(k1)->points[5].valid());
  EXPECT_EQ(map.checkConsistency(), "");
}

TEST_F(MapTest, ReplacingAndErasingKeepTheMapConsistent) {
  auto lock = map.writeLock();
  const MapPointId a = map.addPoint(Eigen::Vector3d(0, 0, 2), k1);
  map.addObservation(a, k1, 1);
  map.addObservation(a, k2, 1);
  const MapPointId b = map.addPoint(Eigen::Vector3d(0, 0, 2.01), k2);
  map.addObservation(b, k2, 2);
  const KeyFrameId k3 = map.addKeyFrame(keyframeWith(10));
  map.addObservation(b, k3, 2);
  map.replacePoint(b, a);  // a duplicate fused
  EXPECT_EQ(map.point(b), nullptr);
  EXPECT_EQ(map.keyframe(k3)->points[2], a);
  EXPECT_FALSE(map.keyframe(k2)->points[2].valid());  // k2 already saw a at keypoint 1
  EXPECT_EQ(map.checkConsistency(), "");
  map.eraseKeyFrame(k2);
  EXPECT_EQ(map.point(a)->observations.size(), 2u);
  EXPECT_EQ(map.checkConsistency(), "");
  map.erasePoint(a);
  EXPECT_FALSE(map.keyframe(k1)->points[1].valid());
  EXPECT_EQ(map.checkConsistency(), "");
}

TEST_F(MapTest, ConsistencyCheckNamesWhatIsBroken) {
  auto lock = map.writeLock();
  const MapPointId p = map.addPoint(Eigen::Vector3d(0, 0, 2), k1);
  map.addObservation(p, k1, 3);
  map.addObservation(p, k2, 4);
  map.mutableKeyFrame(k2)->points[6] = p;  // a second keypoint claims p behind its back
  const std::string problem = map.checkConsistency();
  EXPECT_NE(problem.find("keyframe " + std::to_string(k2.value)), std::string::npos) << problem;
  map.mutableKeyFrame(k2)->points[6] = MapPointId();
  map.mutablePoint(p)->p_w.x() = std::nan("");
  EXPECT_NE(map.checkConsistency().find("non-finite"), std::string::npos);
}

TEST_F(MapTest, AFusedPointIsFollowedToThePointItBecame) {
  auto lock = map.writeLock();
  auto point = [&](double x, int idx) {
    const MapPointId p = map.addPoint(Eigen::Vector3d(x, 0, 2), k1);
    map.addObservation(p, k1, idx);
    map.addObservation(p, k2, idx);
    return p;
  };
  const MapPointId a = point(0.0, 1), b = point(0.01, 2), c = point(0.02, 3);
  EXPECT_EQ(map.livePoint(a), a);
  map.replacePoint(a, b);
  map.replacePoint(b, c);  // fused again: a's chain goes on to c
  EXPECT_EQ(map.livePoint(a), c);
  EXPECT_EQ(map.livePoint(b), c);
  map.erasePoint(c);  // culled: nothing to follow
  EXPECT_FALSE(map.livePoint(a).valid());
  EXPECT_FALSE(map.livePoint(MapPointId(999)).valid());
}

TEST_F(MapTest, TheRecordOfFusedPointsIsBounded) {
  auto lock = map.writeLock();
  auto point = [&](int idx) {  // at a keypoint that no live point holds
    const MapPointId p = map.addPoint(Eigen::Vector3d(0, 0, 2), k1);
    map.addObservation(p, k1, idx);
    map.addObservation(p, k2, idx);
    return p;
  };
  const MapPointId first = point(1);
  MapPointId keep = point(2);
  map.replacePoint(first, keep);
  // kMaxReplacements fusions later the first one is forgotten, the last not.
  MapPointId last;
  for (size_t i = 0; i < Map::kMaxReplacements; ++i) {
    last = keep;
    keep = point(1 + i % 2);
    map.replacePoint(last, keep);
  }
  EXPECT_EQ(map.numPoints(), 1u);
  EXPECT_FALSE(map.livePoint(first).valid());
  EXPECT_EQ(map.livePoint(last), keep);
  EXPECT_EQ(map.checkConsistency(), "");
}

}  // namespace
}  // namespace ecar
