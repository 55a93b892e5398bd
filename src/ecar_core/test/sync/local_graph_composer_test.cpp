// The local graph composer: the device mirror (positions sent once, again
// after a reset, a version change, or once the point left the mirrored
// queue), the edgeslam payload, the size of the ecar payload per point, the
// plane resend rules, visible objects and tombstones, stale frames of a
// replaced map, and a whole synthetic session in both sync modes.
#include "ecar_core/sync/local_graph_composer.h"

#include <set>
#include <string>

#include <gtest/gtest.h>

#include "ecar_core/common/error.h"
#include "ecar_core/common/timing.h"
#include "ecar_core/structure/vo_store.h"

namespace ecar {
namespace {

// A keyframe with `n` keypoints and random descriptors.
KeyFrame keyframeWith(int n, DeviceId device) {
  KeyFrame kf;
  kf.camera = std::make_shared<const PinholeCamera>(CameraParams());
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

  static std::vector<MapPointId> positionIds(const LocalGraph& g) {
    std::vector<MapPointId> ids;
    for (const auto& p : g.positions) ids.push_back(p.id);
    return ids;
  }

  // The graph of `r` for a device whose state is `state` (null: none), in the
  // map's current epoch.
  LocalGraph build(const TrackResult& r, SyncMode mode, DeviceSyncState* state,
                   const LocalGraphComposer* with = nullptr, bool reset = false) const {
    ComposerInput in;
    in.device = "device_1";
    in.mode = mode;
    in.frame = &r;
    in.reset = reset;
    {
      auto lock = map.readLock();
      in.map_epoch = map.epoch();
    }
    std::optional<LocalGraph> g = (with ? *with : composer).compose(map, in, lookups, state);
    EXPECT_TRUE(g.has_value());
    return g ? *g : LocalGraph();
  }

  static std::string nameOf(DeviceId id) { return "device_" + std::to_string(id.value); }

  Map map;
  std::vector<KeyFrameId> kfs;
  std::vector<MapPointId> points;
  LocalGraphComposer composer;
  ComposerLookups lookups{nullptr, &LocalGraphTest::nameOf, nullptr};
};

TEST_F(LocalGraphTest, PositionsAreSentOnce) {
  DeviceSyncState mirror(10);
  const auto g1 = build(trackedResult(0, 20), SyncMode::kEcar, &mirror);
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
  const auto g2 = build(trackedResult(10, 20), SyncMode::kEcar, &mirror);
  EXPECT_EQ(g2.points.size(), 20u);
  ASSERT_EQ(g2.positions.size(), 10u);
  EXPECT_EQ(g2.positions.front().id, points[20]);
  EXPECT_EQ(mirror.points().numKeyFrames(), 2u);
  EXPECT_EQ(mirror.points().numPoints(), 30u);
}

TEST_F(LocalGraphTest, PositionsAreSentAgainAfterAReset) {
  DeviceSyncState mirror(10);
  build(trackedResult(0, 20), SyncMode::kEcar, &mirror);
  mirror.resetMap();
  EXPECT_EQ(mirror.points().numPoints(), 0u);
  const auto g = build(trackedResult(0, 20), SyncMode::kEcar, &mirror);
  EXPECT_EQ(g.positions.size(), 20u);
  // Upload.reset does the same.
  EXPECT_TRUE(build(trackedResult(0, 20), SyncMode::kEcar, &mirror).positions.empty());
  EXPECT_EQ(build(trackedResult(0, 20), SyncMode::kEcar, &mirror, nullptr, true).positions.size(),
            20u);
}

TEST_F(LocalGraphTest, PositionsAreSentAgainAfterAVersionChange) {
  DeviceSyncState mirror(10);
  build(trackedResult(0, 20), SyncMode::kEcar, &mirror);
  {
    auto lock = map.writeLock();
    MapPoint* p = map.mutablePoint(points[7]);
    p->p_w.z() = 3.5;
    ++p->version;
  }
  const auto g = build(trackedResult(0, 20), SyncMode::kEcar, &mirror);
  ASSERT_EQ(g.positions.size(), 1u);
  EXPECT_EQ(g.positions[0].id, points[7]);
  EXPECT_FLOAT_EQ(g.positions[0].p_w.z(), 3.5f);
  // Sent once: the next graph does not repeat it.
  EXPECT_TRUE(build(trackedResult(0, 20), SyncMode::kEcar, &mirror).positions.empty());
  // A new version that moved less than the tolerance (1 mm) is not resent.
  {
    auto lock = map.writeLock();
    MapPoint* p = map.mutablePoint(points[7]);
    p->p_w.z() += 0.0004;
    ++p->version;
  }
  EXPECT_TRUE(build(trackedResult(0, 20), SyncMode::kEcar, &mirror).positions.empty());
  LocalGraphComposerConfig exact;
  exact.position_tolerance = 0.0;
  DeviceSyncState mirror2(10);
  const LocalGraphComposer strict(exact);
  build(trackedResult(0, 20), SyncMode::kEcar, &mirror2, &strict);
  {
    auto lock = map.writeLock();
    MapPoint* p = map.mutablePoint(points[7]);
    p->p_w.z() += 0.0004;
    ++p->version;
  }
  EXPECT_EQ(build(trackedResult(0, 20), SyncMode::kEcar, &mirror2, &strict).positions.size(), 1u);
}

TEST_F(LocalGraphTest, DepthMovesWithinTheViewTolerancesAreNotResent) {
  LocalGraphComposerConfig config;
  config.position_tolerance_deg = 0.05;
  config.position_tolerance_depth = 0.02;
  const LocalGraphComposer viewed(config);
  DeviceSyncState mirror(10);
  build(trackedResult(0, 20), SyncMode::kEcar, &mirror, &viewed);  // camera at the origin
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
  const auto g = build(trackedResult(0, 20), SyncMode::kEcar, &mirror, &viewed);
  EXPECT_EQ(positionIds(g), (std::vector<MapPointId>{points[1], points[2]}));
}

TEST_F(LocalGraphTest, PositionsAreSentAgainOnceThePointLeftTheQueue) {
  DeviceSyncState mirror(3);
  build(trackedResult(0, 10), SyncMode::kEcar, &mirror);  // holds 0..9
  // Three keyframes without points 0..4: the first keyframe is evicted, and
  // with it the points only it held; 5..9 stay (held by the later ones).
  for (int i = 0; i < 3; ++i) build(trackedResult(5, 10), SyncMode::kEcar, &mirror);
  EXPECT_EQ(mirror.points().numKeyFrames(), 3u);
  EXPECT_FALSE(mirror.points().holds(points[0]));
  EXPECT_TRUE(mirror.points().holds(points[5]));
  const auto g = build(trackedResult(0, 10), SyncMode::kEcar, &mirror);
  std::vector<MapPointId> expected(points.begin(), points.begin() + 5);
  EXPECT_EQ(positionIds(g), expected);
}

TEST_F(LocalGraphTest, LostFramesAndCulledPointsAreLeftOut) {
  DeviceSyncState mirror(10);
  TrackResult lost = trackedResult(0, 20);
  lost.state = TrackingState::kLost;
  const auto g0 = build(lost, SyncMode::kEcar, &mirror);
  EXPECT_TRUE(g0.points.empty());
  EXPECT_EQ(g0.status, GraphStatus::kLost);
  EXPECT_EQ(mirror.points().numKeyFrames(), 0u);
  {
    auto lock = map.writeLock();
    map.erasePoint(points[2]);
  }
  TrackResult r = trackedResult(0, 20);
  r.tracked.push_back(r.tracked[4]);  // a duplicate id counts once
  const auto g = build(r, SyncMode::kEcar, &mirror);
  EXPECT_EQ(g.points.size(), 19u);
  EXPECT_EQ(g.positions.size(), 19u);
  ComposerInput in;
  in.frame = &r;
  in.map_epoch = 1;
  EXPECT_THROW(composer.compose(map, in, lookups, nullptr), Error);
}

TEST_F(LocalGraphTest, EdgeSlamCarriesTheWholeLocalMap) {
  LocalGraphComposerConfig config;
  config.edgeslam_keyframes = 0;
  const LocalGraphComposer all(config);
  DeviceSyncState state;
  const auto g = build(trackedResult(0, 20), SyncMode::kEdgeSlam, &state, &all);
  EXPECT_TRUE(g.points.empty());
  EXPECT_TRUE(g.positions.empty());
  ASSERT_EQ(g.keyframes.size(), static_cast<size_t>(kKeyFrames));
  EXPECT_EQ(g.map_points.size(), points.size());
  auto lock = map.readLock();
  for (const auto& k : g.keyframes) {
    const KeyFrame* kf = map.keyframe(k.id);
    ASSERT_NE(kf, nullptr);
    EXPECT_EQ(k.device, nameOf(kf->device));
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
  const LocalGraphComposer two(config);
  const auto g2 = build(trackedResult(0, 20), SyncMode::kEdgeSlam, &state, &two);
  EXPECT_EQ(g2.keyframes.size(), 2u);
  EXPECT_EQ(g2.map_points.size(), 25u);
}

// Wire bytes of the ecar payload (ecar_msgs: TrackedPoint 10 B, PointPosition
// 14 B, plus a 4-byte array length each) against edgeslam's (MapPointFull
// 68 B, KeyFrameInfo ids 4 B each): a device that keeps tracking the same
// points gets about 10 B per point in ecar mode.
TEST_F(LocalGraphTest, EcarPayloadPerPointIsSmall) {
  DeviceSyncState mirror(10);
  const auto bytes = [](const LocalGraph& g) {
    size_t b = 8 + 10 * g.points.size() + 14 * g.positions.size();
    b += 8 + 68 * g.map_points.size();
    for (const auto& k : g.keyframes) b += 4 + 56 + 4 + 4 * k.points.size() + 4 + 8;
    return b;
  };
  build(trackedResult(0, 20), SyncMode::kEcar, &mirror);
  size_t total = 0, tracked = 0;
  for (int i = 0; i < 5; ++i) {
    const auto g = build(trackedResult(i, 20), SyncMode::kEcar, &mirror);
    total += bytes(g);
    tracked += g.points.size();
  }
  EXPECT_LE(static_cast<double>(total) / tracked, 20.0);
  DeviceSyncState other;
  const auto edge = build(trackedResult(0, 20), SyncMode::kEdgeSlam, &other);
  EXPECT_GE(bytes(edge), 6 * bytes(build(trackedResult(0, 20), SyncMode::kEcar, &mirror)));
}

// A floor plane (id, version) with a 4 x 2 m boundary offset by `shift` in x.
Plane floorPlane(uint32_t id, uint32_t version, double shift = 0.0, double offset = 0.0) {
  Plane p;
  p.id = PlaneId(id);
  p.label = PlaneLabel::kFloor;
  p.normal = Eigen::Vector3d::UnitZ();
  p.offset = offset;
  p.version = version;
  p.boundary = {
      {shift, -1, -offset}, {shift + 4, -1, -offset}, {shift + 4, 1, -offset}, {shift, 1, -offset}};
  return p;
}

std::vector<PlaneId> planeIds(const LocalGraph& g) {
  std::vector<PlaneId> ids;
  for (const auto& p : g.planes) ids.push_back(p.id);
  return ids;
}

TEST_F(LocalGraphTest, PlanesAreResentOnlyWhenTheyChangeVisiblyOrAsARefresh) {
  LocalGraphComposerConfig config;
  config.plane_refresh = 5;
  const LocalGraphComposer c(config);
  DeviceSyncState state;
  const TrackResult r = trackedResult(0, 20);
  ComposerInput in;
  in.device = "device_1";
  in.frame = &r;
  in.map_epoch = 1;
  std::vector<Plane> planes = {floorPlane(1, 1), floorPlane(2, 1, 10.0)};
  in.planes = &planes;
  auto g = c.compose(map, in, lookups, &state);
  ASSERT_TRUE(g);
  EXPECT_EQ(planeIds(*g), (std::vector<PlaneId>{PlaneId(1), PlaneId(2)}));
  // Re-estimated (new version) but not visibly changed: not resent.
  planes = {floorPlane(1, 2, 0.0, 0.005), floorPlane(2, 2, 10.1)};
  EXPECT_TRUE(c.compose(map, in, lookups, &state)->planes.empty());
  // The offset moves 3 cm, the extent of plane 2 by 0.3 m: both resent at once.
  planes = {floorPlane(1, 3, 0.0, 0.03), floorPlane(2, 3, 10.3)};
  EXPECT_EQ(planeIds(*c.compose(map, in, lookups, &state)),
            (std::vector<PlaneId>{PlaneId(1), PlaneId(2)}));
  // A label change or a 2 degree turn is a visible change too.
  Plane turned = floorPlane(1, 4, 0.0, 0.03);
  turned.normal =
      Eigen::AngleAxisd(2.0 * M_PI / 180.0, Eigen::Vector3d::UnitX()) * Eigen::Vector3d::UnitZ();
  Plane relabelled = floorPlane(2, 4, 10.3);
  relabelled.label = PlaneLabel::kOther;
  planes = {turned, relabelled};
  EXPECT_EQ(planeIds(*c.compose(map, in, lookups, &state)),
            (std::vector<PlaneId>{PlaneId(1), PlaneId(2)}));
  // Unchanged: nothing until the refresh, 5 graphs after each was last sent.
  for (int i = 0; i < 4; ++i) EXPECT_TRUE(c.compose(map, in, lookups, &state)->planes.empty()) << i;
  EXPECT_EQ(planeIds(*c.compose(map, in, lookups, &state)),
            (std::vector<PlaneId>{PlaneId(1), PlaneId(2)}));
  // Upload.reset: the device lost its local map; every plane goes out again.
  EXPECT_TRUE(c.compose(map, in, lookups, &state)->planes.empty());
  in.reset = true;
  EXPECT_EQ(c.compose(map, in, lookups, &state)->planes.size(), 2u);
  // A lost frame carries no planes and does not count as a graph.
  in.reset = false;
  TrackResult lost = r;
  lost.state = TrackingState::kLost;
  in.frame = &lost;
  const uint64_t graphs = state.graphs();
  EXPECT_TRUE(c.compose(map, in, lookups, &state)->planes.empty());
  EXPECT_EQ(state.graphs(), graphs);
}

// A merged map's young floor is fused into the floor it met: the device that
// was sent it is told once, and a stale snapshot of the visible planes that
// still lists it does not send it again.
TEST_F(LocalGraphTest, PlanesTheServerRemovedAreNamedOnceToTheDevicesThatHeldThem) {
  const LocalGraphComposer c;
  DeviceSyncState state, other;
  const TrackResult r = trackedResult(0, 20);
  ComposerInput in;
  in.device = "device_1";
  in.frame = &r;
  in.map_epoch = 1;
  std::set<uint32_t> held_by_server = {1, 3};
  ComposerLookups with_planes = lookups;
  with_planes.plane_exists = [&](PlaneId id) { return held_by_server.count(id.value) > 0; };
  std::vector<Plane> planes = {floorPlane(1, 1), floorPlane(3, 1, 0.0, 0.08)};
  in.planes = &planes;
  ASSERT_EQ(c.compose(map, in, with_planes, &state)->planes.size(), 2u);
  held_by_server.erase(3);
  auto g = c.compose(map, in, with_planes, &state);  // the snapshot still has plane 3
  EXPECT_TRUE(g->planes.empty());
  EXPECT_EQ(g->removed_planes, (std::vector<PlaneId>{PlaneId(3)}));
  EXPECT_EQ(state.numPlanes(), 1u);
  EXPECT_TRUE(c.compose(map, in, with_planes, &state)->removed_planes.empty());
  // A device never sent the plane is not told about it.
  in.device = "device_2";
  EXPECT_TRUE(c.compose(map, in, with_planes, &other)->removed_planes.empty());
  // Without the lookup (a server that never removes planes) nothing is named.
  held_by_server.clear();
  DeviceSyncState third;
  ASSERT_EQ(c.compose(map, in, lookups, &third)->planes.size(), 2u);
  EXPECT_TRUE(c.compose(map, in, lookups, &third)->removed_planes.empty());
}

VirtualObject anchorAt(double x) {
  VirtualObject vo;
  vo.kind = VoKind::kAnchor;
  vo.position = Eigen::Vector3d(x, 0.0, 0.0);
  vo.width = 0.1f;
  vo.owner = "device_2";
  return vo;
}

TEST_F(LocalGraphTest, VisibleObjectsAndTombstonesOfDeletedOnes) {
  VoStoreConfig store_config;
  store_config.database_path = ":memory:";
  VoStore store(store_config);
  const ObjectId a = store.registerObject(anchorAt(1.0)).id;
  const ObjectId b = store.registerObject(anchorAt(2.0)).id;
  ComposerLookups with_store = lookups;
  with_store.objects = [&](const std::vector<ObjectId>& ids) { return store.objects(ids); };
  DeviceSyncState state;
  const TrackResult r = trackedResult(0, 20);
  ComposerInput in;
  in.frame = &r;
  in.map_epoch = 1;
  std::vector<VirtualObject> visible = store.objects({a, b});
  in.objects = &visible;
  auto g = composer.compose(map, in, with_store, &state);
  ASSERT_EQ(g->objects.size(), 2u);
  EXPECT_EQ(state.objects().size(), 2u);
  // b leaves the view: the device keeps it (no tombstone while it lives).
  visible = store.objects({a});
  g = composer.compose(map, in, with_store, &state);
  ASSERT_EQ(g->objects.size(), 1u);
  EXPECT_EQ(g->objects[0].id, a);
  // b is deleted out of view: its tombstone goes out once.
  ASSERT_TRUE(store.remove(b, 1, "device_2").accepted);
  g = composer.compose(map, in, with_store, &state);
  ASSERT_EQ(g->objects.size(), 2u);
  EXPECT_EQ(g->objects[1].id, b);
  EXPECT_TRUE(g->objects[1].deleted);
  EXPECT_EQ(g->objects[1].version, 2u);
  EXPECT_EQ(composer.compose(map, in, with_store, &state)->objects.size(), 1u);
  // Upload.reset keeps what the device was sent: a later deletion of `a` out
  // of view still reaches it.
  in.reset = true;
  composer.compose(map, in, with_store, &state);
  in.reset = false;
  visible.clear();
  ASSERT_TRUE(store.remove(a, 1, "device_2").accepted);
  g = composer.compose(map, in, with_store, &state);
  ASSERT_EQ(g->objects.size(), 1u);
  EXPECT_TRUE(g->objects[0].deleted);
  // VOs shared directly (no objects in graphs): none, and no tombstones.
  DeviceSyncState direct;
  in.objects = nullptr;
  EXPECT_TRUE(composer.compose(map, in, with_store, &direct)->objects.empty());
  EXPECT_TRUE(direct.objects().empty());
}

TEST_F(LocalGraphTest, AHeldObjectWhoseTombstoneWasCompactedGetsOneOfItsOwn) {
  VoStoreConfig store_config;
  store_config.database_path = ":memory:";
  store_config.tombstone_retention = 0.0;
  VoStore store(store_config);
  const ObjectId a = store.registerObject(anchorAt(1.0)).id;
  ComposerLookups with_store = lookups;
  with_store.objects = [&](const std::vector<ObjectId>& ids) { return store.objects(ids); };
  DeviceSyncState state;
  const TrackResult r = trackedResult(0, 20);
  ComposerInput in;
  in.frame = &r;
  in.map_epoch = 1;
  std::vector<VirtualObject> visible = store.objects({a});
  in.objects = &visible;
  ASSERT_EQ(composer.compose(map, in, with_store, &state)->objects.size(), 1u);
  // Deleted out of the device's view and compacted before its next graph.
  visible.clear();
  ASSERT_TRUE(store.remove(a, 1, "device_2").accepted);
  ASSERT_EQ(store.compactTombstones(steadySeconds()), 1u);
  ASSERT_FALSE(store.get(a).has_value());
  auto g = composer.compose(map, in, with_store, &state);
  ASSERT_EQ(g->objects.size(), 1u);
  EXPECT_EQ(g->objects[0].id, a);
  EXPECT_TRUE(g->objects[0].deleted);
  EXPECT_EQ(g->objects[0].version, 2u);  // past the version the device holds
  EXPECT_TRUE(state.objects().empty());
  EXPECT_TRUE(composer.compose(map, in, with_store, &state)->objects.empty());  // once
}

TEST_F(LocalGraphTest, FramesAlignedInAReplacedMapAreDropped) {
  DeviceSyncState state;
  const TrackResult r = trackedResult(0, 20);
  build(r, SyncMode::kEcar, &state);
  EXPECT_EQ(state.points().numPoints(), 20u);
  // A map is loaded (its epoch moves on); a frame aligned before is stale.
  ComposerInput in;
  in.frame = &r;
  in.map_epoch = 1;
  {
    auto lock = map.writeLock();
    map.setCounters(map.nextKeyFrameId(), map.nextPointId(), 7);
  }
  EXPECT_FALSE(composer.compose(map, in, lookups, &state).has_value());
  EXPECT_EQ(state.points().numPoints(), 0u);
  TrackResult lost = r;
  lost.state = TrackingState::kLost;
  in.frame = &lost;
  EXPECT_FALSE(composer.compose(map, in, lookups, &state).has_value());
  // The first frame of the new epoch carries every position again.
  in.frame = &r;
  in.map_epoch = 7;
  const std::optional<LocalGraph> g = composer.compose(map, in, lookups, &state);
  ASSERT_TRUE(g);
  EXPECT_EQ(g->map_epoch, 7u);
  EXPECT_EQ(g->positions.size(), 20u);
}

// A device walks along the map: each upload tracks 20 points 5 further on,
// sees the floor plane and, from the third upload, an object that another
// device moves and then deletes. In ecar mode the positions of points it holds
// never repeat, a reconnect (reset) sends them again, the plane goes out once
// per refresh, the object at each new version and its tombstone once; in
// edgeslam mode every graph carries the whole local map and no positions.
TEST_F(LocalGraphTest, ASyntheticSessionInBothModes) {
  VoStoreConfig store_config;
  store_config.database_path = ":memory:";
  VoStore store(store_config);
  ComposerLookups with_store = lookups;
  with_store.objects = [&](const std::vector<ObjectId>& ids) { return store.objects(ids); };
  LocalGraphComposerConfig config;
  config.plane_refresh = 4;
  const LocalGraphComposer c(config);
  for (const SyncMode mode : {SyncMode::kEcar, SyncMode::kEdgeSlam}) {
    SCOPED_TRACE(toString(mode));
    DeviceSyncState state(3);
    const std::vector<Plane> planes = {floorPlane(1, 1)};
    const ObjectId id = store.registerObject(anchorAt(3.0)).id;
    size_t positions = 0, plane_sends = 0, tombstones = 0;
    std::vector<uint32_t> object_versions;
    for (int upload = 0; upload < 12; ++upload) {
      const int first = std::min(5 * (upload % 6), 5 * (kKeyFrames - 1));
      const TrackResult r = trackedResult(first, 20);
      std::vector<VirtualObject> visible;
      if (upload == 4) {
        ASSERT_TRUE(store.manipulate(id, 1, anchorAt(3.5), "device_2").accepted);
      }
      if (upload == 8) {
        ASSERT_TRUE(store.remove(id, 2, "device_2").accepted);
      }
      if (upload >= 2) {
        for (const auto& vo : store.objects({id})) {
          if (!vo.deleted) visible.push_back(vo);
        }
      }
      ComposerInput in;
      in.device = "device_1";
      in.frame_index = 4 * upload;
      in.mode = mode;
      in.map_epoch = 1;
      in.reset = upload == 6;  // the device reconnected
      in.frame = &r;
      in.planes = &planes;
      in.objects = &visible;
      const std::optional<LocalGraph> g = c.compose(map, in, with_store, &state);
      ASSERT_TRUE(g);
      EXPECT_EQ(g->status, GraphStatus::kOk);
      EXPECT_EQ(g->frame_index, 4u * upload);
      positions += g->positions.size();
      plane_sends += g->planes.size();
      for (const auto& vo : g->objects) {
        if (vo.deleted) {
          ++tombstones;
        } else {
          object_versions.push_back(vo.version);
        }
      }
      if (mode == SyncMode::kEcar) {
        EXPECT_EQ(g->points.size(), 20u);
        EXPECT_TRUE(g->map_points.empty());
        if (upload == 6) {
          EXPECT_EQ(g->positions.size(), 20u);
        }
      } else {
        EXPECT_TRUE(g->points.empty());
        EXPECT_TRUE(g->positions.empty());
        EXPECT_EQ(g->keyframes.size(), static_cast<size_t>(kKeyFrames));
        EXPECT_EQ(g->map_points.size(), points.size());
      }
    }
    if (mode == SyncMode::kEcar) {
      // 20 at the start and 5 new per upload along the map; 20 again after
      // the reset at upload 6 and 5 new per upload after it.
      EXPECT_EQ(positions, 20u + 5u * 5u + 20u + 5u * 5u);
    }
    // The plane: uploads 0 and 4 (refresh every 4), 6 (the reset) and 10.
    EXPECT_EQ(plane_sends, 4u);
    // The object is in view from upload 2 to 7 (version 1, then 2), deleted at 8.
    EXPECT_EQ(object_versions, (std::vector<uint32_t>{1, 1, 2, 2, 2, 2}));
    EXPECT_EQ(tombstones, 1u);
  }
}

TEST(SyncModeTest, ParsesAndPrints) {
  EXPECT_EQ(parseSyncMode("ecar"), SyncMode::kEcar);
  EXPECT_EQ(parseSyncMode("edgeslam"), SyncMode::kEdgeSlam);
  EXPECT_STREQ(toString(SyncMode::kEdgeSlam), "edgeslam");
  EXPECT_THROW(parseSyncMode("full"), Error);
}

}  // namespace
}  // namespace ecar
