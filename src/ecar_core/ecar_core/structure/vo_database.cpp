#include "ecar_core/structure/vo_database.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <limits>

#include <sqlite3.h>

#include "ecar_core/common/error.h"

namespace ecar {

namespace {

// The database identifies itself in its meta table: format and schema version.
constexpr const char* kFormat = "ecar_vo_store";
// Version 2 adds objects.map_id (the atlas map); a version-1 file is upgraded
// in place (its objects were in the one map, id 1).
constexpr int kSchemaVersion = 2;
constexpr int kBusyTimeoutMs = 1000;

}  // namespace

// The SQLite connection: schema checks, loading, one transaction per change.
class VoDatabase::Connection {
 public:
  Connection(const std::string& path, const VoStoreConfig& config) : path_(path) {
    const int flags = SQLITE_OPEN_READWRITE | SQLITE_OPEN_CREATE | SQLITE_OPEN_NOMUTEX;
    if (sqlite3_open_v2(path.c_str(), &db_, flags, nullptr) != SQLITE_OK) {
      const std::string why = db_ ? sqlite3_errmsg(db_) : "out of memory";
      sqlite3_close(db_);
      db_ = nullptr;
      throw Error(path + ": cannot open the VO database: " + why);
    }
    try {
      init(config);
    } catch (...) {
      finalizeAll();
      sqlite3_close(db_);
      db_ = nullptr;
      throw;
    }
  }

  ~Connection() {
    finalizeAll();
    sqlite3_close(db_);
  }

  /// Calls `row` with every stored entry, by id; returns the stored id counter.
  template <typename F>
  uint32_t load(F&& row) {
    sqlite3_stmt* select = prepare(
        "SELECT id, kind, px, py, pz, sx, sy, sz, ex, ey, ez, r, g, b, width, nx, ny, nz, "
        "plane_id, owner, version, deleted, keyframe_id, last_editor, editor_since, map_id "
        "FROM objects ORDER BY id");
    try {
      int rc;
      while ((rc = sqlite3_step(select)) == SQLITE_ROW) row(readRow(select));
      if (rc != SQLITE_DONE) fail("reading the objects table");
    } catch (...) {
      sqlite3_finalize(select);
      throw;
    }
    sqlite3_finalize(select);
    const std::string next = metaValue("next_id");
    char* end = nullptr;
    const unsigned long long value = std::strtoull(next.c_str(), &end, 10);
    if (next.empty() || *end != '\0' || value < 1 || value > std::numeric_limits<uint32_t>::max()) {
      throw Error(path_ + ": malformed VO database: meta next_id is '" + next + "'");
    }
    return static_cast<uint32_t>(value);
  }

  /// Writes one object row and, when given, the id counter, in one transaction.
  /// Returns false with `error` set when it fails (the transaction is rolled back).
  bool write(const VoRecord& entry, std::optional<uint32_t> next_id, std::string* error) {
    return transaction(error, [&](std::string*) {
      return bindEntry(entry) && step(upsert_) && (!next_id || setNextId(*next_id));
    });
  }

  /// Writes object rows in one transaction. Returns false with `error` set
  /// when it fails (the transaction is rolled back).
  bool writeAll(const std::vector<const VoRecord*>& entries, std::string* error,
                std::optional<uint32_t> next_id) {
    return transaction(error, [&](std::string*) {
      bool ok = true;
      for (size_t i = 0; ok && i < entries.size(); ++i)
        ok = bindEntry(*entries[i]) && step(upsert_);
      return ok && (!next_id || setNextId(*next_id));
    });
  }

  /// Deletes the rows of `ids` in one transaction. Returns false with `error`
  /// set when it fails (the transaction is rolled back).
  bool eraseAll(const std::vector<ObjectId>& ids, std::string* error) {
    return transaction(error, [&](std::string*) {
      bool ok = true;
      for (size_t i = 0; ok && i < ids.size(); ++i) {
        ok = sqlite3_reset(erase_) == SQLITE_OK &&
             sqlite3_bind_int64(erase_, 1, static_cast<sqlite3_int64>(ids[i].value)) == SQLITE_OK &&
             step(erase_);
      }
      return ok;
    });
  }

  /// Replaces every row and the id counter in one transaction. Returns false
  /// with `error` set when it fails (the transaction is rolled back).
  bool replaceAll(const std::vector<const VoRecord*>& entries, uint32_t next_id,
                  std::string* error) {
    return transaction(error, [&](std::string* why) {
      bool ok = exec("DELETE FROM objects", why);
      for (size_t i = 0; ok && i < entries.size(); ++i)
        ok = bindEntry(*entries[i]) && step(upsert_);
      return ok && setNextId(next_id);
    });
  }

  /// Copies the database to `path` (online backup API).
  void backupTo(const std::string& path) const {
    sqlite3* dest = nullptr;
    if (sqlite3_open(path.c_str(), &dest) != SQLITE_OK) {
      const std::string why = dest ? sqlite3_errmsg(dest) : "out of memory";
      sqlite3_close(dest);
      throw Error(path + ": cannot open the backup file: " + why);
    }
    sqlite3_backup* backup = sqlite3_backup_init(dest, "main", db_, "main");
    int rc = SQLITE_ERROR;
    if (backup) {
      rc = sqlite3_backup_step(backup, -1);
      sqlite3_backup_finish(backup);
    }
    const std::string why = sqlite3_errmsg(dest);
    sqlite3_close(dest);
    if (rc != SQLITE_DONE) throw Error(path + ": VO database backup failed: " + why);
  }

 private:
  void init(const VoStoreConfig& config) {
    sqlite3_extended_result_codes(db_, 1);
    sqlite3_busy_timeout(db_, kBusyTimeoutMs);
    const bool in_memory = path_ == ":memory:";
    // One server owns the file: in exclusive locking mode the locks taken are
    // kept until close, so a second process cannot assign the same ids.
    if (!in_memory) execOrThrow("PRAGMA locking_mode = EXCLUSIVE", "setting the locking mode");

    // Look at the file before changing anything in it (a foreign file is left as it is).
    std::vector<std::string> tables;
    {
      sqlite3_stmt* list = nullptr;
      int rc = sqlite3_prepare_v2(
          db_, "SELECT name FROM sqlite_master WHERE type = 'table' ORDER BY name", -1, &list,
          nullptr);
      if (rc != SQLITE_OK) {
        const std::string why = sqlite3_errmsg(db_);
        throw Error(path_ + ": cannot read it as an SQLite database: " + why);
      }
      while ((rc = sqlite3_step(list)) == SQLITE_ROW) {
        tables.emplace_back(reinterpret_cast<const char*>(sqlite3_column_text(list, 0)));
      }
      sqlite3_finalize(list);
      if (rc != SQLITE_DONE) fail("reading its schema (not an SQLite database?)");
    }
    if (tables.empty()) {
      createSchema();
    } else {
      const bool has_meta = std::count(tables.begin(), tables.end(), "meta") > 0;
      const bool has_objects = std::count(tables.begin(), tables.end(), "objects") > 0;
      if (!has_meta || !has_objects) {
        std::string names;
        for (const std::string& t : tables) names += (names.empty() ? "" : ", ") + t;
        throw Error(path_ + ": not an eCAR VO database (its tables are: " + names + ")");
      }
      const std::string format = metaValue("format");
      if (format != kFormat) {
        throw Error(path_ + ": not an eCAR VO database (meta format is '" + format + "')");
      }
      std::string schema = metaValue("schema_version");
      if (schema == "1") {
        execOrThrow(
            "BEGIN IMMEDIATE;"
            "ALTER TABLE objects ADD COLUMN map_id INTEGER NOT NULL DEFAULT 1;"
            "UPDATE meta SET value = '2' WHERE key = 'schema_version';"
            "COMMIT",
            "upgrading the schema from version 1 to 2");
        schema = metaValue("schema_version");
      }
      if (schema != std::to_string(kSchemaVersion)) {
        throw Error(path_ + ": VO database schema version '" + schema + "', this build reads " +
                    std::to_string(kSchemaVersion));
      }
    }
    {
      sqlite3_stmt* check = prepare("PRAGMA quick_check");
      std::string result;
      while (sqlite3_step(check) == SQLITE_ROW) {
        const unsigned char* text = sqlite3_column_text(check, 0);
        result += (result.empty() ? "" : "; ") +
                  std::string(text ? reinterpret_cast<const char*>(text) : "");
      }
      sqlite3_finalize(check);
      if (result != "ok") throw Error(path_ + ": malformed VO database: " + result);
    }
    if (!in_memory) {
      sqlite3_stmt* mode = prepare("PRAGMA journal_mode = WAL");
      std::string result;
      if (sqlite3_step(mode) == SQLITE_ROW) {
        result = reinterpret_cast<const char*>(sqlite3_column_text(mode, 0));
      }
      sqlite3_finalize(mode);
      if (result != "wal") {
        throw Error(path_ + ": cannot switch the VO database to WAL journal mode (got '" + result +
                    "'): " + sqlite3_errmsg(db_));
      }
    }
    execOrThrow(config.synchronous == "normal" ? "PRAGMA synchronous = NORMAL"
                                               : "PRAGMA synchronous = FULL",
                "setting synchronous");
    if (config.max_database_mb > 0.0) {
      const long long pages =
          std::max(1LL, static_cast<long long>(config.max_database_mb * 1024.0 * 1024.0 /
                                               static_cast<double>(pageSize())));
      execOrThrow("PRAGMA max_page_count = " + std::to_string(pages), "setting max_page_count");
    }
    // Take the exclusive lock now, so a database in use fails here, not at the first change.
    execOrThrow("BEGIN EXCLUSIVE", "locking (is another process using it?)");
    execOrThrow("COMMIT", "locking");
    upsert_ = prepare(
        "INSERT OR REPLACE INTO objects (id, kind, px, py, pz, sx, sy, sz, ex, ey, ez, r, g, b, "
        "width, nx, ny, nz, plane_id, owner, version, deleted, keyframe_id, last_editor, "
        "editor_since, map_id) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, ?13, "
        "?14, ?15, ?16, ?17, ?18, ?19, ?20, ?21, ?22, ?23, ?24, ?25, ?26)");
    set_meta_ = prepare("INSERT OR REPLACE INTO meta (key, value) VALUES (?1, ?2)");
    erase_ = prepare("DELETE FROM objects WHERE id = ?1");
  }

  void createSchema() {
    execOrThrow("BEGIN IMMEDIATE", "creating the schema");
    execOrThrow(
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
        " last_editor TEXT NOT NULL, editor_since INTEGER NOT NULL,"
        " map_id INTEGER NOT NULL DEFAULT 1);"
        "INSERT INTO meta (key, value) VALUES ('format', '" +
            std::string(kFormat) + "'), ('schema_version', '" + std::to_string(kSchemaVersion) +
            "'), ('next_id', '1');"
            "COMMIT",
        "creating the schema");
  }

  long long pageSize() {
    sqlite3_stmt* page = prepare("PRAGMA page_size");
    long long size = 4096;
    if (sqlite3_step(page) == SQLITE_ROW) size = sqlite3_column_int64(page, 0);
    sqlite3_finalize(page);
    return size > 0 ? size : 4096;
  }

  std::string metaValue(const char* key) {
    sqlite3_stmt* get = prepare("SELECT value FROM meta WHERE key = ?1");
    sqlite3_bind_text(get, 1, key, -1, SQLITE_STATIC);
    std::string value;
    const int rc = sqlite3_step(get);
    if (rc == SQLITE_ROW && sqlite3_column_type(get, 0) != SQLITE_NULL) {
      value = reinterpret_cast<const char*>(sqlite3_column_text(get, 0));
    }
    sqlite3_finalize(get);
    if (rc != SQLITE_ROW && rc != SQLITE_DONE) fail(std::string("reading meta ") + key);
    return value;
  }

  VoRecord readRow(sqlite3_stmt* s) {
    const long long id = sqlite3_column_int64(s, 0);
    auto bad = [&](const std::string& why) {
      throw Error(path_ + ": malformed VO database: object " + std::to_string(id) + ": " + why);
    };
    for (int col = 0; col < 26; ++col) {
      const int type = sqlite3_column_type(s, col);
      const bool text_col = col == 19 || col == 23;
      if (text_col ? type != SQLITE_TEXT : (type != SQLITE_INTEGER && type != SQLITE_FLOAT)) {
        bad(std::string("column ") + sqlite3_column_name(s, col) + " has the wrong type");
      }
    }
    auto integer = [&](int col, long long lo, long long hi) {
      const long long v = sqlite3_column_int64(s, col);
      if (sqlite3_column_type(s, col) != SQLITE_INTEGER || v < lo || v > hi) {
        bad(std::string(sqlite3_column_name(s, col)) + " " + std::to_string(v) +
            " is out of range");
      }
      return v;
    };
    auto vec = [&](int col) {
      return Eigen::Vector3d(sqlite3_column_double(s, col), sqlite3_column_double(s, col + 1),
                             sqlite3_column_double(s, col + 2));
    };
    const long long max_u32 = std::numeric_limits<uint32_t>::max();
    VoRecord e;
    e.vo.id = ObjectId(static_cast<uint32_t>(integer(0, 1, max_u32)));
    e.vo.kind = static_cast<VoKind>(integer(1, 0, 1));
    e.vo.position = vec(2);
    e.vo.start = vec(5);
    e.vo.end = vec(8);
    e.vo.r = static_cast<uint8_t>(integer(11, 0, 255));
    e.vo.g = static_cast<uint8_t>(integer(12, 0, 255));
    e.vo.b = static_cast<uint8_t>(integer(13, 0, 255));
    e.vo.width = static_cast<float>(sqlite3_column_double(s, 14));
    e.vo.normal = vec(15);
    e.vo.plane = PlaneId(static_cast<uint32_t>(integer(18, 0, max_u32)));
    e.vo.owner = reinterpret_cast<const char*>(sqlite3_column_text(s, 19));
    e.vo.version = static_cast<uint32_t>(integer(20, 1, max_u32));
    e.vo.deleted = integer(21, 0, 1) != 0;
    e.keyframe = KeyFrameId(static_cast<uint32_t>(integer(22, 0, max_u32)));
    e.last_editor = reinterpret_cast<const char*>(sqlite3_column_text(s, 23));
    e.editor_since = static_cast<uint32_t>(integer(24, 0, max_u32));
    e.vo.map = MapId(static_cast<uint32_t>(integer(25, 0, max_u32)));
    if (!coordinatesFinite(e.vo)) bad("a coordinate is not finite");
    if (e.editor_since > e.vo.version) bad("editor_since is after its version");
    return e;
  }

  bool bindEntry(const VoRecord& e) {
    sqlite3_stmt* s = upsert_;
    sqlite3_reset(s);
    sqlite3_clear_bindings(s);
    int col = 1;
    bool ok = true;
    auto i64 = [&](long long v) { ok = ok && sqlite3_bind_int64(s, col++, v) == SQLITE_OK; };
    auto dbl = [&](double v) { ok = ok && sqlite3_bind_double(s, col++, v) == SQLITE_OK; };
    auto txt = [&](const std::string& v) {
      ok = ok && sqlite3_bind_text(s, col++, v.c_str(), static_cast<int>(v.size()),
                                   SQLITE_TRANSIENT) == SQLITE_OK;
    };
    auto vec = [&](const Eigen::Vector3d& v) {
      dbl(v.x());
      dbl(v.y());
      dbl(v.z());
    };
    i64(e.vo.id.value);
    i64(static_cast<int>(e.vo.kind));
    vec(e.vo.position);
    vec(e.vo.start);
    vec(e.vo.end);
    i64(e.vo.r);
    i64(e.vo.g);
    i64(e.vo.b);
    dbl(e.vo.width);
    vec(e.vo.normal);
    i64(e.vo.plane.value);
    txt(e.vo.owner);
    i64(e.vo.version);
    i64(e.vo.deleted ? 1 : 0);
    i64(e.keyframe.value);
    txt(e.last_editor);
    i64(e.editor_since);
    i64(e.vo.map.value);
    return ok;
  }

  /// Runs `body` (statements of this connection, reporting into its argument)
  /// between BEGIN IMMEDIATE and COMMIT; rolls back and returns false with
  /// `error` set (the body's text, else SQLite's message) when any part fails.
  template <typename Body>
  bool transaction(std::string* error, Body body) {
    if (!exec("BEGIN IMMEDIATE", error)) return false;
    bool ok = body(error);
    if (ok) ok = exec("COMMIT", error);
    if (!ok) {
      if (error->empty()) *error = sqlite3_errmsg(db_);
      if (!sqlite3_get_autocommit(db_)) sqlite3_exec(db_, "ROLLBACK", nullptr, nullptr, nullptr);
    }
    return ok;
  }

  /// Binds and writes the "next_id" meta row (inside a transaction).
  bool setNextId(uint32_t next_id) {
    return sqlite3_bind_text(set_meta_, 1, "next_id", -1, SQLITE_STATIC) == SQLITE_OK &&
           sqlite3_bind_text(set_meta_, 2, std::to_string(next_id).c_str(), -1, SQLITE_TRANSIENT) ==
               SQLITE_OK &&
           step(set_meta_);
  }

  bool step(sqlite3_stmt* s) {
    const int rc = sqlite3_step(s);
    sqlite3_reset(s);
    return rc == SQLITE_DONE;
  }

  bool exec(const std::string& sql, std::string* error) {
    char* message = nullptr;
    if (sqlite3_exec(db_, sql.c_str(), nullptr, nullptr, &message) == SQLITE_OK) return true;
    *error = message ? message : sqlite3_errmsg(db_);
    sqlite3_free(message);
    return false;
  }

  void execOrThrow(const std::string& sql, const std::string& what) {
    std::string error;
    if (!exec(sql, &error)) throw Error(path_ + ": VO database, " + what + ": " + error);
  }

  sqlite3_stmt* prepare(const std::string& sql) {
    sqlite3_stmt* s = nullptr;
    if (sqlite3_prepare_v2(db_, sql.c_str(), -1, &s, nullptr) != SQLITE_OK) {
      fail("preparing '" + sql.substr(0, 40) + "...'");
    }
    return s;
  }

  [[noreturn]] void fail(const std::string& what) {
    throw Error(path_ + ": VO database, " + what + ": " + sqlite3_errmsg(db_));
  }

  void finalizeAll() {
    sqlite3_finalize(upsert_);
    sqlite3_finalize(set_meta_);
    sqlite3_finalize(erase_);
    upsert_ = set_meta_ = erase_ = nullptr;
  }

  std::string path_;
  sqlite3* db_ = nullptr;
  sqlite3_stmt* upsert_ = nullptr;
  sqlite3_stmt* set_meta_ = nullptr;
  sqlite3_stmt* erase_ = nullptr;
};

VoDatabase::VoDatabase(const VoStoreConfig& config)
    : connection_(std::make_unique<Connection>(config.database_path, config)) {}

VoDatabase::~VoDatabase() = default;

uint32_t VoDatabase::load(const std::function<void(VoRecord)>& row) {
  return connection_->load(row);
}

bool VoDatabase::write(const VoRecord& record, std::optional<uint32_t> next_id,
                       std::string* error) {
  return connection_->write(record, next_id, error);
}

bool VoDatabase::writeAll(const std::vector<const VoRecord*>& records, std::string* error,
                          std::optional<uint32_t> next_id) {
  return connection_->writeAll(records, error, next_id);
}

bool VoDatabase::eraseAll(const std::vector<ObjectId>& ids, std::string* error) {
  return connection_->eraseAll(ids, error);
}

bool VoDatabase::replaceAll(const std::vector<const VoRecord*>& records, uint32_t next_id,
                            std::string* error) {
  return connection_->replaceAll(records, next_id, error);
}

void VoDatabase::backupTo(const std::string& path) const { connection_->backupTo(path); }

}  // namespace ecar
