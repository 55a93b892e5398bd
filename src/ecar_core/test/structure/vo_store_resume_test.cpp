// VoStore::mergeNewer: a server resuming after a crash from its own autosave (an
// older snapshot of the same database) keeps every change the database
// acknowledged since, where replaceAll (loading a saved session on purpose)
// puts the snapshot's state back.
#include <gtest/gtest.h>

#include <string>

#include "ecar_core/common/error.h"
#include "ecar_core/structure/vo_store.h"
#include "test_support.h"

namespace ecar {
namespace {

using ecar::testing::errorOf;
using ecar::testing::TempDir;

/// A 20 cm floor line at x, owned by device_0.
VirtualObject floorLine(double x) {
  VirtualObject vo;
  vo.kind = VoKind::kLine;
  vo.start = Eigen::Vector3d(x, 0.0, 0.0);
  vo.end = Eigen::Vector3d(x, 0.2, 0.0);
  vo.width = 0.02f;
  vo.normal = Eigen::Vector3d::UnitZ();
  vo.owner = "device_0";
  return vo;
}

VoStoreConfig fileConfig(const TempDir& dir) {
  VoStoreConfig config;
  config.database_path = dir.file("vo.sqlite");
  return config;
}

/// The autosave's snapshot: objects 1 and 2 at version 1. Then, acknowledged
/// after it: 1 moved (v2), 2 deleted (v2), 3 registered.
VoSnapshot crashAfterChanges(const VoStoreConfig& config) {
  VoStore store(config);
  EXPECT_TRUE(store.registerObject(floorLine(0.0)).accepted);
  EXPECT_TRUE(store.registerObject(floorLine(1.0)).accepted);
  const VoSnapshot autosave = store.snapshot();
  EXPECT_TRUE(store.manipulate(ObjectId(1), 1, floorLine(0.5)).accepted);
  EXPECT_TRUE(store.remove(ObjectId(2), 1, "device_0").accepted);
  EXPECT_TRUE(store.registerObject(floorLine(2.0)).accepted);
  return autosave;  // the store closes as a killed process leaves its database
}

void expectChangesSinceTheAutosave(const VoStore& store, size_t live = 2) {
  ASSERT_TRUE(store.get(ObjectId(1)));
  EXPECT_EQ(store.get(ObjectId(1))->version, 2u);
  EXPECT_NEAR(store.get(ObjectId(1))->start.x(), 0.5, 1e-9);
  ASSERT_TRUE(store.get(ObjectId(2)));
  EXPECT_TRUE(store.get(ObjectId(2))->deleted);
  ASSERT_TRUE(store.get(ObjectId(3)));
  EXPECT_EQ(store.numLive(), live);
}

TEST(VoStoreResume, MergingTheAutosaveKeepsEveryChangeAcknowledgedSince) {
  TempDir dir;
  const VoStoreConfig config = fileConfig(dir);
  const VoSnapshot autosave = crashAfterChanges(config);
  {
    VoStore resumed(config);
    const VoStore::MergeCounts counts = resumed.mergeNewer(autosave);
    EXPECT_EQ(counts.from_snapshot, 0u);
    EXPECT_EQ(counts.kept, 3u);
    expectChangesSinceTheAutosave(resumed);
    // Ids are not reused.
    const VoOutcome next = resumed.registerObject(floorLine(3.0));
    ASSERT_TRUE(next.accepted);
    EXPECT_EQ(next.id, ObjectId(4));
  }
  VoStore reopened(config);
  expectChangesSinceTheAutosave(reopened, 3);  // and object 4
  EXPECT_TRUE(reopened.get(ObjectId(4)));
}

TEST(VoStoreResume, ReplacingPutsTheSnapshotBackAsALoadOnPurposeDoes) {
  TempDir dir;
  const VoStoreConfig config = fileConfig(dir);
  const VoSnapshot autosave = crashAfterChanges(config);
  VoStore store(config);
  store.replaceAll(autosave);
  EXPECT_EQ(store.get(ObjectId(1))->version, 1u);
  EXPECT_FALSE(store.get(ObjectId(2))->deleted);
  EXPECT_FALSE(store.get(ObjectId(3)));
  // Ids stay unique all the same.
  EXPECT_EQ(store.registerObject(floorLine(3.0)).id, ObjectId(4));
}

TEST(VoStoreResume, NewerObjectsOfTheSnapshotAreTakenAndWritten) {
  TempDir dir;
  const VoStoreConfig config = fileConfig(dir);
  VoSnapshot snapshot = crashAfterChanges(config);
  snapshot.objects[0].vo.version = 7;  // object 1, newer in the file than in the database
  VoRecord extra = snapshot.objects[1];
  extra.vo.id = ObjectId(9);  // only in the file
  extra.vo.version = 1;
  snapshot.objects.push_back(extra);
  snapshot.next_id = ObjectId(10);
  {
    VoStore store(config);
    const VoStore::MergeCounts counts = store.mergeNewer(snapshot);
    EXPECT_EQ(counts.from_snapshot, 2u);
    EXPECT_EQ(counts.kept, 2u);  // 2 (deleted since) and 3 (made since)
  }
  VoStore reopened(config);
  EXPECT_EQ(reopened.get(ObjectId(1))->version, 7u);
  EXPECT_NEAR(reopened.get(ObjectId(1))->start.x(), 0.0, 1e-9);
  EXPECT_TRUE(reopened.get(ObjectId(9)));
  EXPECT_TRUE(reopened.get(ObjectId(2))->deleted);
  EXPECT_EQ(reopened.registerObject(floorLine(3.0)).id, ObjectId(10));
}

TEST(VoStoreResume, AHostileSnapshotIsRefusedWholeAndChangesNothing) {
  TempDir dir;
  const VoStoreConfig config = fileConfig(dir);
  VoSnapshot snapshot = crashAfterChanges(config);
  snapshot.objects[0].vo.version = 9;
  snapshot.objects[0].vo.end = Eigen::Vector3d(1e8, 0.0, 0.0);  // a 1e8 m line
  VoStore store(config);
  const std::string error = errorOf([&] { store.mergeNewer(snapshot); });
  EXPECT_NE(error.find("merging the map file's VOs"), std::string::npos) << error;
  expectChangesSinceTheAutosave(store);
}

}  // namespace
}  // namespace ecar
