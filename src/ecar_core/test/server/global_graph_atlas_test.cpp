// The global graph's atlas: maps keep their planes, grid links and objects
// apart; a merge moves the merged map's (SQLite first, versions bump, grid
// links re-cast); the map file holds every map, and an object whose map the
// file lacks is kept and reported.
#include <gtest/gtest.h>

#include "ecar_core/io/map_file.h"
#include "ecar_core/io/slam_map_codec.h"
#include "ecar_core/server/global_graph.h"
#include "ecar_core/server/grid_connection.h"
#include "ecar_core/slam/map_merge.h"
#include "ecar_core/structure/plane_segmenter.h"
#include "server/structure_fixtures.h"
#include "test_support.h"

namespace ecar {
namespace {

using testing::camera640;
using testing::floorKeyFrame;
using testing::lookingAlongX;
using testing::TempDir;

GlobalGraphConfig configWith(const std::string& database) {
  GlobalGraphConfig c;
  c.vo.database_path = database;
  return c;
}

KeyFrameId addKeyFrame(SlamSystem* slam, const SE3& T_w_c) {
  auto lock = slam->map().writeLock();
  KeyFrame kf;
  kf.camera = std::make_shared<const PinholeCamera>(camera640());
  kf.T_c_w = T_w_c.inverse();
  return slam->map().addKeyFrame(std::move(kf));
}

// The floor seen by `keyframe` of `map`, integrated and linked to its cells.
KeyFramePlanes addFloor(GlobalGraph* graph, GridConnection* grid, MapId map, KeyFrameId keyframe,
                        const SE3& T_w_c) {
  PlaneKeyFrameInput input = floorKeyFrame(keyframe, T_w_c);
  input.map = map;
  // Point ids of the map's own range (a point is on one plane).
  for (PlanePoint& p : input.points) p.id = MapPointId(p.id.value + (map.value - 1) * 10000000);
  KeyFramePlanes out;
  out.keyframe = keyframe;
  out.T_w_c = T_w_c;
  out.map_epoch = graph->epoch();
  out.update = graph->planes().integrate(input, PlaneSegmenter(PlaneConfig()).segment(input));
  out.planes = out.update.keyframe_planes;
  EXPECT_GT(grid->linkKeyFrame(out), 0u);
  return out;
}

VirtualObject lineIn(MapId map, double x) {
  VirtualObject vo;
  vo.map = map;
  vo.start = Eigen::Vector3d(x, 0.2, 0.0);
  vo.end = Eigen::Vector3d(x + 0.3, 0.2, 0.0);
  vo.width = 0.05f;
  return vo;
}

TrackResult frameIn(const GlobalGraph& graph, MapId map, const SE3& T_w_c) {
  TrackResult r;
  r.state = TrackingState::kOk;
  r.T_w_c = T_w_c;
  r.map_epoch = graph.epoch();
  r.map = map;
  return r;
}

bool sees(const VisibleStructure& v, ObjectId id) {
  for (const VirtualObject& o : v.objects) {
    if (o.id == id) return true;
  }
  return false;
}

Plane planeOf(const GlobalGraph& graph, PlaneId id) {
  for (const Plane& p : graph.planes().planes()) {
    if (p.id == id) return p;
  }
  ADD_FAILURE() << "no plane " << id.value;
  return Plane();
}

// Two maps in their own coordinates (the same floor seen from the same pose
// in each) keep two planes and their own objects; then map 2 merges into map
// 1 through S: its plane and object move (the object in SQLite), its
// keyframe's cells are re-cast, and a device in map 1 sees the object.
TEST(GlobalGraphAtlas, MapsKeepTheirStructureApartAndAMergeMovesIt) {
  const TempDir dir;
  const GlobalGraphConfig config = configWith(dir.file("vo.sqlite"));
  Sim3 S;
  S.R = expSO3(Eigen::Vector3d(0.0, 0.0, 10.0 * M_PI / 180.0));
  S.t = Eigen::Vector3d(2.0, 1.0, 0.0);
  ObjectId in_two;
  VirtualObject before;
  {
    GlobalGraph graph(config);
    MapId one, two;
    const std::shared_ptr<SlamSystem> slam1 = graph.addMap(camera640(), &one);
    const std::shared_ptr<SlamSystem> slam2 = graph.addMap(camera640(), &two);
    ASSERT_EQ(one, MapId(1));
    ASSERT_EQ(two, MapId(2));
    EXPECT_EQ(graph.mapIds().size(), 2u);
    const SE3 pose = lookingAlongX(0.0);
    const KeyFrameId k1 = addKeyFrame(slam1.get(), pose);
    const KeyFrameId k2 = addKeyFrame(slam2.get(), pose);
    EXPECT_NE(k1, k2);  // id ranges of their own
    EXPECT_EQ(graph.mapOfKeyFrame(k2)->map().numKeyFrames(), 1u);
    GridConnection grid(&graph, GridConnectionConfig());
    const KeyFramePlanes p1 = addFloor(&graph, &grid, one, k1, pose);
    const KeyFramePlanes p2 = addFloor(&graph, &grid, two, k2, pose);
    ASSERT_EQ(p1.update.created.size(), 1u);
    ASSERT_EQ(p2.update.created.size(), 1u);  // not joined to map 1's floor
    const PlaneId floor2 = p2.update.created.front();
    const Plane floor2_before = planeOf(graph, floor2);
    EXPECT_EQ(floor2_before.map, two);

    const VoOutcome r = graph.vos().registerObject(lineIn(two, 3.0));
    ASSERT_TRUE(r.accepted) << r.reason;
    in_two = r.id;
    before = *graph.vos().get(in_two);
    graph.grid().attachObject(before, 0.1, 0.05);
    EXPECT_TRUE(sees(grid.visible(frameIn(graph, two, pose), "device_0"), in_two));
    // The same pose in map 1 is another place: the object is not there.
    const VisibleStructure in_one = grid.visible(frameIn(graph, one, pose), "device_0");
    EXPECT_FALSE(sees(in_one, in_two));
    ASSERT_EQ(in_one.planes.size(), 1u);
    EXPECT_EQ(in_one.planes.front().map, one);
    const std::vector<CellKey> cells_before = graph.grid().cellsOfKeyFrame(k2);

    // The SLAM maps merge (as the atlas merges them), then the graph.
    MergeResult merged;
    {
      auto l1 = slam1->map().writeLock();
      auto l2 = slam2->map().writeLock();
      merged = mergeMaps(&slam1->map(), &slam2->map(), S, {});
    }
    MergeEvent event;
    event.into = one;
    event.from = two;
    event.S = S;
    event.correction = merged.correction;
    graph.applyMerge(event);
    graph.finishMerges();

    const Plane floor2_after = planeOf(graph, floor2);
    EXPECT_EQ(floor2_after.map, one);
    EXPECT_EQ(floor2_after.version, floor2_before.version + 1);
    EXPECT_LT((floor2_after.boundary.front() - S * floor2_before.boundary.front()).norm(), 1e-9);
    const VirtualObject after = *graph.vos().get(in_two);
    EXPECT_EQ(after.map, one);
    EXPECT_EQ(after.version, before.version + 1);
    EXPECT_LT((after.start - S * before.start).norm(), 1e-9);
    const std::vector<CellKey> cells_after = graph.grid().cellsOfKeyFrame(k2);
    EXPECT_FALSE(cells_after.empty());
    EXPECT_NE(cells_after, cells_before);
    // A device in map 1 where map 2's keyframe now is sees the object.
    const SE3 moved = slam1->map().keyframe(k2)->T_w_c();
    EXPECT_TRUE(sees(grid.visible(frameIn(graph, one, moved), "device_0"), in_two));
  }
  // SQLite holds the moved object in its new map.
  VoStoreConfig vo = config.vo;
  vo.cell_size = config.grid.cell_size;
  const VoStore reopened(vo);
  const std::optional<VirtualObject> stored = reopened.get(in_two);
  ASSERT_TRUE(stored.has_value());
  EXPECT_EQ(stored->map, MapId(1));
  EXPECT_LT((stored->start - S * before.start).norm(), 1e-9);
}

// A registration names the map its coordinates are in; one made in a map that
// is not the requester's current map (it merged since) is refused, not put in
// the wrong coordinates. rviz (not a device) draws in the largest map.
TEST(GlobalGraphAtlas, ARequestFromAMergedMapIsRefused) {
  GlobalGraph graph(configWith(":memory:"));
  MapId one, two;
  const std::shared_ptr<SlamSystem> slam1 = graph.addMap(camera640(), &one);
  const std::shared_ptr<SlamSystem> slam2 = graph.addMap(camera640(), &two);
  addKeyFrame(slam1.get(), lookingAlongX(0.0));
  for (double x : {0.0, 1.0}) addKeyFrame(slam2.get(), lookingAlongX(x));
  ASSERT_EQ(graph.largestMap(), two);
  GridConnection grid(&graph, GridConnectionConfig());
  VoRequest r;
  r.device = "rviz";
  r.object = lineIn(one, 2.0);
  const VoOutcome stale = grid.apply(r);
  EXPECT_FALSE(stale.accepted);
  EXPECT_EQ(stale.code, VoReject::kStaleMap);
  EXPECT_NE(stale.reason.find("map 1"), std::string::npos) << stale.reason;
  EXPECT_EQ(graph.vos().numObjects(), 0u);
  r.object.map = two;
  const VoOutcome ok = grid.apply(r);
  ASSERT_TRUE(ok.accepted) << ok.reason;
  EXPECT_EQ(graph.vos().get(ok.id)->map, two);
  r.object.map = MapId();  // not given: the requester's current map
  const VoOutcome current = grid.apply(r);
  ASSERT_TRUE(current.accepted) << current.reason;
  EXPECT_EQ(graph.vos().get(current.id)->map, two);
}

// Every map goes into the file with its id; the larger map is the "slam"
// section (what a one-map reader reads); an object of a map the file lacks is
// kept and listed.
TEST(GlobalGraphAtlas, TheMapFileHoldsEveryMapAndReportsOrphanObjects) {
  const TempDir dir;
  const std::string file = dir.file("atlas.ecarmap");
  std::vector<KeyFrameId> saved_two;
  ObjectId orphan, kept;
  {
    GlobalGraph graph(configWith(dir.file("a.sqlite")));
    MapId one, two;
    const std::shared_ptr<SlamSystem> slam1 = graph.addMap(camera640(), &one);
    const std::shared_ptr<SlamSystem> slam2 = graph.addMap(camera640(), &two);
    addKeyFrame(slam1.get(), lookingAlongX(0.0));
    for (double x : {0.0, 1.0}) saved_two.push_back(addKeyFrame(slam2.get(), lookingAlongX(x)));
    GridConnection grid(&graph, GridConnectionConfig());
    addFloor(&graph, &grid, two, saved_two.front(), lookingAlongX(0.0));
    kept = graph.vos().registerObject(lineIn(two, 2.0)).id;
    orphan = graph.vos().registerObject(lineIn(MapId(7), 2.5)).id;
    ASSERT_TRUE(kept.valid() && orphan.valid());
    const MapCounts saved = graph.save(file);
    EXPECT_EQ(saved.maps, 2u);
    EXPECT_EQ(saved.keyframes, 3u);
  }
  // A one-map reader gets the larger map.
  const MapFileReader reader = MapFileReader::open(file);
  EXPECT_EQ(decodeSlamMap(reader.reader(kSlamSection), ScaleInfo::fromConfig(OrbConfig()))
                ->numKeyFrames(),
            2u);

  GlobalGraph loaded(configWith(dir.file("b.sqlite")));
  const MapCounts counts = loaded.load(file);
  EXPECT_EQ(counts.maps, 2u);
  EXPECT_EQ(counts.orphan_objects, std::vector<ObjectId>{orphan});
  std::vector<MapId> ids = loaded.mapIds();
  std::sort(ids.begin(), ids.end());
  ASSERT_EQ(ids, (std::vector<MapId>{MapId(1), MapId(2)}));
  const std::shared_ptr<SlamSystem> two = loaded.map(MapId(2));
  ASSERT_TRUE(two);
  EXPECT_EQ(two->map().keyframeIds().size(), 2u);
  for (const KeyFrameId k : saved_two) {
    EXPECT_NE(two->map().keyframe(k), nullptr) << k.value;
    EXPECT_EQ(loaded.mapOfKeyFrame(k), two);
  }
  EXPECT_EQ(loaded.planes().planes().front().map, MapId(2));
  EXPECT_EQ(loaded.vos().get(kept)->map, MapId(2));
  ASSERT_TRUE(loaded.vos().get(orphan).has_value());  // kept, never silently dropped
  EXPECT_EQ(loaded.vos().get(orphan)->map, MapId(7));
  // New maps take ids after the loaded ones, with keyframe ids of their own.
  MapId third;
  const std::shared_ptr<SlamSystem> slam3 = loaded.addMap(camera640(), &third);
  EXPECT_EQ(third, MapId(3));
  EXPECT_EQ(loaded.mapOfKeyFrame(addKeyFrame(slam3.get(), lookingAlongX(0.0))), slam3);
}

}  // namespace
}  // namespace ecar
