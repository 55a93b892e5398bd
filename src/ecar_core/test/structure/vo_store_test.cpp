// The VO store: registration, manipulation, deletion and their versions; every
// rejection and its reason; grid attachment against analytic cells; keyframe
// attachment; reload from SQLite; acknowledged changes surviving a SIGKILL;
// corrupt, foreign and locked database files.
#include "ecar_core/structure/vo_store.h"
#include "ecar_core/structure/grid_cells.h"
#include "ecar_core/structure/grid_map.h"

#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <gtest/gtest.h>
#include <sqlite3.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iostream>
#include <limits>
#include <map>
#include <set>
#include <thread>

#include "ecar_core/common/error.h"
#include "ecar_core/common/timing.h"
#include "test_support.h"

namespace ecar {
namespace {

using ecar::testing::errorOf;
using ecar::testing::TempDir;

namespace fs = std::filesystem;

VirtualObject line(const Eigen::Vector3d& start, const Eigen::Vector3d& end,
                   const std::string& owner = "device_0") {
  VirtualObject vo;
  vo.kind = VoKind::kLine;
  vo.start = start;
  vo.end = end;
  vo.r = 200;
  vo.g = 10;
  vo.b = 30;
  vo.width = 0.02f;
  vo.normal = Eigen::Vector3d(0, 0, 2);  // normalised by the store
  vo.plane = PlaneId(3);
  vo.owner = owner;
  return vo;
}

VirtualObject anchor(const Eigen::Vector3d& position, const std::string& owner = "device_0") {
  VirtualObject vo;
  vo.kind = VoKind::kAnchor;
  vo.position = position;
  vo.width = 0.05f;
  vo.owner = owner;
  return vo;
}

VoStoreConfig memoryConfig() {
  VoStoreConfig config;
  config.database_path = ":memory:";
  return config;
}

std::string readFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

void expectSame(const VirtualObject& a, const VirtualObject& b) {
  EXPECT_EQ(a.id, b.id);
  EXPECT_EQ(a.kind, b.kind);
  EXPECT_EQ(a.position, b.position);
  EXPECT_EQ(a.start, b.start);
  EXPECT_EQ(a.end, b.end);
  EXPECT_EQ(a.r, b.r);
  EXPECT_EQ(a.g, b.g);
  EXPECT_EQ(a.b, b.b);
  EXPECT_EQ(a.width, b.width);
  EXPECT_EQ(a.normal, b.normal);
  EXPECT_EQ(a.plane, b.plane);
  EXPECT_EQ(a.owner, b.owner);
  EXPECT_EQ(a.version, b.version);
  EXPECT_EQ(a.deleted, b.deleted);
}

std::set<CellKey> asSet(const std::vector<CellKey>& cells) {
  return std::set<CellKey>(cells.begin(), cells.end());
}

std::string throwMessage(const std::function<void()>& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

// ---------------------------------------------------------------- config

TEST(VoStoreConfig, ValidateNamesTheKey) {
  EXPECT_NO_THROW(VoStoreConfig().validate());
  auto key = [](auto mutate) {
    VoStoreConfig c;
    mutate(c);
    return throwMessage([&] { c.validate(); });
  };
  EXPECT_NE(key([](VoStoreConfig& c) { c.cell_size = 0; }).find("cell_size"), std::string::npos);
  EXPECT_NE(key([](VoStoreConfig& c) { c.synchronous = "off"; }).find("synchronous"),
            std::string::npos);
  EXPECT_NE(key([](VoStoreConfig& c) { c.attach_margin = 0.06; }).find("attach_margin"),
            std::string::npos);
  EXPECT_NE(key([](VoStoreConfig& c) { c.database_path.clear(); }).find("database_path"),
            std::string::npos);
  EXPECT_NE(key([](VoStoreConfig& c) { c.map_min.x() = 2000; }).find("map_min"), std::string::npos);
  EXPECT_NE(key([](VoStoreConfig& c) { c.max_line_length = 0.0001; }).find("max_line_length"),
            std::string::npos);
  EXPECT_EQ(parseVoAttachMode("grid"), VoAttachMode::kGrid);
  EXPECT_EQ(parseVoAttachMode("keyframe"), VoAttachMode::kKeyFrame);
  EXPECT_STREQ(toString(VoAttachMode::kKeyFrame), "keyframe");
  EXPECT_THROW(parseVoAttachMode("cells"), Error);
}

// ---------------------------------------------------------------- changes

TEST(VoStore, RegisterManipulateDeleteVersions) {
  VoStore store(memoryConfig());
  const VoOutcome a = store.registerObject(line({0, 0, 0}, {1, 0, 0}));
  ASSERT_TRUE(a.accepted) << a.reason;
  EXPECT_EQ(a.id, ObjectId(1));
  EXPECT_EQ(a.version, 1u);
  EXPECT_TRUE(a.reason.empty());
  const VoOutcome b = store.registerObject(anchor({2, 0, 0}));
  ASSERT_TRUE(b.accepted);
  EXPECT_EQ(b.id, ObjectId(2));

  std::optional<VirtualObject> vo = store.get(a.id);
  ASSERT_TRUE(vo);
  EXPECT_EQ(vo->version, 1u);
  EXPECT_TRUE(vo->position.isApprox(Eigen::Vector3d(0.5, 0, 0)));  // centre of the segment
  EXPECT_TRUE(vo->normal.isApprox(Eigen::Vector3d::UnitZ()));      // normalised
  EXPECT_EQ(vo->owner, "device_0");
  EXPECT_EQ(store.get(b.id)->start, Eigen::Vector3d(2, 0, 0));  // anchor: start = end = position

  VirtualObject moved = line({0, 1, 0}, {1, 1, 0}, "someone_else");
  const VoOutcome m = store.manipulate(a.id, 1, moved, "device_1");
  ASSERT_TRUE(m.accepted) << m.reason;
  EXPECT_EQ(m.id, a.id);
  EXPECT_EQ(m.version, 2u);
  vo = store.get(a.id);
  EXPECT_EQ(vo->version, 2u);
  EXPECT_TRUE(vo->position.isApprox(Eigen::Vector3d(0.5, 1, 0)));
  EXPECT_EQ(vo->owner, "device_0");  // the registering device stays the owner

  // vo.policy owner_delete (the default): device_1 moved it but only device_0 deletes it.
  const VoOutcome refused = store.remove(a.id, 2, "device_1");
  EXPECT_EQ(refused.code, VoReject::kNotOwner);
  EXPECT_NE(refused.reason.find(
                "deleting object 1 is for its owner device_0 only (vo.policy owner_delete)"),
            std::string::npos)
      << refused.reason;
  const VoOutcome d = store.remove(a.id, 2, "device_0");
  ASSERT_TRUE(d.accepted) << d.reason;
  EXPECT_EQ(d.version, 3u);
  vo = store.get(a.id);
  ASSERT_TRUE(vo);  // a tombstone
  EXPECT_TRUE(vo->deleted);
  EXPECT_EQ(vo->version, 3u);
  EXPECT_EQ(store.numObjects(), 2u);
  EXPECT_EQ(store.numLive(), 1u);
  EXPECT_EQ(store.nextId(), ObjectId(3));
  const std::vector<VirtualObject> both = store.objects({b.id, a.id, ObjectId(99)});
  ASSERT_EQ(both.size(), 2u);
  EXPECT_EQ(both[0].id, a.id);
  EXPECT_TRUE(both[0].deleted);
}

TEST(VoStore, RejectsWithReasons) {
  VoStoreConfig config = memoryConfig();
  config.accept_own_stale = false;
  VoStore store(config);
  const ObjectId id = store.registerObject(line({0, 0, 0}, {1, 0, 0})).id;
  const VirtualObject before = *store.get(id);

  auto expectReject = [&](const VoOutcome& out, VoReject code, const std::string& text) {
    EXPECT_FALSE(out.accepted);
    EXPECT_EQ(out.code, code) << out.reason;
    EXPECT_NE(out.reason.find(text), std::string::npos)
        << "'" << out.reason << "' lacks '" << text << "'";
  };
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();

  VirtualObject bad = line({0, 0, 0}, {nan, 0, 0});
  expectReject(store.registerObject(bad), VoReject::kNotFinite, "end is not finite");
  bad = anchor({0, 0, 0});
  bad.normal.y() = inf;
  expectReject(store.registerObject(bad), VoReject::kNotFinite, "normal is not finite");
  bad = line({0, 0, 0}, {1, 0, 0});
  bad.width = std::numeric_limits<float>::quiet_NaN();
  expectReject(store.registerObject(bad), VoReject::kNotFinite, "width is not finite");
  bad = line({0, 0, 0}, {1, 0, 0});
  bad.position.z() = nan;  // recomputed for a line, but NaN anywhere is rejected
  expectReject(store.registerObject(bad), VoReject::kNotFinite, "position is not finite");

  expectReject(store.registerObject(anchor({2000, 0, 0})), VoReject::kOutOfMap,
               "position (2000, 0, 0) is out of the map bounds");
  expectReject(store.registerObject(line({0, 0, 0}, {0, 0, 0})), VoReject::kBadGeometry,
               "line length 0 m is below min_line_length");
  expectReject(store.registerObject(line({0, 0, 0}, {6, 0, 0})), VoReject::kBadGeometry,
               "line length 6 m exceeds max_line_length 5 m");
  bad = line({0, 0, 0}, {1, 0, 0});
  bad.width = 0.0f;
  expectReject(store.registerObject(bad), VoReject::kBadAttribute, "width 0 m is not in (0, 0.5]");
  bad.width = 0.8f;
  expectReject(store.registerObject(bad), VoReject::kBadAttribute, "width 0.8 m");
  bad = anchor({0, 0, 0});
  bad.width = -1.0f;
  expectReject(store.registerObject(bad), VoReject::kBadAttribute, "not in [0, 0.5]");
  bad = anchor({0, 0, 0});
  bad.kind = static_cast<VoKind>(7);
  expectReject(store.registerObject(bad), VoReject::kBadAttribute, "kind 7");
  bad = anchor({0, 0, 0});
  bad.normal.setZero();
  expectReject(store.registerObject(bad), VoReject::kBadGeometry, "normal is zero");
  bad = anchor({0, 0, 0}, std::string(65, 'x'));
  expectReject(store.registerObject(bad), VoReject::kBadAttribute, "owner is longer than 64");

  // Changes to existing objects.
  VoOutcome out = store.manipulate(ObjectId(42), 1, anchor({0, 0, 0}));
  expectReject(out, VoReject::kUnknownId, "unknown object id 42");
  EXPECT_EQ(out.version, 0u);
  expectReject(store.remove(ObjectId(42), 1, ""), VoReject::kUnknownId, "unknown object id 42");
  out = store.manipulate(id, 1, line({0, 0, nan}, {1, 0, 0}));
  expectReject(out, VoReject::kNotFinite, "start is not finite");
  EXPECT_EQ(out.version, 1u);  // the store's version
  expectReject(store.manipulate(id, 1, line({999.5, 0, 0}, {1000.5, 0, 0})), VoReject::kOutOfMap,
               "end (1000.5, 0, 0) is out of the map bounds");
  expectReject(store.manipulate(id, 2, line({0, 0, 0}, {1, 0, 0})), VoReject::kStaleVersion,
               "base_version 2 is newer than the store's version 1");
  expectReject(store.manipulate(id, 0, line({0, 0, 0}, {1, 0, 0})), VoReject::kStaleVersion,
               "a change must name the version it applies to (base_version 0");
  EXPECT_TRUE(store.manipulate(id, 1, line({0, 0, 0}, {2, 0, 0}), "device_1").accepted);
  out = store.manipulate(id, 1, line({0, 0, 0}, {3, 0, 0}), "device_1");
  expectReject(out, VoReject::kStaleVersion, "stale base_version 1: the store has version 2");
  EXPECT_EQ(out.version, 2u);
  expectReject(store.remove(id, 1, ""), VoReject::kStaleVersion, "the store has version 2");
  // No unconditional deletes: a delete names the version it deletes.
  expectReject(store.remove(id, 0, ""), VoReject::kStaleVersion,
               "a delete must name the version it applies to");

  // The map bounds can be narrowed at run time.
  store.setMapBounds(Eigen::Vector3d::Constant(-10), Eigen::Vector3d::Constant(10));
  expectReject(store.registerObject(anchor({11, 0, 0})), VoReject::kOutOfMap, "out of the map");
  EXPECT_THROW(store.setMapBounds(Eigen::Vector3d::Constant(1), Eigen::Vector3d::Constant(-1)),
               Error);

  ASSERT_TRUE(store.remove(id, 2, "").accepted);
  out = store.manipulate(id, 3, line({0, 0, 0}, {1, 0, 0}));
  expectReject(out, VoReject::kDeleted, "object 1 was deleted (version 3)");
  EXPECT_EQ(out.version, 3u);
  expectReject(store.remove(id, 3, ""), VoReject::kDeleted, "was deleted");

  // Rejections consumed no id and left the object at its accepted states.
  EXPECT_EQ(store.nextId(), ObjectId(2));
  EXPECT_EQ(store.numObjects(), 1u);
  EXPECT_EQ(store.get(id)->version, 3u);
  EXPECT_EQ(store.get(id)->end, Eigen::Vector3d(2, 0, 0));
  EXPECT_EQ(before.version, 1u);
  EXPECT_EQ(store.registerObject(anchor({1, 1, 0})).id, ObjectId(2));
}

TEST(VoStore, FullStoreAndKeyFrameModeRejections) {
  VoStoreConfig config = memoryConfig();
  config.max_objects = 2;
  VoStore store(config);
  EXPECT_TRUE(store.registerObject(anchor({0, 0, 0})).accepted);
  EXPECT_TRUE(store.registerObject(anchor({0, 0, 0})).accepted);
  const VoOutcome full = store.registerObject(anchor({0, 0, 0}));
  EXPECT_EQ(full.code, VoReject::kFull);
  EXPECT_NE(full.reason.find("full"), std::string::npos);

  config = memoryConfig();
  config.attach_mode = VoAttachMode::kKeyFrame;
  VoStore kf_store(config);
  const VoOutcome none = kf_store.registerObject(anchor({0, 0, 0}));
  EXPECT_EQ(none.code, VoReject::kNoKeyFrame);
  EXPECT_NE(none.reason.find("keyframe"), std::string::npos);
}

TEST(VoStore, PoliciesDecideWhoChangesWhat) {
  for (const VoPolicy policy : {VoPolicy::kOpen, VoPolicy::kOwnerDelete, VoPolicy::kOwnerOnly}) {
    SCOPED_TRACE(toString(policy));
    VoStoreConfig config = memoryConfig();
    config.policy = policy;
    VoStore store(config);
    const ObjectId id = store.registerObject(anchor({0, 0, 0}, "device_0")).id;
    const VoOutcome move = store.manipulate(id, 1, anchor({1, 0, 0}), "device_1");
    EXPECT_EQ(move.accepted, policy != VoPolicy::kOwnerOnly) << move.reason;
    const uint32_t v = store.get(id)->version;
    const VoOutcome del = store.remove(id, v, "device_1");
    EXPECT_EQ(del.accepted, policy == VoPolicy::kOpen) << del.reason;
    if (!del.accepted) {
      EXPECT_EQ(del.code, VoReject::kNotOwner);
      EXPECT_NE(del.reason.find("for its owner device_0 only"), std::string::npos) << del.reason;
      // The operator's rviz user and the owner may.
      EXPECT_TRUE(store.manipulate(id, v, anchor({2, 0, 0}), "rviz").accepted);
      EXPECT_TRUE(store.remove(id, v + 1, "device_0").accepted);
    }
  }
  EXPECT_EQ(parseVoPolicy("owner_only"), VoPolicy::kOwnerOnly);
  EXPECT_THROW(parseVoPolicy("anyone"), Error);
}

TEST(VoStore, TombstonesAreCompactedAndDoNotFillTheStore) {
  VoStoreConfig config = memoryConfig();
  config.max_objects = 3;
  config.tombstone_retention = 100.0;
  config.max_tombstones = 4;
  VoStore store(config);
  // One device registering and deleting in a loop never fills the store for good.
  std::vector<ObjectId> ids;
  for (int i = 0; i < 10; ++i) {
    const VoOutcome r = store.registerObject(anchor({0, 0, 0}, "device_0"));
    ASSERT_TRUE(r.accepted) << i << ": " << r.reason;
    ASSERT_TRUE(store.remove(r.id, 1, "device_0").accepted);
    ids.push_back(r.id);
  }
  // Live objects are limited; tombstones beyond max_tombstones went, oldest first.
  EXPECT_EQ(store.numLive(), 0u);
  EXPECT_EQ(store.numTombstones(), 4u);
  EXPECT_FALSE(store.get(ids[0]).has_value());
  EXPECT_TRUE(store.get(ids[9])->deleted);
  for (int i = 0; i < 3; ++i) ASSERT_TRUE(store.registerObject(anchor({0, 0, 0})).accepted);
  EXPECT_EQ(store.registerObject(anchor({0, 0, 0})).code, VoReject::kFull);
  // Within the retention nothing goes; after it, every tombstone does (from the database too).
  EXPECT_EQ(store.compactTombstones(steadySeconds()), 0u);
  EXPECT_EQ(store.compactTombstones(steadySeconds() + 101.0), 4u);
  EXPECT_EQ(store.numTombstones(), 0u);
  EXPECT_EQ(store.numObjects(), 3u);
  EXPECT_EQ(store.nextId(), ObjectId(14));  // ids are never reused
}

TEST(VoStore, AHostileSnapshotIsRefusedWholeAndChangesNothing) {
  VoStoreConfig config = memoryConfig();
  config.max_objects = 5;
  VoStore store(config);
  const ObjectId kept = store.registerObject(anchor({1, 2, 3}, "device_0")).id;
  const auto refused = [&](const VirtualObject& vo, const std::string& why) {
    VoSnapshot snapshot;
    VoRecord r;
    r.vo = vo;
    r.vo.id = ObjectId(1);
    r.vo.version = 1;
    snapshot.objects.push_back(r);
    snapshot.next_id = ObjectId(2);
    const std::string e = errorOf([&] { store.replaceAll(snapshot); });
    EXPECT_NE(e.find(why), std::string::npos) << e;
  };
  // Well-formed, finite, but a line of 1.8 km or 1e8 m (billions of cells), points far outside,
  // a huge width, a long owner name.
  refused(line({-900, 0, 0}, {900, 0, 0}), "longer than max_line_length");
  refused(line({0, 0, 0}, {1e8, 0, 0}), "outside the map bounds");
  refused(anchor({5000, 0, 0}), "outside the map bounds");
  VirtualObject wide = line({0, 0, 0}, {1, 0, 0});
  wide.width = 1e6f;
  refused(wide, "outside [0, max_width]");
  refused(anchor({0, 0, 0}, std::string(500, 'x')), "owner too long");
  // More live objects than max_objects.
  VoSnapshot many;
  for (uint32_t i = 1; i <= 6; ++i) {
    VoRecord r;
    r.vo = anchor({0, 0, 0});
    r.vo.id = ObjectId(i);
    r.vo.version = 1;
    many.objects.push_back(r);
  }
  many.next_id = ObjectId(7);
  EXPECT_NE(errorOf([&] { store.replaceAll(many); }).find("more than max_objects"),
            std::string::npos);
  // Nothing changed.
  EXPECT_EQ(store.numObjects(), 1u);
  EXPECT_EQ(store.get(kept)->position, Eigen::Vector3d(1, 2, 3));
}

// A drag: one device sends a MANIPULATE per frame, each before the previous
// acknowledgement arrived, so with the same base version.
TEST(VoStore, OwnStaleBaseVersionDuringADrag) {
  VoStore store(memoryConfig());
  const ObjectId id = store.registerObject(anchor({0, 0, 0}, "device_0")).id;
  for (int frame = 1; frame <= 5; ++frame) {
    const VoOutcome out = store.manipulate(id, 1, anchor({0.1 * frame, 0, 0}), "device_0");
    ASSERT_TRUE(out.accepted) << out.reason;
    EXPECT_EQ(out.version, 1u + frame);
  }
  // Another device that saw version 3 conflicts with device_0's later changes.
  const VoOutcome other = store.manipulate(id, 3, anchor({9, 0, 0}), "device_1");
  EXPECT_EQ(other.code, VoReject::kStaleVersion);
  EXPECT_EQ(other.version, 6u);
  // device_1 at the current version wins; device_0's drag from before it is now stale.
  ASSERT_TRUE(store.manipulate(id, 6, anchor({9, 0, 0}), "device_1").accepted);
  EXPECT_EQ(store.manipulate(id, 5, anchor({1, 0, 0}), "device_0").code, VoReject::kStaleVersion);
  // device_1 may continue its own drag from version 6.
  EXPECT_TRUE(store.manipulate(id, 6, anchor({8, 0, 0}), "device_1").accepted);
  EXPECT_EQ(store.get(id)->position, Eigen::Vector3d(8, 0, 0));
}

// ---------------------------------------------------------------- grid

// A store whose accepted changes attach their objects to a grid, as the grid
// connection does (server/grid_connection.h).
struct AttachedStore {
  explicit AttachedStore(const VoStoreConfig& config) : store(config) {}
  ObjectId registerObject(const VirtualObject& vo) { return attached(store.registerObject(vo)); }
  bool manipulate(ObjectId id, uint32_t base, const VirtualObject& vo) {
    return attached(store.manipulate(id, base, vo)).valid();
  }
  bool remove(ObjectId id) {
    return attached(store.remove(id, store.get(id) ? store.get(id)->version : 1, "")).valid();
  }
  std::vector<VirtualObject> objectsInCells(const std::vector<CellKey>& cells) const {
    return store.objects(grid.objectsInCells(cells));
  }
  ObjectId attached(const VoOutcome& out) {
    if (!out.accepted) return ObjectId();
    grid.attachObject(*store.get(out.id), store.config().cell_size, store.config().attach_margin);
    return out.id;
  }
  VoStore store;
  GridMap grid;
};

TEST(VoStoreGrid, AnchorCell) {
  VoStoreConfig config = memoryConfig();
  config.attach_margin = 0.0;
  AttachedStore store(config);
  const ObjectId id = store.registerObject(anchor({0.15, 0.25, 0.05}));
  EXPECT_EQ(store.grid.cellsOfObject(id), std::vector<CellKey>({CellKey{1, 2, 0}}));
  const std::vector<VirtualObject> got = store.objectsInCells({CellKey{1, 2, 0}});
  ASSERT_EQ(got.size(), 1u);
  EXPECT_EQ(got[0].id, id);
  EXPECT_TRUE(store.objectsInCells({CellKey{0, 0, 0}, CellKey{1, 2, 1}}).empty());
  // Negative coordinates: floor, not truncation.
  const ObjectId neg = store.registerObject(anchor({-0.05, -0.15, -0.01}));
  EXPECT_EQ(store.grid.cellsOfObject(neg), std::vector<CellKey>({CellKey{-1, -2, -1}}));
}

TEST(VoStoreGrid, FloorLineCrossesTheAnalyticCells) {
  const double cell = 0.1;
  // 1 m along x at the centre of a cell row: cells x = 0..10 of row (y 0, z 0).
  std::vector<CellKey> cells =
      attachmentCells(line({0.05, 0.05, 0.05}, {1.05, 0.05, 0.05}), cell, 0.0);
  std::vector<CellKey> expected;
  for (int x = 0; x <= 10; ++x) expected.push_back(CellKey{x, 0, 0});
  EXPECT_EQ(cells, expected);

  // 1 m diagonal on the floor rising 0.3 m in y: 10 x-crossings and 3
  // y-crossings, none at a corner, so 1 + 10 + 3 cells.
  const VirtualObject diagonal = line({0.05, 0.05, 0.05}, {1.05, 0.35, 0.05});
  cells = attachmentCells(diagonal, cell, 0.0);
  EXPECT_EQ(cells.size(), 14u);
  // The cell of x in [i, i+1) * 0.1 holds y = 0.05 + 0.3 * (x - 0.05): check each.
  std::set<CellKey> sampled;
  for (int k = 0; k <= 200000; ++k) {
    const Eigen::Vector3d p = diagonal.start + (diagonal.end - diagonal.start) * (k / 200000.0);
    sampled.insert(CellKey{static_cast<int32_t>(std::floor(p.x() / cell)),
                           static_cast<int32_t>(std::floor(p.y() / cell)),
                           static_cast<int32_t>(std::floor(p.z() / cell))});
  }
  EXPECT_EQ(asSet(cells), sampled);

  // A general 3D segment with negative coordinates: the same cells as dense sampling.
  const VirtualObject skew = line({0.03, 0.07, 0.02}, {-0.71, 0.33, 0.55});
  sampled.clear();
  for (int k = 0; k <= 200000; ++k) {
    const Eigen::Vector3d p = skew.start + (skew.end - skew.start) * (k / 200000.0);
    sampled.insert(CellKey{static_cast<int32_t>(std::floor(p.x() / cell)),
                           static_cast<int32_t>(std::floor(p.y() / cell)),
                           static_cast<int32_t>(std::floor(p.z() / cell))});
  }
  EXPECT_EQ(asSet(attachmentCells(skew, cell, 0.0)), sampled);
}

TEST(VoStoreGrid, MarginCoversBothLayersOfAFloorAtACellBoundary) {
  // A stroke on a floor at z = 0 (the boundary of layers z = -1 and 0) and
  // within 2 cm of the boundary y = 0: both layers and both rows.
  const std::vector<CellKey> cells =
      attachmentCells(line({0.05, 0.01, 0.0}, {1.05, 0.01, 0.0}), 0.1, 0.02);
  std::set<CellKey> expected;
  for (int x = 0; x <= 10; ++x) {
    for (int y : {-1, 0}) {
      for (int z : {-1, 0}) expected.insert(CellKey{x, y, z});
    }
  }
  EXPECT_EQ(asSet(cells), expected);
  EXPECT_EQ(cells.size(), 44u);
  // 5 cm from every boundary: the margin adds nothing.
  EXPECT_EQ(attachmentCells(anchor({0.15, 0.25, 0.05}), 0.1, 0.02),
            std::vector<CellKey>({CellKey{1, 2, 0}}));
}

TEST(VoStoreGrid, MovingReattachesAndDeleteDetaches) {
  VoStoreConfig config = memoryConfig();
  config.attach_margin = 0.0;
  AttachedStore store(config);
  const ObjectId id = store.registerObject(line({0.05, 0.05, 0.05}, {1.05, 0.05, 0.05}));
  const ObjectId other = store.registerObject(anchor({0.55, 0.05, 0.05}));
  EXPECT_EQ(store.objectsInCells({CellKey{5, 0, 0}}).size(), 2u);  // both, each once
  EXPECT_EQ(store.objectsInCells({CellKey{3, 0, 0}, CellKey{4, 0, 0}}).size(), 1u);

  ASSERT_TRUE(store.manipulate(id, 1, line({20.05, 0.05, 0.05}, {20.05, 1.05, 0.05})));
  const std::vector<VirtualObject> old_place = store.objectsInCells({CellKey{3, 0, 0}});
  EXPECT_TRUE(old_place.empty());
  const std::vector<VirtualObject> new_place = store.objectsInCells({CellKey{200, 7, 0}});
  ASSERT_EQ(new_place.size(), 1u);
  EXPECT_EQ(new_place[0].id, id);
  EXPECT_EQ(new_place[0].version, 2u);  // at its latest version
  EXPECT_EQ(store.grid.cellsOfObject(id).size(), 11u);

  ASSERT_TRUE(store.remove(id));
  EXPECT_TRUE(store.objectsInCells({CellKey{200, 7, 0}}).empty());
  EXPECT_TRUE(store.grid.cellsOfObject(id).empty());
  const std::vector<VirtualObject> left = store.objectsInCells({CellKey{5, 0, 0}});
  ASSERT_EQ(left.size(), 1u);
  EXPECT_EQ(left[0].id, other);
}

// ---------------------------------------------------------------- keyframe

TEST(VoStoreKeyFrame, HangsOnTheNearestKeyFrameAtRegistration) {
  VoStoreConfig config = memoryConfig();
  config.attach_mode = VoAttachMode::kKeyFrame;
  VoStore store(config);
  EXPECT_EQ(store.attachMode(), VoAttachMode::kKeyFrame);
  const ObjectId a = store.registerObject(anchor({0, 0, 0}), KeyFrameId(7)).id;
  const ObjectId b = store.registerObject(anchor({5, 0, 0}), KeyFrameId(8)).id;
  const ObjectId c = store.registerObject(anchor({5, 1, 0}), KeyFrameId(8)).id;
  EXPECT_EQ(store.keyFrameOf(a), KeyFrameId(7));
  std::vector<VirtualObject> got = store.objectsOfKeyFrames({KeyFrameId(7)});
  ASSERT_EQ(got.size(), 1u);
  EXPECT_EQ(got[0].id, a);
  got = store.objectsOfKeyFrames({KeyFrameId(8), KeyFrameId(7), KeyFrameId(9)});
  ASSERT_EQ(got.size(), 3u);
  EXPECT_EQ(got[0].id, a);
  EXPECT_EQ(got[2].id, c);
  // Moving keeps the keyframe (the one nearest at registration).
  ASSERT_TRUE(store.manipulate(a, 1, anchor({30, 0, 0})).accepted);
  got = store.objectsOfKeyFrames({KeyFrameId(7)});
  ASSERT_EQ(got.size(), 1u);
  EXPECT_EQ(got[0].position, Eigen::Vector3d(30, 0, 0));
  ASSERT_TRUE(store.remove(b, 1, "").accepted);
  got = store.objectsOfKeyFrames({KeyFrameId(8)});
  ASSERT_EQ(got.size(), 1u);
  EXPECT_EQ(got[0].id, c);
  EXPECT_TRUE(store.objectsOfKeyFrames({KeyFrameId(9)}).empty());
}

// A culled keyframe's objects move to its heir, in the database too, at the same version.
TEST(VoStoreKeyFrame, ObjectsOfACulledKeyFrameMoveToItsHeir) {
  TempDir dir;
  VoStoreConfig config;
  config.database_path = dir.file("vo.sqlite");
  config.attach_mode = VoAttachMode::kKeyFrame;
  ObjectId a, b, c;
  {
    VoStore store(config);
    a = store.registerObject(anchor({0, 0, 0}), KeyFrameId(7)).id;
    b = store.registerObject(anchor({1, 0, 0}), KeyFrameId(7)).id;
    c = store.registerObject(anchor({2, 0, 0}), KeyFrameId(8)).id;
    ASSERT_TRUE(store.manipulate(b, 1, anchor({1, 1, 0})).accepted);
    EXPECT_EQ(store.moveKeyFrame(KeyFrameId(7), KeyFrameId(8)), 2u);
    EXPECT_TRUE(store.objectsOfKeyFrames({KeyFrameId(7)}).empty());
    std::vector<VirtualObject> got = store.objectsOfKeyFrames({KeyFrameId(8)});
    ASSERT_EQ(got.size(), 3u);
    EXPECT_EQ(got[1].id, b);
    EXPECT_EQ(got[1].version, 2u);  // not a change of the object
    EXPECT_EQ(got[1].position, Eigen::Vector3d(1, 1, 0));
    EXPECT_EQ(store.moveKeyFrame(KeyFrameId(7), KeyFrameId(9)), 0u);  // nothing left there
    EXPECT_EQ(store.moveKeyFrame(KeyFrameId(8), KeyFrameId(8)), 0u);
    // No heir: the objects hang on no keyframe.
    EXPECT_EQ(store.moveKeyFrame(KeyFrameId(8), KeyFrameId()), 3u);
    EXPECT_TRUE(store.objectsOfKeyFrames({KeyFrameId(8)}).empty());
    EXPECT_EQ(store.numLive(), 3u);
    EXPECT_EQ(store.moveKeyFrame(KeyFrameId(), KeyFrameId(8)), 0u);
  }
  VoStore reopened(config);
  for (ObjectId id : {a, b, c}) EXPECT_FALSE(reopened.keyFrameOf(id).valid()) << id.value;
  EXPECT_EQ(reopened.get(b)->version, 2u);
}

// ---------------------------------------------------------------- persistence

TEST(VoStorePersistence, ReloadsEveryObjectAndTheIdCounter) {
  TempDir dir;
  VoStoreConfig config;
  config.database_path = dir.file("vo.sqlite");
  std::vector<VirtualObject> saved;
  std::vector<std::vector<CellKey>> cells;
  {
    VoStore store(config);
    for (int i = 0; i < 20; ++i) {
      VirtualObject vo = i % 2 ? anchor({0.1 * i, 1, 0}) : line({0.1 * i, 0, 0}, {0.1 * i, 1, 0});
      vo.r = static_cast<uint8_t>(i);
      vo.width = 0.001f * (i + 1);
      vo.plane = PlaneId(i);
      vo.normal = Eigen::Vector3d(0.1, 0.2, 0.9);
      ASSERT_TRUE(store.registerObject(vo, KeyFrameId(100 + i)).accepted);
    }
    ASSERT_TRUE(store.manipulate(ObjectId(3), 1, line({3, 3, 0}, {3.5, 3.1, 0.2})).accepted);
    ASSERT_TRUE(store.manipulate(ObjectId(3), 2, line({4, 3, 0}, {4.5, 3.1, 0.2})).accepted);
    ASSERT_TRUE(store.remove(ObjectId(5), 1, "").accepted);
    ASSERT_TRUE(store.remove(ObjectId(20), 1, "").accepted);  // the highest id, deleted
    saved = store.allObjects();
    for (const VirtualObject& vo : saved) {
      cells.push_back(vo.deleted ? std::vector<CellKey>()
                                 : attachmentCells(vo, config.cell_size, config.attach_margin));
    }
  }
  VoStore reopened(config);
  const std::vector<VirtualObject> loaded = reopened.allObjects();
  ASSERT_EQ(loaded.size(), saved.size());
  for (size_t i = 0; i < saved.size(); ++i) {
    expectSame(loaded[i], saved[i]);
    EXPECT_EQ(loaded[i].deleted
                  ? std::vector<CellKey>()
                  : attachmentCells(loaded[i], config.cell_size, config.attach_margin),
              cells[i]);
  }
  EXPECT_EQ(reopened.get(ObjectId(3))->version, 3u);
  EXPECT_TRUE(reopened.get(ObjectId(5))->deleted);
  EXPECT_EQ(reopened.numLive(), 18u);
  EXPECT_EQ(reopened.keyFrameOf(ObjectId(7)), KeyFrameId(106));
  EXPECT_EQ(reopened.objectsOfKeyFrames({KeyFrameId(106)}).size(), 1u);
  EXPECT_TRUE(reopened.objectsOfKeyFrames({KeyFrameId(104)}).empty());  // object 5: deleted
  // Ids are never reused, not even the deleted highest one.
  EXPECT_EQ(reopened.nextId(), ObjectId(21));
  const VoOutcome next = reopened.registerObject(anchor({0, 0, 0}));
  EXPECT_EQ(next.id, ObjectId(21));
  // Versions continue.
  EXPECT_EQ(reopened.manipulate(ObjectId(3), 3, anchor({1, 1, 1})).version, 4u);

  // A backup is a database that loads the same objects.
  reopened.backupTo(dir.file("copy.sqlite"));
  VoStoreConfig copy_config = config;
  copy_config.database_path = dir.file("copy.sqlite");
  VoStore copy(copy_config);
  const std::vector<VirtualObject> copied = copy.allObjects();
  const std::vector<VirtualObject> current = reopened.allObjects();
  ASSERT_EQ(copied.size(), current.size());
  for (size_t i = 0; i < copied.size(); ++i) expectSame(copied[i], current[i]);
}

TEST(VoStorePersistence, ASecondOpenOfTheSameFileFails) {
  TempDir dir;
  VoStoreConfig config;
  config.database_path = dir.file("vo.sqlite");
  VoStore store(config);
  ASSERT_TRUE(store.registerObject(anchor({0, 0, 0})).accepted);
  const std::string message = throwMessage([&] { VoStore second(config); });
  EXPECT_NE(message.find(config.database_path), std::string::npos) << message;
  EXPECT_NE(message.find("locked"), std::string::npos) << message;
  EXPECT_TRUE(store.registerObject(anchor({0, 0, 0})).accepted);  // the owner carries on
}

TEST(VoStorePersistence, ForeignAndCorruptFilesAreRefusedAndLeftAsTheyAre) {
  TempDir dir;
  VoStoreConfig config;

  // Not an SQLite file.
  config.database_path = dir.file("text.sqlite");
  {
    std::ofstream out(config.database_path, std::ios::binary);
    for (int i = 0; i < 200; ++i) out << "this is a text file, not a database\n";
  }
  std::string before = readFile(config.database_path);
  std::string message = throwMessage([&] { VoStore store(config); });
  EXPECT_NE(message.find(config.database_path), std::string::npos) << message;
  EXPECT_NE(message.find("not a database"), std::string::npos) << message;
  EXPECT_EQ(readFile(config.database_path), before);

  // Another program's SQLite database.
  config.database_path = dir.file("foreign.sqlite");
  {
    sqlite3* db = nullptr;
    ASSERT_EQ(sqlite3_open(config.database_path.c_str(), &db), SQLITE_OK);
    ASSERT_EQ(sqlite3_exec(db,
                           "CREATE TABLE users (name TEXT); INSERT INTO users VALUES ('ann');"
                           "CREATE TABLE objects (id INTEGER)",
                           nullptr, nullptr, nullptr),
              SQLITE_OK);
    sqlite3_close(db);
  }
  before = readFile(config.database_path);
  message = throwMessage([&] { VoStore store(config); });
  EXPECT_NE(message.find("not an eCAR VO database (its tables are: objects, users)"),
            std::string::npos)
      << message;
  EXPECT_EQ(readFile(config.database_path), before);

  // A store whose row was damaged by hand.
  config.database_path = dir.file("damaged.sqlite");
  {
    VoStore store(config);
    ASSERT_TRUE(store.registerObject(anchor({0, 0, 0})).accepted);
    ASSERT_TRUE(store.registerObject(anchor({1, 0, 0})).accepted);
  }
  {
    sqlite3* db = nullptr;
    ASSERT_EQ(sqlite3_open(config.database_path.c_str(), &db), SQLITE_OK);
    ASSERT_EQ(
        sqlite3_exec(db, "UPDATE objects SET kind = 9 WHERE id = 2", nullptr, nullptr, nullptr),
        SQLITE_OK);
    sqlite3_close(db);
  }
  message = throwMessage([&] { VoStore store(config); });
  EXPECT_NE(message.find("malformed VO database: object 2: kind 9 is out of range"),
            std::string::npos)
      << message;

  // A store truncated to its first page (its table pages are gone).
  config.database_path = dir.file("truncated.sqlite");
  {
    VoStore store(config);
    for (int i = 0; i < 300; ++i) ASSERT_TRUE(store.registerObject(anchor({0, 0, 0})).accepted);
  }
  ASSERT_GT(fs::file_size(config.database_path), 3 * 4096u);
  fs::resize_file(config.database_path, 4096);
  message = throwMessage([&] { VoStore store(config); });
  EXPECT_NE(message.find(config.database_path), std::string::npos) << message;
  EXPECT_NE(message.find("malformed"), std::string::npos) << message;
}

TEST(VoStorePersistence, AFailedWriteRejectsTheChangeAndLeavesTheStoreAsItWas) {
  TempDir dir;
  VoStoreConfig config;
  config.database_path = dir.file("small.sqlite");
  config.max_database_mb = 0.05;  // 12 pages of 4 KiB
  VoStore store(config);
  VoOutcome out;
  int accepted = 0;
  while ((out = store.registerObject(line({0, 0, 0}, {1, 0, 0}, std::string(60, 'o')))).accepted) {
    ++accepted;
    ASSERT_LT(accepted, 10000);
  }
  EXPECT_EQ(out.code, VoReject::kStorage);
  EXPECT_NE(out.reason.find("database write failed"), std::string::npos) << out.reason;
  EXPECT_EQ(store.numObjects(), static_cast<size_t>(accepted));
  EXPECT_EQ(store.nextId(), ObjectId(accepted + 1));
  EXPECT_FALSE(store.get(ObjectId(accepted + 1)));
  // A manipulation that still fits is accepted (the row is replaced in place).
  EXPECT_TRUE(store.manipulate(ObjectId(1), 1, line({0, 0, 0}, {2, 0, 0})).accepted);
}

// fork() a child that registers and manipulates objects and writes each
// acknowledged (id, version) to a pipe; SIGKILL it mid-way (after
// `kill_after` acknowledgements, the parent draining the pipe as it goes so
// the child is still working); the reopened database must hold every
// acknowledged object at (at least) its version.
void sigkillTest(const std::string& synchronous, size_t kill_after) {
  TempDir dir;
  VoStoreConfig config;
  config.database_path = dir.file("crash.sqlite");
  config.synchronous = synchronous;
  int fds[2];
  ASSERT_EQ(pipe(fds), 0);
  struct Ack {
    uint32_t id, version;
  };
  const pid_t child = fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    close(fds[0]);
    try {
      VoStore store(config);
      for (uint32_t i = 0; i < 1000000; ++i) {
        VoOutcome out;
        if (i % 3 == 2) {  // move an earlier object
          const ObjectId id(1 + (i * 7919) % store.numObjects());
          const uint32_t version = store.get(id)->version;
          out = store.manipulate(id, version, anchor({0.01 * i, 1, 0}), "child");
        } else {
          out = store.registerObject(line({0.01 * i, 0, 0}, {0.01 * i, 1, 0}, "child"));
        }
        if (!out.accepted) _exit(3);
        const Ack ack{out.id.value, out.version};
        if (write(fds[1], &ack, sizeof ack) != sizeof ack) _exit(4);
      }
    } catch (...) {
      _exit(2);
    }
    _exit(0);
  }
  close(fds[1]);
  std::map<uint32_t, uint32_t> acknowledged;  // id -> latest acknowledged version
  size_t acks = 0;
  Ack ack;
  while (acks < kill_after && read(fds[0], &ack, sizeof ack) == sizeof ack) {
    acknowledged[ack.id] = std::max(acknowledged[ack.id], ack.version);
    ++acks;
  }
  kill(child, SIGKILL);
  int status = 0;
  ASSERT_EQ(waitpid(child, &status, 0), child);
  ASSERT_TRUE(WIFSIGNALED(status)) << "the child ended before the kill, status " << status;
  // Acknowledgements written before the kill are still in the pipe.
  while (read(fds[0], &ack, sizeof ack) == sizeof ack) {
    acknowledged[ack.id] = std::max(acknowledged[ack.id], ack.version);
    ++acks;
  }
  close(fds[0]);
  ASSERT_GE(acks, kill_after);

  VoStore store(config);
  size_t present = 0;
  for (const auto& [id, version] : acknowledged) {
    const std::optional<VirtualObject> vo = store.get(ObjectId(id));
    if (vo && vo->version >= version) ++present;
    EXPECT_TRUE(vo && vo->version >= version) << "object " << id << " version " << version;
  }
  EXPECT_EQ(present, acknowledged.size());
  // At most the change in flight when the kill came is stored without an acknowledgement.
  EXPECT_LE(store.numObjects(), acknowledged.size() + 1);
  std::cout << "[ crash    ] synchronous=" << synchronous << ": " << acks
            << " acknowledged changes, " << acknowledged.size() << " objects; " << present
            << " back after SIGKILL" << std::endl;
}

TEST(VoStorePersistence, EveryAcknowledgedChangeSurvivesSigkill) { sigkillTest("normal", 3000); }

TEST(VoStorePersistence, EveryAcknowledgedChangeSurvivesSigkillSynchronousFull) {
  sigkillTest("full", 300);
}

// ---------------------------------------------------------------- threads, timing

TEST(VoStore, ConcurrentWritersAndReaders) {
  TempDir dir;
  VoStoreConfig config;
  config.database_path = dir.file("threads.sqlite");
  config.synchronous = "normal";
  VoStore store(config);
  constexpr int kThreads = 4, kPerThread = 50;
  std::atomic<bool> done{false};
  std::atomic<size_t> reads{0};
  std::thread reader([&] {
    while (!done) {
      store.forEachLive([](const VirtualObject& vo) { ASSERT_GE(vo.version, 1u); });
      for (const VirtualObject& vo : store.allObjects()) ASSERT_GE(vo.version, 1u);
      ++reads;
    }
  });
  std::vector<std::thread> writers;
  std::vector<std::vector<ObjectId>> ids(kThreads);
  for (int t = 0; t < kThreads; ++t) {
    writers.emplace_back([&, t] {
      const std::string me = "device_" + std::to_string(t);
      for (int i = 0; i < kPerThread; ++i) {
        const VoOutcome out = store.registerObject(anchor({0.05 + 0.1 * (i % 20), 0.05, 0.05}, me));
        ASSERT_TRUE(out.accepted);
        ids[t].push_back(out.id);
        ASSERT_TRUE(store.manipulate(out.id, 1, anchor({0.15, 0.05, 0.05}), me).accepted);
      }
    });
  }
  for (std::thread& w : writers) w.join();
  done = true;
  reader.join();
  std::set<ObjectId> all;
  for (const auto& v : ids) all.insert(v.begin(), v.end());
  EXPECT_EQ(all.size(), static_cast<size_t>(kThreads * kPerThread));  // unique ids
  const std::vector<VirtualObject> moved = store.allObjects();
  EXPECT_EQ(moved.size(), all.size());
  for (const VirtualObject& vo : moved) EXPECT_EQ(cellOf(vo.position, 0.1), (CellKey{1, 0, 0}));
  EXPECT_GT(reads.load(), 0u);
}

TEST(VoStore, TimePerChange) {
  TempDir dir;
  for (const char* sync : {"full", "normal"}) {
    VoStoreConfig config;
    config.database_path = dir.file(std::string(sync) + ".sqlite");
    config.synchronous = sync;
    VoStore store(config);
    constexpr int kN = 200;
    const auto t0 = std::chrono::steady_clock::now();
    for (int i = 0; i < kN; ++i) {
      ASSERT_TRUE(store.registerObject(line({0.01 * i, 0, 0}, {0.01 * i, 0.5, 0})).accepted);
    }
    const auto t1 = std::chrono::steady_clock::now();
    for (int i = 0; i < kN; ++i) {
      ASSERT_TRUE(
          store.manipulate(ObjectId(i + 1), 1, line({0.01 * i, 1, 0}, {0, 1.5, 0})).accepted);
    }
    const auto t2 = std::chrono::steady_clock::now();
    const double reg_ms = std::chrono::duration<double, std::milli>(t1 - t0).count() / kN;
    const double man_ms = std::chrono::duration<double, std::milli>(t2 - t1).count() / kN;
    std::cout << "[ timing   ] synchronous=" << sync << ": register " << reg_ms
              << " ms/object, manipulate " << man_ms << " ms/change" << std::endl;
  }

  // Lookup on a grid of 10,000 strokes spread over a 30 m x 3 m floor.
  AttachedStore store(memoryConfig());
  for (int i = 0; i < 10000; ++i) {
    const double x = 0.003 * i, y = 0.3 * (i % 10);
    ASSERT_TRUE(store.registerObject(line({x, y, 0.01}, {x + 0.05, y + 0.02, 0.01})).valid());
  }
  std::vector<CellKey> visible;  // 2,000 cells: a 5 m x 4 m patch of floor
  for (int x = 0; x < 50; ++x) {
    for (int y = 0; y < 40; ++y) visible.push_back(CellKey{100 + x, y, 0});
  }
  const auto t0 = std::chrono::steady_clock::now();
  size_t found = 0;
  constexpr int kQueries = 100;
  for (int q = 0; q < kQueries; ++q) found = store.grid.objectsInCells(visible).size();
  const double query_ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count() /
      kQueries;
  EXPECT_GT(found, 1000u);
  std::cout << "[ timing   ] objectsInCells: 2000 cells, " << found << " of 10000 objects in "
            << query_ms << " ms" << std::endl;
}

}  // namespace
}  // namespace ecar
