// The VO database's schema upgrade: a version-1 file (one map, no map_id
// column) opens as version 2 with every object in map 1, and keeps working.
#include <gtest/gtest.h>
#include <sqlite3.h>

#include <string>

#include "ecar_core/structure/vo_store.h"
#include "test_support.h"

namespace ecar {
namespace {

using testing::TempDir;

std::string metaValue(const std::string& path, const char* key) {
  sqlite3* db = nullptr;
  EXPECT_EQ(sqlite3_open(path.c_str(), &db), SQLITE_OK);
  sqlite3_stmt* get = nullptr;
  sqlite3_prepare_v2(db, "SELECT value FROM meta WHERE key = ?1", -1, &get, nullptr);
  sqlite3_bind_text(get, 1, key, -1, SQLITE_STATIC);
  std::string value;
  if (sqlite3_step(get) == SQLITE_ROW) {
    value = reinterpret_cast<const char*>(sqlite3_column_text(get, 0));
  }
  sqlite3_finalize(get);
  sqlite3_close(db);
  return value;
}

TEST(VoDatabaseUpgrade, AVersionOneFileOpensWithItsObjectsInMapOne) {
  const TempDir dir;
  const std::string path = dir.file("v1.sqlite");
  {
    // The version-1 schema as a build before the atlas wrote it.
    sqlite3* db = nullptr;
    ASSERT_EQ(sqlite3_open(path.c_str(), &db), SQLITE_OK);
    ASSERT_EQ(
        sqlite3_exec(
            db,
            "CREATE TABLE meta (key TEXT PRIMARY KEY NOT NULL, value TEXT NOT NULL);"
            "CREATE TABLE objects ("
            " id INTEGER PRIMARY KEY NOT NULL, kind INTEGER NOT NULL,"
            " px REAL NOT NULL, py REAL NOT NULL, pz REAL NOT NULL,"
            " sx REAL NOT NULL, sy REAL NOT NULL, sz REAL NOT NULL,"
            " ex REAL NOT NULL, ey REAL NOT NULL, ez REAL NOT NULL,"
            " r INTEGER NOT NULL, g INTEGER NOT NULL, b INTEGER NOT NULL, width REAL NOT NULL,"
            " nx REAL NOT NULL, ny REAL NOT NULL, nz REAL NOT NULL,"
            " plane_id INTEGER NOT NULL, owner TEXT NOT NULL, version INTEGER NOT NULL,"
            " deleted INTEGER NOT NULL, keyframe_id INTEGER NOT NULL,"
            " last_editor TEXT NOT NULL, editor_since INTEGER NOT NULL);"
            "INSERT INTO meta (key, value) VALUES ('format', 'ecar_vo_store'),"
            " ('schema_version', '1'), ('next_id', '8');"
            "INSERT INTO objects VALUES (7, 0, 1.5, 0, 0, 1, 0, 0, 2, 0, 0, 200, 10, 10,"
            " 0.02, 0, 0, 1, 3, 'device_0', 2, 0, 0, 'device_1', 1);",
            nullptr, nullptr, nullptr),
        SQLITE_OK)
        << sqlite3_errmsg(db);
    sqlite3_close(db);
  }
  VoStoreConfig config;
  config.database_path = path;
  {
    VoStore store(config);
    const std::optional<VirtualObject> vo = store.get(ObjectId(7));
    ASSERT_TRUE(vo.has_value());
    EXPECT_EQ(vo->map, MapId(1));
    EXPECT_EQ(vo->version, 2u);
    EXPECT_EQ(vo->owner, "device_0");
    EXPECT_DOUBLE_EQ(vo->start.x(), 1.0);
    // It keeps working: a new object in map 2 gets the next id.
    VirtualObject next = *vo;
    next.map = MapId(2);
    const VoOutcome r = store.registerObject(next);
    ASSERT_TRUE(r.accepted) << r.reason;
    EXPECT_EQ(r.id, ObjectId(8));
  }
  EXPECT_EQ(metaValue(path, "schema_version"), "2");
  VoStore reopened(config);
  EXPECT_EQ(reopened.get(ObjectId(7))->map, MapId(1));
  EXPECT_EQ(reopened.get(ObjectId(8))->map, MapId(2));
}

}  // namespace
}  // namespace ecar
