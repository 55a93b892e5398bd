// The grid connection: a keyframe's cells on its planes, objects attached to
// their cells by interactions (moved, deleted), and which planes and objects an
// aligned upload sees (grid and keyframe attachment, direct sharing).
#include "ecar_core/server/grid_connection.h"

#include <gtest/gtest.h>

#include "ecar_core/common/error.h"
#include "ecar_core/structure/plane_segmenter.h"
#include "server/structure_fixtures.h"

namespace ecar {
namespace {

using testing::camera640;
using testing::floorKeyFrame;
using testing::lookingAlongX;

VirtualObject lineAt(double x, double y) {
  VirtualObject vo;
  vo.map = MapId(1);  // the first map of the atlas
  vo.start = Eigen::Vector3d(x, y, 0.0);
  vo.end = Eigen::Vector3d(x + 0.3, y, 0.0);
  vo.width = 0.05f;
  return vo;
}

bool holds(const VisibleStructure& v, ObjectId id) {
  for (const auto& o : v.objects) {
    if (o.id == id) return true;
  }
  return false;
}

// A graph with a SLAM system on the 640x480 camera and the floor of keyframe 1
// (seen from x = 0) in its planes and grid.
class GridConnectionTest : public ::testing::Test {
 protected:
  explicit GridConnectionTest(VoAttachMode mode = VoAttachMode::kGrid) : graph(configOf(mode)) {
    graph.addMap(camera640());
  }

  static GlobalGraphConfig configOf(VoAttachMode mode) {
    GlobalGraphConfig c;
    c.vo.database_path = ":memory:";
    c.vo.attach_mode = mode;
    return c;
  }

  KeyFramePlanes segmentFloor(GridConnection* grid, KeyFrameId id, const SE3& T_w_c) {
    PlaneKeyFrameInput input = floorKeyFrame(id, T_w_c);
    input.map = MapId(1);
    KeyFramePlanes k;
    k.keyframe = id;
    k.T_w_c = T_w_c;
    k.map_epoch = graph.epoch();
    k.update = graph.planes().integrate(input, PlaneSegmenter(PlaneConfig()).segment(input));
    k.planes = k.update.keyframe_planes;
    cells = grid->linkKeyFrame(k);
    return k;
  }

  TrackResult frameAt(const SE3& T_w_c, std::vector<KeyFrameId> local = {}) const {
    TrackResult r;
    r.state = TrackingState::kOk;
    r.T_w_c = T_w_c;
    r.local_keyframes = std::move(local);
    r.map_epoch = graph.epoch();
    r.map = MapId(1);
    return r;
  }

  static VoRequest registration(const VirtualObject& vo) {
    VoRequest r;
    r.device = "device_0";
    r.object = vo;
    return r;
  }

  GlobalGraph graph;
  size_t cells = 0;
};

TEST_F(GridConnectionTest, FloorPlaneCellsAndObjectsInGridMode) {
  GridConnection grid(&graph, GridConnectionConfig());
  const SE3 T_w_c = lookingAlongX(0.0);
  const KeyFramePlanes k = segmentFloor(&grid, KeyFrameId(1), T_w_c);
  ASSERT_EQ(k.update.created.size(), 1u);
  EXPECT_GT(cells, 100u);
  EXPECT_EQ(graph.grid().cellsOfKeyFrame(KeyFrameId(1)).size(), cells);
  const std::vector<Plane> planes = graph.planes().planes();
  ASSERT_EQ(planes.size(), 1u);
  EXPECT_EQ(planes[0].label, PlaneLabel::kFloor);

  const VoOutcome near = grid.apply(registration(lineAt(4.0, 0.0)));
  const VoOutcome far = grid.apply(registration(lineAt(25.0, 0.0)));  // beyond the points
  const VoOutcome behind = grid.apply(registration(lineAt(-3.0, 0.0)));
  ASSERT_TRUE(near.accepted && far.accepted && behind.accepted);
  EXPECT_EQ(graph.vos().get(near.id)->owner, "device_0");
  EXPECT_FALSE(graph.grid().cellsOfObject(near.id).empty());  // attached to its cells

  const VisibleStructure v = grid.visible(frameAt(T_w_c, {KeyFrameId(1)}), "device_0");
  EXPECT_TRUE(v.objects_computed);
  ASSERT_EQ(v.planes.size(), 1u);
  EXPECT_EQ(v.planes[0].id, planes[0].id);
  EXPECT_FALSE(v.cells.empty());
  EXPECT_TRUE(holds(v, near.id));
  EXPECT_TRUE(holds(v, far.id));  // 25 m away: the per-point test reaches it
  EXPECT_FALSE(holds(v, behind.id));
  EXPECT_LT(v.milliseconds, 50.0);

  // Turned around, the camera sees the object behind it and not the others.
  SE3 T_back = lookingAlongX(1.0);
  T_back.linear() = Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitZ()) * T_back.linear();
  const VisibleStructure back = grid.visible(frameAt(T_back), "device_0");
  EXPECT_TRUE(holds(back, behind.id));
  EXPECT_FALSE(holds(back, near.id));

  // A moved object is attached to its new cells; a deleted one leaves the graphs.
  VoRequest move = registration(lineAt(4.0, 0.5));
  move.type = VoRequestType::kManipulate;
  move.object_id = near.id;
  move.base_version = 1;
  const std::vector<CellKey> before = graph.grid().cellsOfObject(near.id);
  ASSERT_TRUE(grid.apply(move).accepted);
  EXPECT_NE(graph.grid().cellsOfObject(near.id), before);
  VoRequest remove;
  remove.device = "device_0";
  remove.type = VoRequestType::kDelete;
  remove.object_id = near.id;
  remove.base_version = 2;
  ASSERT_TRUE(grid.apply(remove).accepted);
  EXPECT_TRUE(graph.grid().cellsOfObject(near.id).empty());
  EXPECT_FALSE(holds(grid.visible(frameAt(T_w_c), "device_0"), near.id));
  // A rejected change (unknown id) changes nothing.
  move.object_id = ObjectId(99);
  EXPECT_FALSE(grid.apply(move).accepted);
}

TEST_F(GridConnectionTest, LostFramesAndDirectSharingSeeNoObjects) {
  GridConnectionConfig direct;
  direct.objects = false;
  GridConnection grid(&graph, direct);
  segmentFloor(&grid, KeyFrameId(1), lookingAlongX(0.0));
  ASSERT_TRUE(grid.apply(registration(lineAt(4.0, 0.0))).accepted);
  const VisibleStructure v = grid.visible(frameAt(lookingAlongX(0.0)), "device_0");
  EXPECT_FALSE(v.objects_computed);
  EXPECT_TRUE(v.objects.empty());
  EXPECT_EQ(v.planes.size(), 1u);
  TrackResult lost = frameAt(lookingAlongX(0.0));
  lost.state = TrackingState::kLost;
  const VisibleStructure none = grid.visible(lost, "device_0");
  EXPECT_TRUE(none.planes.empty());
  EXPECT_TRUE(none.cells.empty());
}

class GridConnectionKeyFrameTest : public GridConnectionTest {
 protected:
  GridConnectionKeyFrameTest() : GridConnectionTest(VoAttachMode::kKeyFrame) {}
};

TEST_F(GridConnectionKeyFrameTest, KeyFrameModeFollowsTheLocalKeyFrames) {
  GridConnection grid(&graph, GridConnectionConfig());
  const SE3 T_w_c = lookingAlongX(0.0);
  segmentFloor(&grid, KeyFrameId(1), T_w_c);
  const VoOutcome r = graph.vos().registerObject(lineAt(4.0, 0.0), KeyFrameId(1));
  ASSERT_TRUE(r.accepted);
  EXPECT_TRUE(holds(grid.visible(frameAt(T_w_c, {KeyFrameId(1)}), "device_0"), r.id));
  EXPECT_FALSE(holds(grid.visible(frameAt(T_w_c, {KeyFrameId(2)}), "device_0"), r.id));
  // Without a keyframe in the map a registration is refused with a reason.
  const VoOutcome no = grid.apply(registration(lineAt(4.0, 0.5)));
  EXPECT_FALSE(no.accepted);
  EXPECT_FALSE(no.reason.empty());
  // With one, it hangs on the nearest.
  {
    Map& map = graph.map(MapId(1))->map();
    auto lock = map.writeLock();
    for (double x : {0.0, 6.0}) {
      KeyFrame kf;
      kf.camera = std::make_shared<const PinholeCamera>(camera640());
      kf.T_c_w = lookingAlongX(x).inverse();
      map.addKeyFrame(std::move(kf));
    }
  }
  const VoOutcome hung = grid.apply(registration(lineAt(5.0, 0.0)));
  ASSERT_TRUE(hung.accepted) << hung.reason;
  EXPECT_EQ(graph.vos().keyFrameOf(hung.id), KeyFrameId(2));
}

}  // namespace
}  // namespace ecar
