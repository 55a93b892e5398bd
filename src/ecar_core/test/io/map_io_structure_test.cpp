// Map files, the structure sections: planes, grid links and virtual objects
// round trip exactly (into a PlaneMap, a GridMap and an SQLite-backed VoStore
// that keeps them after a reopen), and a damaged, truncated or other-version
// file is rejected with an error naming the section while nothing changes.
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "ecar_core/common/error.h"
#include "ecar_core/io/map_file.h"
#include "ecar_core/io/slam_map_codec.h"
#include "ecar_core/io/structure_codec.h"
#include "ecar_core/structure/grid_caster.h"
#include "ecar_core/structure/grid_cells.h"
#include "ecar_core/structure/grid_map.h"
#include "ecar_core/structure/plane_map.h"
#include "ecar_core/structure/vo_store.h"
#include "test_support.h"

namespace ecar {
namespace {

using ecar::testing::contains;
using ecar::testing::errorOf;
using ecar::testing::readBytes;
using ecar::testing::TempDir;
using ecar::testing::writeBytes;

namespace fs = std::filesystem;

// Two planes (a floor and a wall) with points, boundaries and keyframe links;
// the id counter is past a plane merged away (id 3).
std::vector<PlaneRecord> samplePlanes() {
  PlaneRecord floor;
  floor.plane.id = PlaneId(1);
  floor.plane.label = PlaneLabel::kFloor;
  floor.plane.normal = Eigen::Vector3d::UnitZ();
  floor.plane.offset = 1.25;
  floor.plane.boundary = {{0, 0, -1.25}, {2, 0, -1.25}, {2, 3, -1.25}, {0, 3, -1.25}};
  floor.plane.version = 7;
  for (uint32_t i = 1; i <= 5; ++i) floor.points.push_back({MapPointId(i), {0.1 * i, 0.2, -1.25}});
  floor.keyframes = {KeyFrameId(2), KeyFrameId(5)};
  PlaneRecord wall;
  wall.plane.id = PlaneId(4);
  wall.plane.label = PlaneLabel::kWall;
  wall.plane.normal = Eigen::Vector3d(1, 1, 0).normalized();
  wall.plane.offset = -0.5;
  wall.plane.boundary = {{0.5, -0.2, 0}, {0.6, -0.1, 0}, {0.6, -0.1, 1}};
  wall.plane.version = 2;
  for (uint32_t i = 10; i < 13; ++i) wall.points.push_back({MapPointId(i), {0.3, 0.4, 0.01 * i}});
  wall.keyframes = {KeyFrameId(5)};
  for (PlaneRecord* r : {&floor, &wall}) {
    r->plane.num_points = static_cast<uint32_t>(r->points.size());
  }
  return {floor, wall};
}

GridLinks sampleGrid() {
  return {{KeyFrameId(2), {CellKey{0, 0, -13}, CellKey{1, 0, -13}, CellKey{-4, 7, -13}}},
          {KeyFrameId(5), {CellKey{3, 2, 1}}},
          {KeyFrameId(9), {}}};
}

VirtualObject line(double x) {
  VirtualObject vo;
  vo.kind = VoKind::kLine;
  vo.start = {x, 0.5, -1.25};
  vo.end = {x + 0.3, 0.5, -1.25};
  vo.r = 200;
  vo.g = 10;
  vo.b = 30;
  vo.width = 0.03f;
  vo.normal = Eigen::Vector3d::UnitZ();
  vo.plane = PlaneId(1);
  vo.owner = "device_0";
  return vo;
}

VoStoreConfig storeConfig(const std::string& path) {
  VoStoreConfig c;
  c.database_path = path;
  return c;
}

// A store with a line moved twice (by two editors), an anchor hanging on a
// keyframe, and a deleted line (a tombstone).
void fillStore(VoStore* store) {
  const VoOutcome a = store->registerObject(line(0.0), KeyFrameId(2));
  ASSERT_TRUE(a.accepted) << a.reason;
  ASSERT_TRUE(store->manipulate(a.id, 1, line(0.5), "device_1").accepted);
  ASSERT_TRUE(store->manipulate(a.id, 2, line(0.6), "device_1").accepted);
  VirtualObject anchor;
  anchor.kind = VoKind::kAnchor;
  anchor.position = {1.0, 2.0, -1.25};
  anchor.width = 0.0f;
  anchor.owner = "rviz";
  ASSERT_TRUE(store->registerObject(anchor, KeyFrameId(5)).accepted);
  const VoOutcome c = store->registerObject(line(1.5));
  ASSERT_TRUE(c.accepted);
  ASSERT_TRUE(store->remove(c.id, 1, "device_0").accepted);
}

void expectSamePlanes(const std::vector<PlaneRecord>& a, const std::vector<PlaneRecord>& b) {
  ASSERT_EQ(a.size(), b.size());
  for (size_t i = 0; i < a.size(); ++i) {
    const Plane &p = a[i].plane, &q = b[i].plane;
    EXPECT_EQ(p.id, q.id);
    EXPECT_EQ(p.label, q.label);
    EXPECT_EQ(p.normal, q.normal);
    EXPECT_EQ(p.offset, q.offset);
    EXPECT_EQ(p.version, q.version);
    EXPECT_EQ(p.num_points, q.num_points);
    EXPECT_EQ(p.boundary, q.boundary);
    ASSERT_EQ(a[i].points.size(), b[i].points.size());
    for (size_t k = 0; k < a[i].points.size(); ++k) {
      EXPECT_EQ(a[i].points[k].id, b[i].points[k].id);
      EXPECT_EQ(a[i].points[k].p_w, b[i].points[k].p_w);
    }
    EXPECT_EQ(a[i].keyframes, b[i].keyframes);
  }
}

void expectSameVos(const VoSnapshot& a, const VoSnapshot& b) {
  EXPECT_EQ(a.next_id, b.next_id);
  ASSERT_EQ(a.objects.size(), b.objects.size());
  for (size_t i = 0; i < a.objects.size(); ++i) {
    const VirtualObject &p = a.objects[i].vo, &q = b.objects[i].vo;
    EXPECT_EQ(p.id, q.id);
    EXPECT_EQ(p.kind, q.kind);
    EXPECT_EQ(p.position, q.position);
    EXPECT_EQ(p.start, q.start);
    EXPECT_EQ(p.end, q.end);
    EXPECT_EQ(std::make_tuple(p.r, p.g, p.b), std::make_tuple(q.r, q.g, q.b));
    EXPECT_EQ(p.width, q.width);
    EXPECT_EQ(p.normal, q.normal);
    EXPECT_EQ(p.plane, q.plane);
    EXPECT_EQ(p.owner, q.owner);
    EXPECT_EQ(p.version, q.version);
    EXPECT_EQ(p.deleted, q.deleted);
    EXPECT_EQ(a.objects[i].keyframe, b.objects[i].keyframe);
    EXPECT_EQ(a.objects[i].last_editor, b.objects[i].last_editor);
    EXPECT_EQ(a.objects[i].editor_since, b.objects[i].editor_since);
  }
}

// The structure of `planes`, `grid` and `store` in a map file at `path`.
void saveStructure(const PlaneMap& planes, const GridMap& grid, const VoStore& store,
                   const std::string& path) {
  StructureState state;
  state.planes = planes.save();
  state.next_plane_id = planes.nextId();
  state.grid = grid.save();
  state.vos = store.snapshot();
  MapFileWriter writer;
  writer.addSection("slam", {1, 2, 3});  // not read here
  addStructureSections(&writer, state);
  writer.write(path);
}

// Reads every section first, then swaps them in (the server's order).
void loadStructure(const std::string& path, PlaneMap* planes, GridMap* grid, VoStore* store) {
  const StructureState state = readStructureSections(MapFileReader::open(path));
  store->replaceAll(state.vos);
  planes->load(state.planes, state.next_plane_id);
  grid->load(state.grid);
  grid->attachObjects(store->allObjects(), store->config().cell_size,
                      store->config().attach_margin);
}

TEST(MapIoStructure, RoundTripKeepsEverythingAndSurvivesReopening) {
  const TempDir dir;
  PlaneMap planes{PlaneConfig()};
  planes.load(samplePlanes(), 6);
  GridMap grid;
  grid.load(sampleGrid());
  VoStore store(storeConfig(dir.file("a.sqlite")));
  fillStore(&store);
  ASSERT_EQ(store.numObjects(), 3u);
  saveStructure(planes, grid, store, dir.file("map.ecar"));

  // A fresh server: other contents, replaced by the file's.
  PlaneMap planes2{PlaneConfig()};
  GridMap grid2;
  grid2.setKeyFrameCells(KeyFrameId(77), {CellKey{9, 9, 9}});
  {
    VoStore store2(storeConfig(dir.file("b.sqlite")));
    ASSERT_TRUE(store2.registerObject(line(3.0)).accepted);
    loadStructure(dir.file("map.ecar"), &planes2, &grid2, &store2);

    expectSamePlanes(planes.save(), planes2.save());
    EXPECT_EQ(planes2.nextId(), 6u);
    EXPECT_EQ(planes2.planesOfKeyFrame(KeyFrameId(5)),
              (std::vector<PlaneId>{PlaneId(1), PlaneId(4)}));
    EXPECT_EQ(planes2.planeOfPoint(MapPointId(11)), PlaneId(4));
    EXPECT_EQ(grid.save(), grid2.save());
    EXPECT_TRUE(grid2.cellsOfKeyFrame(KeyFrameId(77)).empty());
    EXPECT_EQ(grid2.keyframesOfCell(CellKey{3, 2, 1}), std::vector<KeyFrameId>{KeyFrameId(5)});
    expectSameVos(store.snapshot(), store2.snapshot());
    EXPECT_EQ(store2.numLive(), 2u);
    // Attachments are rebuilt: the moved line is in its new cells, on its keyframe.
    const VirtualObject moved = *store2.get(ObjectId(1));
    EXPECT_EQ(moved.version, 3u);
    EXPECT_EQ(grid2.cellsOfObject(ObjectId(1)),
              attachmentCells(*store.get(ObjectId(1)), 0.1, store.config().attach_margin));
    EXPECT_EQ(grid2.objectsInCells({cellOf(moved.position, 0.1)}).size(), 1u);
    EXPECT_EQ(store2.objectsOfKeyFrames({KeyFrameId(5)}).size(), 1u);
    EXPECT_TRUE(grid2.cellsOfObject(ObjectId(3)).empty());  // the tombstone
    // device_1 keeps its stale-base allowance: a drag continues from version 2.
    EXPECT_TRUE(store2.manipulate(ObjectId(1), 2, line(0.7), "device_1").accepted);
  }
  // Reopened (a restart after kill -9): the loaded objects, the id counter
  // (the store's own registration had id 1, the file's counter is 4).
  VoStore reopened(storeConfig(dir.file("b.sqlite")));
  EXPECT_EQ(reopened.numObjects(), 3u);
  EXPECT_EQ(reopened.get(ObjectId(1))->version, 4u);
  EXPECT_EQ(reopened.get(ObjectId(2))->owner, "rviz");
  EXPECT_TRUE(reopened.get(ObjectId(3))->deleted);
  EXPECT_EQ(reopened.nextId(), ObjectId(4));
  EXPECT_EQ(reopened.registerObject(line(2.0)).id, ObjectId(4));
}

TEST(MapIoStructure, IdsAreNeverReusedByALoad) {
  VoStore store(storeConfig(":memory:"));
  for (int i = 0; i < 6; ++i) ASSERT_TRUE(store.registerObject(line(0.1 * i)).accepted);
  VoSnapshot older;
  older.next_id = ObjectId(2);
  older.objects.push_back(VoRecord{line(0.0), KeyFrameId(), "device_0", 0});
  older.objects[0].vo.id = ObjectId(1);
  older.objects[0].vo.version = 1;
  older.objects[0].vo.position = (older.objects[0].vo.start + older.objects[0].vo.end) / 2;
  store.replaceAll(older);
  EXPECT_EQ(store.numObjects(), 1u);
  EXPECT_EQ(store.nextId(), ObjectId(7));
}

// A copy of `bytes` with the byte at `offset` flipped.
std::vector<uint8_t> flipped(std::vector<uint8_t> bytes, size_t offset) {
  bytes.at(offset) ^= 0x5a;
  return bytes;
}

class Damaged : public ::testing::Test {
 protected:
  void SetUp() override {
    PlaneMap planes{PlaneConfig()};
    planes.load(samplePlanes(), 6);
    GridMap grid;
    grid.load(sampleGrid());
    VoStore store(storeConfig(":memory:"));
    fillStore(&store);
    saveStructure(planes, grid, store, dir_.file("good.ecar"));
    good_ = readBytes(dir_.file("good.ecar"));

    // The running server's state that a bad file must leave untouched.
    live_planes_.load({samplePlanes()[1]}, 9);
    live_grid_.setKeyFrameCells(KeyFrameId(3), {CellKey{1, 1, 1}});
    live_store_ = std::make_unique<VoStore>(storeConfig(dir_.file("live.sqlite")));
    ASSERT_TRUE(live_store_->registerObject(line(4.0)).accepted);
    before_planes_ = live_planes_.save();
    before_grid_ = live_grid_.save();
    before_vos_ = live_store_->snapshot();
  }

  // Loads `bytes` as a file; returns the error text.
  std::string loadError(const std::vector<uint8_t>& bytes) {
    const std::string path = dir_.file("bad.ecar");
    writeBytes(path, bytes);
    return errorOf([&] { loadStructure(path, &live_planes_, &live_grid_, live_store_.get()); });
  }

  void expectUntouched() {
    expectSamePlanes(before_planes_, live_planes_.save());
    EXPECT_EQ(live_planes_.nextId(), 9u);
    EXPECT_EQ(before_grid_, live_grid_.save());
    expectSameVos(before_vos_, live_store_->snapshot());
    live_store_.reset();  // and the database too
    VoStore reopened(storeConfig(dir_.file("live.sqlite")));
    expectSameVos(before_vos_, reopened.snapshot());
  }

  // Byte offset of a section's contents in the good file.
  size_t sectionStart(const std::string& name) const {
    // Sections are back to back in table order, after the header, to the end.
    const MapFileReader file = MapFileReader::parse(good_, "good");
    size_t total = 0;
    for (const std::string& s : file.sectionNames()) total += file.section(s).size();
    size_t offset = good_.size() - total;
    for (const std::string& s : file.sectionNames()) {
      if (s == name) return offset;
      offset += file.section(s).size();
    }
    ADD_FAILURE() << "no section " << name;
    return 0;
  }

  TempDir dir_;
  std::vector<uint8_t> good_;
  PlaneMap live_planes_{PlaneConfig()};
  GridMap live_grid_;
  std::unique_ptr<VoStore> live_store_;
  std::vector<PlaneRecord> before_planes_;
  GridLinks before_grid_;
  VoSnapshot before_vos_;
};

TEST_F(Damaged, CorruptByteInEachSectionNamesItAndChangesNothing) {
  for (const char* section : {"planes", "grid", "vos"}) {
    SCOPED_TRACE(section);
    const std::string error = loadError(flipped(good_, sectionStart(section) + 9));
    EXPECT_TRUE(contains(error, std::string("section '") + section + "'")) << error;
    EXPECT_TRUE(contains(error, "CRC")) << error;
  }
  expectUntouched();
}

TEST_F(Damaged, TruncatedFileIsRejected) {
  std::vector<uint8_t> cut(good_.begin(), good_.end() - 20);
  const std::string error = loadError(cut);
  EXPECT_TRUE(contains(error, "section 'vos'") && contains(error, "truncated")) << error;
  expectUntouched();
}

TEST_F(Damaged, OtherSectionVersionOrMissingSectionIsRejected) {
  // A "grid" section of version 2, with a valid CRC: rejected by its decoder.
  const MapFileReader file = MapFileReader::parse(good_, "good");
  MapFileWriter writer;
  for (const std::string& s : file.sectionNames()) {
    std::vector<uint8_t> bytes = file.section(s);
    if (s == "grid") bytes[0] = 2;
    writer.addSection(s, bytes);
  }
  std::string error = loadError(writer.serialize());
  EXPECT_TRUE(contains(error, "section 'grid'") && contains(error, "version 2")) << error;

  MapFileWriter partial;
  for (const std::string& s : file.sectionNames()) {
    if (s != "vos") partial.addSection(s, file.section(s));
  }
  error = loadError(partial.serialize());
  EXPECT_TRUE(contains(error, "no section 'vos'")) << error;
  expectUntouched();
}

TEST_F(Damaged, InconsistentContentsNameTheField) {
  // A plane point held by two planes, written with valid CRCs.
  std::vector<PlaneRecord> planes = samplePlanes();
  planes[1].points.push_back(planes[0].points[0]);
  MapFileWriter writer;
  writer.addSection(kPlanesSection, encodePlanes(planes, 6));
  writer.addSection(kGridSection, encodeGrid(sampleGrid()));
  writer.addSection(kVosSection, encodeVos(before_vos_));
  std::string error = loadError(writer.serialize());
  EXPECT_TRUE(contains(error, "section 'planes'") && contains(error, "plane 4") &&
              contains(error, "point id"))
      << error;

  // An object id at the id counter.
  VoSnapshot vos = before_vos_;
  vos.next_id = vos.objects.back().vo.id;
  MapFileWriter writer2;
  writer2.addSection(kPlanesSection, encodePlanes(samplePlanes(), 6));
  writer2.addSection(kGridSection, encodeGrid(sampleGrid()));
  writer2.addSection(kVosSection, encodeVos(vos));
  error = loadError(writer2.serialize());
  EXPECT_TRUE(contains(error, "section 'vos'") && contains(error, "id counter")) << error;
  expectUntouched();
}

TEST(MapIoStructure, ReplaceAllRefusesABadSnapshotWithoutChanges) {
  VoStore store(storeConfig(":memory:"));
  ASSERT_TRUE(store.registerObject(line(0.0)).accepted);
  VoSnapshot bad = store.snapshot();
  bad.objects.push_back(bad.objects[0]);  // the same id twice
  const std::string error = errorOf([&] { store.replaceAll(bad); });
  EXPECT_TRUE(contains(error, "object 1 appears twice")) << error;
  EXPECT_EQ(store.numObjects(), 1u);
  EXPECT_EQ(store.nextId(), ObjectId(2));
}

TEST(MapIoStructure, SlamCameraIsReadFromTheSection) {
  CameraParams c;
  c.width = 320;
  c.height = 240;
  c.fx = 300.5;
  c.dist = {0.1, -0.01, 0, 0, 0.001};
  ByteWriter out;
  out.u32(1);
  out.i32(c.width);
  out.i32(c.height);
  for (const double v : {c.fx, c.fy, c.cx, c.cy}) out.f64(v);
  for (const double v : c.dist) out.f64(v);
  const std::vector<uint8_t> bytes = out.release();
  const PinholeCamera camera = decodeSlamCamera(ByteReader(bytes.data(), bytes.size(), "test"));
  EXPECT_EQ(camera.params().width, 320);
  EXPECT_EQ(camera.params().fx, 300.5);
  EXPECT_EQ(camera.params().dist, c.dist);
}

}  // namespace
}  // namespace ecar
