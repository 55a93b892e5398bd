// Plane segmentation of mapped keyframes: the floor in a keyframe's points
// becomes a labelled plane of the graph; culled keyframes, keyframes without
// gravity are skipped with the reason. Also the map queries it reads through.
#include "ecar_core/server/plane_segmentation.h"

#include <random>

#include <gtest/gtest.h>

#include "ecar_core/common/error.h"
#include "ecar_core/slam/map_queries.h"
#include "server/structure_fixtures.h"

namespace ecar {
namespace {

using testing::camera640;
using testing::lookingAlongX;

// A graph whose SLAM map has keyframe 1 (at x = 0, looking along x, gravity
// measured) observing noisy floor points over x in [1, 7], and keyframe 2 (at
// x = 3, no gravity) sharing half of them.
class PlaneSegmentationTest : public ::testing::Test {
 protected:
  PlaneSegmentationTest() : graph(configOf()) {
    Map& map = graph.addMap(camera640())->map();
    auto lock = map.writeLock();
    std::vector<Eigen::Vector3d> floor;
    std::mt19937 rng(5);
    std::normal_distribution<double> noise(0.0, 0.01);
    for (double x = 1.0; x <= 7.0; x += 0.1) {
      for (double y = -1.2; y <= 1.2; y += 0.1) floor.emplace_back(x, y, noise(rng));
    }
    const auto keyframeWith = [&](double x, size_t n, bool gravity) {
      KeyFrame kf;
      kf.camera = std::make_shared<const PinholeCamera>(CameraParams());
      const SE3 T_w_c = lookingAlongX(x);
      kf.T_c_w = T_w_c.inverse();
      kf.features.keypoints.resize(n);
      kf.points.resize(n);
      if (gravity)
        kf.features.gravity_c = 9.81 * (T_w_c.linear().transpose() * Eigen::Vector3d::UnitZ());
      return map.addKeyFrame(std::move(kf));
    };
    kf1 = keyframeWith(0.0, floor.size(), true);
    kf2 = keyframeWith(3.0, floor.size() / 2, false);
    for (size_t i = 0; i < floor.size(); ++i) {
      const MapPointId p = map.addPoint(floor[i], kf1);
      map.addObservation(p, kf1, static_cast<int>(i));
      if (i < floor.size() / 2) map.addObservation(p, kf2, static_cast<int>(i));
    }
    map.updateCovisibility(kf1);
    num_points = floor.size();
  }

  static GlobalGraphConfig configOf() {
    GlobalGraphConfig c;
    c.vo.database_path = ":memory:";
    return c;
  }

  GlobalGraph graph;
  KeyFrameId kf1, kf2;
  size_t num_points = 0;
};

TEST_F(PlaneSegmentationTest, TheFloorOfAKeyFrameBecomesALabelledPlane) {
  const PlaneSegmentation segmentation(&graph, PlaneConfig());
  const KeyFramePlanes r = segmentation.process(kf1);
  ASSERT_TRUE(r.done()) << r.skipped;
  EXPECT_EQ(r.points, num_points);
  EXPECT_EQ(r.observations, 1u);
  ASSERT_EQ(r.update.created.size(), 1u);
  EXPECT_EQ(r.planes, r.update.created);
  EXPECT_EQ(r.map_epoch, graph.epoch());
  EXPECT_TRUE(r.T_w_c.isApprox(lookingAlongX(0.0)));
  const std::vector<Plane> planes = graph.planes().planes();
  ASSERT_EQ(planes.size(), 1u);
  EXPECT_EQ(planes[0].label, PlaneLabel::kFloor);
  EXPECT_NEAR(planes[0].normal.z(), 1.0, 1e-3);
  EXPECT_EQ(graph.planes().planesOfKeyFrame(kf1), r.planes);
  // Keyframe 2 has no gravity of its own: with the upload's it is segmented,
  // its points join the same floor.
  EXPECT_EQ(segmentation.process(kf2).skipped, "no gravity");
  const KeyFramePlanes r2 = segmentation.process(kf2, Eigen::Vector3d(0.0, -9.81, 0.0));
  ASSERT_TRUE(r2.done()) << r2.skipped;
  EXPECT_TRUE(r2.update.created.empty());
  EXPECT_EQ(graph.planes().size(), 1u);
  // A culled (or unknown) keyframe is skipped.
  EXPECT_EQ(segmentation.process(KeyFrameId(99)).skipped, "culled");
}

TEST_F(PlaneSegmentationTest, MapQueriesCopyWhatTheModulesNeed) {
  const Map& map = graph.map(MapId(1))->map();
  const std::optional<KeyFrameNeighbourhood> n = keyframeNeighbourhood(map, kf2, 10);
  ASSERT_TRUE(n);
  EXPECT_EQ(n->points.size(), num_points);  // its own half and kf1's (its neighbour)
  EXPECT_FALSE(n->gravity_c.has_value());
  EXPECT_EQ(n->map_epoch, graph.epoch());
  EXPECT_EQ(keyframeNeighbourhood(map, kf2, 0)->points.size(), num_points / 2);
  EXPECT_FALSE(keyframeNeighbourhood(map, KeyFrameId(42), 10));
  const std::optional<KeyFrameSummary> s1 = keyframeSummary(map, kf1);
  ASSERT_TRUE(s1);
  EXPECT_TRUE(s1->gravity_c.has_value());
  EXPECT_TRUE(s1->T_w_c.isApprox(lookingAlongX(0.0)));
  EXPECT_FALSE(keyframeSummary(map, KeyFrameId(42)));
  EXPECT_EQ(nearestKeyFrame(map, Eigen::Vector3d(2.0, 0.0, 1.5)), kf2);
  EXPECT_EQ(nearestKeyFrame(map, Eigen::Vector3d(-5.0, 0.0, 1.5)), kf1);
  EXPECT_FALSE(nearestKeyFrame(map, Eigen::Vector3d(NAN, 0.0, 0.0)).valid());
  const std::optional<Bounds> b = keyframeBounds(map);
  ASSERT_TRUE(b);
  EXPECT_NEAR(b->min.x(), 0.0, 1e-9);
  EXPECT_NEAR(b->max.x(), 3.0, 1e-9);
  const MapOverview o = mapOverview(map);
  EXPECT_EQ(o.points.size(), num_points);
  EXPECT_EQ(o.keyframes.size(), 2u);
  EXPECT_EQ(o.num_keyframes, 2u);
  EXPECT_EQ(mapEpoch(map), graph.epoch());
  EXPECT_FALSE(keyframeBounds(Map(map.scale())));
  EXPECT_FALSE(nearestKeyFrame(Map(map.scale()), Eigen::Vector3d::Zero()).valid());
}

}  // namespace
}  // namespace ecar
