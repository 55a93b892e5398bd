// The global graph: devices (connect, camera refusal, reconnect, timeout,
// listeners), the map epoch, culled keyframes, VO map bounds, and saving and
// loading the whole map: a fresh server resumes it (creating its SLAM system
// from the file), bad files and paths fail naming the path and change nothing,
// and what was aligned or segmented in the replaced map is dropped.
#include "ecar_core/server/global_graph.h"

#include <fstream>
#include <iterator>

#include <gtest/gtest.h>

#include <chrono>
#include <future>

#include "ecar_core/common/error.h"
#include "ecar_core/server/grid_connection.h"
#include "ecar_core/server/plane_segmentation.h"
#include "ecar_core/slam/map_correction.h"
#include "ecar_core/slam/pose_graph.h"
#include "ecar_core/structure/plane_segmenter.h"
#include "server/structure_fixtures.h"
#include "test_support.h"

namespace ecar {
namespace {

using testing::camera640;
using testing::contains;
using testing::floorKeyFrame;
using testing::lookingAlongX;
using testing::TempDir;

PinholeCamera camera(double fx = 525.0, int width = 640) {
  CameraParams p;
  p.fx = p.fy = fx;
  p.width = width;
  return PinholeCamera(p);
}

GlobalGraphConfig configWith(const std::string& database, uint32_t first_epoch = 1) {
  GlobalGraphConfig c;
  c.vo.database_path = database;
  c.slam.first_epoch = first_epoch;
  return c;
}

struct Recorder : GraphListener {
  int maps = 0;
  std::vector<std::string> added, removed;
  void onMapCreated(MapId, const std::shared_ptr<SlamSystem>&) override { ++maps; }
  void onDeviceAdded(const DeviceInfo& d) override { added.push_back(d.name); }
  void onDeviceRemoved(const DeviceInfo& d) override { removed.push_back(d.name); }
};

TEST(GlobalGraphTest, TheFirstDeviceCreatesTheAtlasAndEachKeepsItsOwnCamera) {
  GlobalGraph graph(configWith(":memory:", 1000));
  Recorder rec;
  graph.addListener(&rec);
  EXPECT_EQ(graph.atlas(), nullptr);
  EXPECT_EQ(graph.epoch(), 1000u);
  const auto a = graph.connect("device_0", camera(), "", 0, 0.0);
  ASSERT_TRUE(a.accepted) << a.message;
  ASSERT_NE(graph.atlas(), nullptr);
  EXPECT_FALSE(graph.hasMap());     // maps come with the first tracked upload
  EXPECT_EQ(graph.epoch(), 1000u);  // the maps start at the server's first epoch
  EXPECT_EQ(a.device.keyframe_queue, 10u);
  EXPECT_EQ(a.device.mode, SyncMode::kEcar);
  const auto b = graph.connect("device_1", camera(600.0), "", 5, 0.0);
  ASSERT_TRUE(b.accepted) << b.message;
  EXPECT_EQ(graph.camera("device_1")->params().fx, 600.0);
  EXPECT_EQ(graph.atlas()->camera(b.device.id).params().fx, 600.0);
  // A map made now tracks each device with its camera.
  const std::shared_ptr<SlamSystem> slam = graph.addMap(camera());
  EXPECT_EQ(slam->camera(b.device.id)->params().fx, 600.0);
  EXPECT_EQ(slam->map().epoch(), 1000u);
  EXPECT_EQ(graph.camera("device_0")->params().fx, 525.0);
  // A reconnect with another camera takes it.
  const auto c = graph.connect("device_1", camera(525.0, 320), "", 5, 0.0, b.device.session);
  ASSERT_TRUE(c.accepted) << c.message;
  EXPECT_EQ(graph.camera("device_1")->width(), 320);
  // Within camera_tolerance (0.5%) of device_0's camera: the same camera object.
  const auto d = graph.connect("device_1", camera(525.5), "edgeslam", 5, 0.0, b.device.session);
  ASSERT_TRUE(d.accepted) << d.message;
  EXPECT_EQ(graph.camera("device_1"), graph.camera("device_0"));
  EXPECT_EQ(d.device.mode, SyncMode::kEdgeSlam);
  EXPECT_EQ(d.device.keyframe_queue, 5u);
  EXPECT_NE(d.device.id, a.device.id);
  EXPECT_EQ(graph.devices().name(d.device.id), "device_1");
  EXPECT_EQ(rec.maps, 1);
  EXPECT_EQ(rec.added, (std::vector<std::string>{"device_0", "device_1"}));
  graph.removeListener(&rec);
}

TEST(GlobalGraphTest, BadNamesAndModesAreRefused) {
  GlobalGraph graph(configWith(":memory:"));
  EXPECT_FALSE(graph.connect("", camera(), "", 0, 0.0).accepted);
  EXPECT_FALSE(graph.connect("0dev", camera(), "", 0, 0.0).accepted);
  EXPECT_FALSE(graph.connect("dev/ice", camera(), "", 0, 0.0).accepted);
  const auto r = graph.connect("device_0", camera(), "full", 0, 0.0);
  EXPECT_FALSE(r.accepted);
  EXPECT_NE(r.message.find("sync_mode"), std::string::npos) << r.message;
  EXPECT_EQ(graph.atlas(), nullptr);  // no SLAM made for a refused device
}

TEST(GlobalGraphTest, ReconnectKeepsTheIdAndTakesTheNewQueue) {
  GlobalGraph graph(configWith(":memory:"));
  Recorder rec;
  graph.addListener(&rec);
  const auto a = graph.connect("device_0", camera(), "", 0, 0.0);
  const auto b = graph.connect("device_0", camera(), "", 3, 1.0, a.device.session);
  EXPECT_TRUE(b.reconnected);
  EXPECT_EQ(b.device.session, a.device.session);
  EXPECT_EQ(b.device.id, a.device.id);
  EXPECT_EQ(graph.devices().device("device_0")->keyframe_queue, 3u);
  EXPECT_EQ(rec.added.size(), 1u);  // no second "added"
  graph.removeListener(&rec);
}

TEST(GlobalGraphTest, SilentDevicesAreDroppedAndMayComeBack) {
  GlobalGraphConfig config = configWith(":memory:");
  config.devices.device_timeout = 10.0;
  GlobalGraph graph(config);
  Recorder rec;
  graph.addListener(&rec);
  const auto a = graph.connect("device_0", camera(), "", 0, 0.0);
  const uint64_t s1 = graph.connect("device_1", camera(), "", 0, 0.0).device.session;
  EXPECT_EQ(graph.touch("device_1", s1, 8.0), SessionCheck::kOk);
  EXPECT_EQ(graph.touch("device_7", s1, 8.0), SessionCheck::kNotConnected);
  EXPECT_TRUE(graph.removeSilent(9.0).empty());
  EXPECT_EQ(graph.removeSilent(12.0), (std::vector<std::string>{"device_0"}));
  EXPECT_EQ(rec.removed, (std::vector<std::string>{"device_0"}));
  EXPECT_FALSE(graph.devices().device("device_0").has_value());
  EXPECT_EQ(graph.touch("device_0", a.device.session, 12.0), SessionCheck::kNotConnected);
  const auto b = graph.connect("device_0", camera(), "", 0, 13.0);
  EXPECT_TRUE(b.accepted);
  EXPECT_FALSE(b.reconnected);
  EXPECT_EQ(b.device.id, a.device.id);
  EXPECT_EQ(graph.disconnect("device_1", s1), SessionCheck::kOk);
  EXPECT_EQ(graph.disconnect("device_1", s1), SessionCheck::kNotConnected);
  EXPECT_EQ(graph.devices().devices().size(), 1u);
  graph.removeListener(&rec);
}

// A node connecting under ever new names must not grow the server for good:
// a device gone without a keyframe is forgotten (id, name, cameras); one whose
// keyframes name it keeps its id, and so does one that connected again.
TEST(GlobalGraphTest, DevicesGoneWithoutKeyFramesAreForgotten) {
  GlobalGraph graph(configWith(":memory:"));
  const auto mapper = graph.connect("mapper", camera(), "", 0, 0.0);
  {
    const std::shared_ptr<SlamSystem> slam =
        graph.map(MapId(1)) ? graph.map(MapId(1)) : graph.addMap(camera());
    auto lock = slam->map().writeLock();
    KeyFrame kf;
    kf.device = mapper.device.id;
    kf.camera = std::make_shared<const PinholeCamera>(camera640());
    kf.T_c_w = lookingAlongX(0.0).inverse();
    slam->map().addKeyFrame(std::move(kf));
  }
  const size_t known = graph.devices().numKnownNames();
  for (int i = 0; i < 50; ++i) {
    const std::string name = "ghost_" + std::to_string(i);
    const auto g = graph.connect(name, camera(500.0 + i), "", 0, 1.0);
    ASSERT_TRUE(g.accepted);
    ASSERT_EQ(graph.disconnect(name, g.device.session), SessionCheck::kOk);
    graph.removeDevice(g.device.id);  // the tracking nodelet does, once idle
    EXPECT_EQ(graph.devices().name(g.device.id), "");
  }
  EXPECT_EQ(graph.devices().numKnownNames(), known);
  // A ghost that comes back is a new device (nothing referred to its old id).
  const auto back = graph.connect("ghost_0", camera(), "", 0, 2.0);
  EXPECT_TRUE(back.accepted);
  EXPECT_GT(back.device.id.value, mapper.device.id.value + 50);
  // The mapper's keyframe names it: it keeps its id and camera when gone.
  ASSERT_EQ(graph.disconnect("mapper", mapper.device.session), SessionCheck::kOk);
  graph.removeDevice(mapper.device.id);
  EXPECT_EQ(graph.devices().name(mapper.device.id), "mapper");
  EXPECT_TRUE(graph.camera("mapper"));
  EXPECT_EQ(graph.connect("mapper", camera(), "", 0, 3.0).device.id, mapper.device.id);
  // A device that connected again before its removal ran keeps everything.
  const auto c = graph.connect("quick", camera(), "", 0, 4.0);
  ASSERT_EQ(graph.disconnect("quick", c.device.session), SessionCheck::kOk);
  const auto c2 = graph.connect("quick", camera(), "", 0, 4.5);
  graph.removeDevice(c.device.id);
  EXPECT_EQ(graph.devices().name(c.device.id), "quick");
  EXPECT_EQ(c2.device.id, c.device.id);
}

// The tracking nodelet calls removeDevice() from its onDeviceRemoved when the
// device's queue is idle, i.e. inside disconnect() and removeSilent() (found by
// the soak: a deadlock of the whole server when devices timed out).
TEST(GlobalGraphTest, RemoveDeviceMayBeCalledFromTheRemovalListener) {
  GlobalGraphConfig config = configWith(":memory:");
  config.devices.device_timeout = 10.0;
  GlobalGraph graph(config);
  struct Remover : GraphListener {
    GlobalGraph* graph;
    void onDeviceRemoved(const DeviceInfo& d) override { graph->removeDevice(d.id); }
  } remover;
  remover.graph = &graph;
  graph.addListener(&remover);
  const auto a = graph.connect("device_0", camera(), "", 0, 0.0);
  graph.connect("device_1", camera(), "", 0, 0.0);
  auto done = std::async(std::launch::async, [&] {
    graph.disconnect("device_0", a.device.session);
    return graph.removeSilent(20.0);
  });
  ASSERT_EQ(done.wait_for(std::chrono::seconds(10)), std::future_status::ready)
      << "deadlock: removeDevice() inside a removal listener";
  EXPECT_EQ(done.get(), (std::vector<std::string>{"device_1"}));
  EXPECT_EQ(graph.devices().numKnownNames(), 0u);  // neither made a keyframe
  graph.removeListener(&remover);
}

TEST(GlobalGraphTest, SessionsGuardLiveDevicesNamesAndCounts) {
  GlobalGraphConfig config = configWith(":memory:");
  config.devices.device_timeout = 10.0;
  config.devices.max_devices = 2;
  GlobalGraph graph(config);
  Recorder rec;
  graph.addListener(&rec);
  const auto a = graph.connect("device_0", camera(), "", 0, 0.0);
  ASSERT_TRUE(a.accepted);
  ASSERT_NE(a.device.session, 0u);
  // Another node taking the live name without the token: refused, the device untouched.
  for (const uint64_t wrong : {uint64_t{0}, a.device.session + 1}) {
    const auto t = graph.connect("device_0", camera(), "edgeslam", 0, 5.0, wrong);
    EXPECT_FALSE(t.accepted);
    EXPECT_NE(t.message.find("another session"), std::string::npos) << t.message;
  }
  EXPECT_EQ(graph.devices().device("device_0")->mode, SyncMode::kEcar);
  // Uploads and disconnects need the token.
  EXPECT_EQ(graph.touch("device_0", a.device.session + 1, 6.0), SessionCheck::kWrongSession);
  EXPECT_EQ(graph.devices().check("device_0", 0), SessionCheck::kWrongSession);
  EXPECT_EQ(graph.disconnect("device_0", 0), SessionCheck::kWrongSession);
  EXPECT_TRUE(graph.devices().device("device_0").has_value());
  EXPECT_EQ(graph.touch("device_0", a.device.session, 6.0), SessionCheck::kOk);
  // Silent for longer than device_timeout: the name may be taken, with a new token.
  const auto b = graph.connect("device_0", camera(), "", 0, 17.0, 0);
  ASSERT_TRUE(b.accepted) << b.message;
  EXPECT_NE(b.device.session, a.device.session);
  EXPECT_EQ(b.device.id, a.device.id);
  EXPECT_EQ(graph.touch("device_0", a.device.session, 17.5), SessionCheck::kWrongSession);
  // Tokens differ between devices.
  const auto c = graph.connect("device_1", camera(), "", 0, 17.0);
  ASSERT_TRUE(c.accepted);
  EXPECT_NE(c.device.session, b.device.session);
  // max_devices: a third is refused; a reconnect of a connected one is not.
  const auto d = graph.connect("device_2", camera(), "", 0, 17.0);
  EXPECT_FALSE(d.accepted);
  EXPECT_NE(d.message.find("max_devices"), std::string::npos) << d.message;
  EXPECT_TRUE(graph.connect("device_1", camera(), "", 0, 17.0, c.device.session).accepted);
  // Reserved names are never devices (with room for one more).
  EXPECT_EQ(graph.disconnect("device_1", c.device.session), SessionCheck::kOk);
  for (const char* name : {"ecar", "rviz", "edge_server", "rosout", "tf"}) {
    const auto r = graph.connect(name, camera(), "", 0, 18.0);
    EXPECT_FALSE(r.accepted) << name;
    EXPECT_NE(r.message.find("reserved"), std::string::npos) << r.message;
  }
  EXPECT_TRUE(graph.connect("rviz_2", camera(), "", 0, 18.0).accepted);
  graph.removeListener(&rec);
}

TEST(GlobalGraphTest, LateListenersGetTheStateReplayed) {
  GlobalGraph graph(configWith(":memory:"));
  graph.connect("device_0", camera(), "", 0, 0.0);
  graph.addMap(camera());
  Recorder rec;
  graph.addListener(&rec);
  EXPECT_EQ(rec.maps, 1);
  EXPECT_EQ(rec.added, (std::vector<std::string>{"device_0"}));
  graph.removeListener(&rec);
}

TEST(GlobalGraphTest, InvalidConfigAndAnUnopenableStoreNameTheProblem) {
  GlobalGraphConfig config = configWith(":memory:");
  config.vo_map_margin = -1.0;
  try {
    GlobalGraph graph(config);
    ADD_FAILURE() << "accepted";
  } catch (const Error& e) {
    EXPECT_TRUE(contains(e.what(), "vo.map_margin")) << e.what();
  }
  try {
    GlobalGraph graph(configWith("/nonexistent_dir_ecar/vo.sqlite"));
    ADD_FAILURE() << "opened";
  } catch (const Error& e) {
    EXPECT_TRUE(contains(e.what(), "nonexistent_dir_ecar")) << e.what();
  }
}

VirtualObject lineAt(double x, double y = 0.2) {
  VirtualObject vo;
  vo.map = MapId(1);  // the first map of the atlas
  vo.start = Eigen::Vector3d(x, y, 0.0);
  vo.end = Eigen::Vector3d(x + 0.3, y, 0.0);
  vo.width = 0.05f;
  return vo;
}

VoRequest registration(const VirtualObject& vo, const std::string& device = "device_0") {
  VoRequest r;
  r.device = device;
  r.object = vo;
  return r;
}

// Planes of keyframe 1 (a floor seen from x = 0) merged into the graph, as
// plane segmentation would, and what it reports. With `slam`, the floor's
// points are made the map's points first (created by the keyframe), as a
// map's plane points are: what refits planes after a correction reads them.
KeyFramePlanes addFloor(GlobalGraph* graph, KeyFrameId id, const SE3& T_w_c,
                        SlamSystem* slam = nullptr) {
  PlaneKeyFrameInput input = floorKeyFrame(id, T_w_c);
  input.map = MapId(1);  // the first map of the atlas
  if (slam) {
    auto lock = slam->map().writeLock();
    for (PlanePoint& p : input.points) p.id = slam->map().addPoint(p.p_w, id);
  }
  KeyFramePlanes out;
  out.keyframe = id;
  out.T_w_c = T_w_c;
  out.map_epoch = graph->epoch();
  out.update = graph->planes().integrate(input, PlaneSegmenter(PlaneConfig()).segment(input));
  out.planes = out.update.keyframe_planes;
  return out;
}

// A server with a floor plane, its keyframe's cells and two objects (one moved).
void fill(GlobalGraph* graph) {
  graph->addMap(camera640());
  GridConnection grid(graph, GridConnectionConfig());
  const KeyFramePlanes k = addFloor(graph, KeyFrameId(1), lookingAlongX(0.0));
  ASSERT_EQ(k.update.created.size(), 1u);
  ASSERT_GT(grid.linkKeyFrame(k), 0u);
  const VoOutcome a = grid.apply(registration(lineAt(2.0)));
  ASSERT_TRUE(a.accepted) << a.reason;
  VoRequest move = registration(lineAt(2.5), "device_1");
  move.type = VoRequestType::kManipulate;
  move.object_id = a.id;
  move.base_version = 1;
  ASSERT_TRUE(grid.apply(move).accepted);
  ASSERT_TRUE(grid.apply(registration(lineAt(4.0))).accepted);
}

TEST(GlobalGraphTest, AFreshServerResumesTheSavedMap) {
  const TempDir dir;
  GlobalGraph first(configWith(dir.file("first.sqlite"), 100));
  fill(&first);
  const MapCounts saved = first.save(dir.file("map.ecarmap"));
  EXPECT_EQ(saved.planes, 1u);
  EXPECT_EQ(saved.objects, 2u);
  EXPECT_EQ(saved.keyframes, 0u);
  EXPECT_GT(saved.bytes, 0u);

  GlobalGraph second(configWith(dir.file("second.sqlite"), 5000));
  ASSERT_FALSE(second.atlas());
  const uint32_t epoch = second.epoch();
  const uint64_t generation = second.generation();
  const MapCounts loaded = second.load(dir.file("map.ecarmap"));
  EXPECT_EQ(loaded.planes, 1u);
  EXPECT_EQ(loaded.objects, 2u);
  ASSERT_TRUE(second.atlas());  // created with the file's camera
  EXPECT_EQ(loaded.maps, 1u);
  EXPECT_EQ(second.atlas()->camera(DeviceId()).params().fx, 525.0);
  EXPECT_NE(second.epoch(), epoch);
  EXPECT_EQ(second.generation(), generation + 1);

  const auto planes1 = first.planes().planes();
  const auto planes2 = second.planes().planes();
  ASSERT_EQ(planes2.size(), 1u);
  EXPECT_EQ(planes2[0].id, planes1[0].id);
  EXPECT_EQ(planes2[0].version, planes1[0].version);
  EXPECT_EQ(planes2[0].normal, planes1[0].normal);
  EXPECT_EQ(planes2[0].boundary, planes1[0].boundary);
  EXPECT_EQ(second.planes().nextId(), first.planes().nextId());
  EXPECT_EQ(second.grid().save(), first.grid().save());
  const auto vos1 = first.vos().allObjects();
  const auto vos2 = second.vos().allObjects();
  ASSERT_EQ(vos2.size(), 2u);
  for (size_t i = 0; i < vos1.size(); ++i) {
    EXPECT_EQ(vos2[i].id, vos1[i].id);
    EXPECT_EQ(vos2[i].version, vos1[i].version);
    EXPECT_EQ(vos2[i].position, vos1[i].position);
    // The objects are attached to their cells again.
    EXPECT_EQ(second.grid().cellsOfObject(vos2[i].id), first.grid().cellsOfObject(vos1[i].id));
  }
  // The planes are cast again: a frame aligned in the loaded map sees the floor.
  GridConnection grid(&second, GridConnectionConfig());
  TrackResult frame;
  frame.state = TrackingState::kOk;
  frame.T_w_c = lookingAlongX(0.0);
  frame.map_epoch = second.epoch();
  frame.map = MapId(1);
  const VisibleStructure now = grid.visible(frame, "device_0");
  EXPECT_FALSE(now.stale);
  EXPECT_EQ(now.planes.size(), 1u);
  EXPECT_EQ(now.objects.size(), 2u);
  // A frame aligned before the load is stale: nothing from the old map is sent.
  frame.map_epoch = epoch;
  const VisibleStructure old = grid.visible(frame, "device_0");
  EXPECT_TRUE(old.stale);
  EXPECT_TRUE(old.planes.empty());
  // A keyframe segmented before the load is dropped; one after is linked.
  KeyFramePlanes before = addFloor(&second, KeyFrameId(2), lookingAlongX(1.0));
  before.map_epoch = epoch;
  EXPECT_EQ(grid.linkKeyFrame(before), 0u);
  EXPECT_EQ(second.grid().numKeyFrames(), 1u);
  before.map_epoch = second.epoch();
  EXPECT_GT(grid.linkKeyFrame(before), 0u);
  EXPECT_EQ(second.grid().numKeyFrames(), 2u);
}

TEST(GlobalGraphTest, BadFilesAndPathsFailNamingThePathAndChangeNothing) {
  const TempDir dir;
  GlobalGraph server(configWith(dir.file("a.sqlite"), 100));
  EXPECT_TRUE(contains(testing::errorOf([&] { server.save(dir.file("m.ecarmap")); }),
                       "no device has connected"));
  fill(&server);
  const std::string good = dir.file("good.ecarmap");
  server.save(good);
  const std::string unwritable = dir.file("no_such_dir/x.ecarmap");
  EXPECT_TRUE(contains(testing::errorOf([&] { server.save(unwritable); }), unwritable));

  // The server now differs from the file: one more object.
  ASSERT_TRUE(server.vos().registerObject(lineAt(5.0)).accepted);
  const uint32_t epoch = server.epoch();
  const uint64_t generation = server.generation();

  std::ifstream in(good, std::ios::binary);
  std::vector<char> bytes((std::istreambuf_iterator<char>(in)), {});
  bytes[bytes.size() - 30] ^= 0x5a;  // inside the last section, "vos"
  const std::string corrupt = dir.file("corrupt.ecarmap");
  std::ofstream(corrupt, std::ios::binary).write(bytes.data(), bytes.size());
  std::string error = testing::errorOf([&] { server.load(corrupt); });
  EXPECT_TRUE(contains(error, corrupt) && contains(error, "section 'vos'")) << error;
  const std::string missing = dir.file("missing.ecarmap");
  error = testing::errorOf([&] { server.load(missing); });
  EXPECT_TRUE(contains(error, missing)) << error;

  EXPECT_EQ(server.vos().numObjects(), 3u);
  EXPECT_EQ(server.epoch(), epoch);
  EXPECT_EQ(server.generation(), generation);

  // A server whose devices have another camera loads the map (its keyframes
  // keep the cameras they were made with: MapIoSlamTest.EachKeyFrameKeepsItsCamera)
  // and keeps its own default camera.
  CameraParams other = camera640().params();
  other.fx = 400.0;
  GlobalGraph foreign(configWith(dir.file("b.sqlite"), 100));
  foreign.addMap(PinholeCamera(other));
  EXPECT_EQ(foreign.load(good).objects, 2u);
  EXPECT_EQ(foreign.vos().numObjects(), 2u);
  EXPECT_EQ(foreign.atlas()->camera(DeviceId()).params().fx, 400.0);
}

// A loop correction moved keyframe 1 by 10 cm up, 0.5 m sideways and 2
// degrees about the vertical: its floor, the object drawn on it and the
// keyframe's cells move with it, the object's new position is in SQLite (a
// fresh store reads it back), and a correction of a replaced map is ignored.
TEST(GlobalGraphTest, AMapCorrectionMovesPlanesObjectsAndCells) {
  const TempDir dir;
  const GlobalGraphConfig config = configWith(dir.file("vo.sqlite"));
  Sim3 C;
  C.R = expSO3(Eigen::Vector3d(0.0, 0.0, 2.0 * M_PI / 180.0));
  C.t = Eigen::Vector3d(0.0, 0.5, 0.1);
  ObjectId id;
  VirtualObject before;
  {
    GlobalGraph graph(config);
    const std::shared_ptr<SlamSystem> slam = graph.addMap(camera640());
    {
      auto lock = slam->map().writeLock();
      KeyFrame kf;
      kf.camera = std::make_shared<const PinholeCamera>(camera640());
      kf.T_c_w = lookingAlongX(0.0).inverse();
      ASSERT_EQ(slam->map().addKeyFrame(std::move(kf)), KeyFrameId(1));
    }
    GridConnection grid(&graph, GridConnectionConfig());
    ASSERT_GT(grid.linkKeyFrame(addFloor(&graph, KeyFrameId(1), lookingAlongX(0.0), slam.get())),
              0u);
    const VoOutcome a = grid.apply(registration(lineAt(2.0)));
    ASSERT_TRUE(a.accepted) << a.reason;
    id = a.id;
    before = *graph.vos().get(id);
    const std::vector<CellKey> cells_before = graph.grid().cellsOfKeyFrame(KeyFrameId(1));
    const Plane floor_before = graph.planes().planes().front();

    MapCorrection correction;
    {
      auto lock = slam->map().writeLock();
      const Sim3 S_old = similarityOf(slam->map().keyframe(KeyFrameId(1))->T_c_w);
      correction = applyCorrection(&slam->map(), {{KeyFrameId(1), S_old}},
                                   {{KeyFrameId(1), S_old * C.inverse()}});
    }
    // A correction of another epoch (a map loaded since) changes nothing.
    MapCorrection stale = correction;
    stale.epoch += 1;
    EXPECT_EQ(graph.applyMapCorrection(MapId(1), stale).objects, 0u);

    const MapCorrectionReport report = graph.applyMapCorrection(MapId(1), correction);
    EXPECT_EQ(report.keyframes, 1u);
    EXPECT_EQ(report.planes, 1u);
    EXPECT_EQ(report.objects, 1u);
    EXPECT_GT(report.keyframe_cells, 0u);
    const Plane floor = graph.planes().planes().front();
    EXPECT_GT(floor.version, floor_before.version);
    EXPECT_LT((floor.normal - C.R * floor_before.normal).norm(), 1e-9);
    // The floor (about z = 0) is now about z = 0.1.
    const Eigen::Vector3d on_floor = C * Eigen::Vector3d(2.0, 1.0, -floor_before.offset);
    EXPECT_NEAR(floor.signedDistance(on_floor), 0.0, 1e-3);
    EXPECT_NEAR(floor.offset, floor_before.offset - 0.1, 1e-3);
    const VirtualObject after = *graph.vos().get(id);
    EXPECT_EQ(after.version, before.version + 1);
    EXPECT_LT((after.start - C * before.start).norm(), 1e-9);
    EXPECT_LT((after.end - C * before.end).norm(), 1e-9);
    EXPECT_NE(graph.grid().cellsOfKeyFrame(KeyFrameId(1)), cells_before);
    EXPECT_FALSE(graph.grid().cellsOfObject(id).empty());
  }
  // What SQLite holds: the moved object.
  VoStoreConfig vo_config = config.vo;
  vo_config.cell_size = config.grid.cell_size;
  VoStore reopened(vo_config);
  const std::optional<VirtualObject> stored = reopened.get(id);
  ASSERT_TRUE(stored.has_value());
  EXPECT_EQ(stored->version, before.version + 1);
  EXPECT_LT((stored->start - C * before.start).norm(), 1e-9);
}

TEST(GlobalGraphTest, CulledKeyFramesLoseTheirLinksAndHandTheirObjectsOn) {
  GlobalGraphConfig config = configWith(":memory:");
  config.vo.attach_mode = VoAttachMode::kKeyFrame;
  GlobalGraph graph(config);
  graph.addMap(camera640());
  GridConnection grid(&graph, GridConnectionConfig());
  const KeyFramePlanes k = addFloor(&graph, KeyFrameId(1), lookingAlongX(0.0));
  ASSERT_GT(grid.linkKeyFrame(k), 0u);
  ASSERT_TRUE(graph.vos().registerObject(lineAt(1.0), KeyFrameId(1)).accepted);
  EXPECT_EQ(graph.eraseKeyFrame(KeyFrameId(1), KeyFrameId(4)), 1u);
  EXPECT_TRUE(graph.grid().cellsOfKeyFrame(KeyFrameId(1)).empty());
  EXPECT_TRUE(graph.planes().planesOfKeyFrame(KeyFrameId(1)).empty());
  EXPECT_EQ(graph.vos().objectsOfKeyFrames({KeyFrameId(4)}).size(), 1u);
}

TEST(GlobalGraphTest, VoBoundsFollowTheKeyFrames) {
  GlobalGraphConfig config = configWith(":memory:");
  config.vo_map_margin = 2.0;
  GlobalGraph graph(config);
  graph.updateVoBounds();  // no map yet: nothing changes
  ASSERT_TRUE(graph.vos().registerObject(lineAt(50.0)).accepted);
  const std::shared_ptr<SlamSystem> slam = graph.addMap(camera640());
  {
    Map& map = slam->map();
    auto lock = map.writeLock();
    for (double x : {0.0, 10.0}) {
      KeyFrame kf;
      kf.camera = std::make_shared<const PinholeCamera>(camera640());
      kf.T_c_w = lookingAlongX(x).inverse();
      map.addKeyFrame(std::move(kf));
    }
  }
  graph.updateVoBounds();
  EXPECT_TRUE(graph.vos().registerObject(lineAt(11.0)).accepted);
  const VoOutcome out = graph.vos().registerObject(lineAt(13.0));
  EXPECT_FALSE(out.accepted);
  EXPECT_EQ(out.code, VoReject::kOutOfMap);
}

}  // namespace
}  // namespace ecar
