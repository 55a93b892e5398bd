#include "ecar_core/vo_store.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <limits>
#include <sstream>
#include <utility>

#include <sqlite3.h>

#include "ecar_core/error.h"

namespace ecar {

namespace {

// The database identifies itself in its meta table: format and schema version.
constexpr const char* kFormat = "ecar_vo_store";
constexpr int kSchemaVersion = 1;
constexpr int kBusyTimeoutMs = 1000;

bool finiteVector(const Eigen::Vector3d& v) { return v.allFinite(); }

std::string str(const Eigen::Vector3d& v) {
  std::ostringstream os;
  os << "(" << v.x() << ", " << v.y() << ", " << v.z() << ")";
  return os.str();
}

std::string str(double value) {
  std::ostringstream os;
  os << value;
  return os.str();
}

CellKey cellOf(const Eigen::Vector3d& p_w, double cell_size) {
  return CellKey{static_cast<int32_t>(std::floor(p_w.x() / cell_size)),
                 static_cast<int32_t>(std::floor(p_w.y() / cell_size)),
                 static_cast<int32_t>(std::floor(p_w.z() / cell_size))};
}

int32_t& axis(CellKey& c, int i) { return i == 0 ? c.x : i == 1 ? c.y : c.z; }

// Whether the segment a + t (b - a), t in [0, 1], meets the closed box [lo, hi].
bool segmentMeetsBox(const Eigen::Vector3d& a, const Eigen::Vector3d& b, const Eigen::Vector3d& lo,
                     const Eigen::Vector3d& hi) {
  const Eigen::Vector3d d = b - a;
  double t_min = 0.0, t_max = 1.0;
  for (int i = 0; i < 3; ++i) {
    if (d[i] == 0.0) {
      if (a[i] < lo[i] || a[i] > hi[i]) return false;
      continue;
    }
    double t1 = (lo[i] - a[i]) / d[i], t2 = (hi[i] - a[i]) / d[i];
    if (t1 > t2) std::swap(t1, t2);
    t_min = std::max(t_min, t1);
    t_max = std::min(t_max, t2);
    if (t_min > t_max) return false;
  }
  return true;
}

// The cells the segment a-b crosses, in order (3D DDA; a point when a == b).
// Each step moves one axis towards the end point's cell, so the walk ends
// there even when rounding disagrees with floor() at a boundary.
std::vector<CellKey> traverse(const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                              double cell_size) {
  CellKey c = cellOf(a, cell_size);
  const CellKey goal = cellOf(b, cell_size);
  const Eigen::Vector3d d = b - a;
  const double inf = std::numeric_limits<double>::infinity();
  int step[3];
  double t_next[3], t_delta[3];
  for (int i = 0; i < 3; ++i) {
    const double k = axis(c, i);
    if (d[i] > 0.0) {
      step[i] = 1;
      t_next[i] = ((k + 1.0) * cell_size - a[i]) / d[i];
      t_delta[i] = cell_size / d[i];
    } else if (d[i] < 0.0) {
      step[i] = -1;
      t_next[i] = (k * cell_size - a[i]) / d[i];
      t_delta[i] = -cell_size / d[i];
    } else {
      step[i] = 0;
      t_next[i] = inf;
      t_delta[i] = inf;
    }
  }
  CellKey g = goal;
  std::vector<CellKey> cells{c};
  while (c != goal) {
    int best = -1;
    for (int i = 0; i < 3; ++i) {
      if (axis(c, i) == axis(g, i) || step[i] == 0) continue;
      if (best < 0 || t_next[i] < t_next[best]) best = i;
    }
    if (best < 0) {
      // Rounding left an axis short with no direction to move in; end at the goal.
      cells.push_back(goal);
      break;
    }
    axis(c, best) += step[best];
    t_next[best] += t_delta[best];
    cells.push_back(c);
  }
  return cells;
}

}  // namespace

const char* toString(VoAttachMode mode) {
  return mode == VoAttachMode::kKeyFrame ? "keyframe" : "grid";
}

VoAttachMode parseVoAttachMode(const std::string& text) {
  if (text == "grid") return VoAttachMode::kGrid;
  if (text == "keyframe") return VoAttachMode::kKeyFrame;
  throw Error("vo_attach: '" + text + "' is neither 'grid' nor 'keyframe'");
}

void VoStoreConfig::validate() const {
  auto fail = [](const std::string& key, const std::string& why) { throw Error(key + ": " + why); };
  auto positive = [](double v) { return std::isfinite(v) && v > 0.0; };
  if (database_path.empty()) fail("database_path", "must not be empty");
  if (synchronous != "full" && synchronous != "normal") {
    fail("synchronous", "'" + synchronous + "' is neither 'full' nor 'normal'");
  }
  if (!positive(cell_size) || cell_size > 10.0) fail("cell_size", "must be in (0, 10] m");
  if (!std::isfinite(attach_margin) || attach_margin < 0.0 || attach_margin >= cell_size / 2.0) {
    fail("attach_margin", "must be in [0, cell_size / 2) m");
  }
  if (attach_mode != VoAttachMode::kGrid && attach_mode != VoAttachMode::kKeyFrame) {
    fail("attach_mode", "must be grid or keyframe");
  }
  if (!map_min.allFinite() || !map_max.allFinite() || (map_min.array() >= map_max.array()).any()) {
    fail("map_min", "map bounds must be finite with map_min < map_max on every axis");
  }
  // Cell coordinates must stay well inside int32 and the CellKey hash's 21-bit fields.
  const double extent = std::max(map_min.cwiseAbs().maxCoeff(), map_max.cwiseAbs().maxCoeff());
  if (extent / cell_size >= (1 << 20)) {
    fail("map_max", "map bounds span more than 2^20 cells of cell_size from the origin");
  }
  if (!positive(min_line_length)) fail("min_line_length", "must be > 0 m");
  if (!positive(max_line_length) || max_line_length < min_line_length) {
    fail("max_line_length", "must be >= min_line_length");
  }
  if (!positive(max_width)) fail("max_width", "must be > 0 m");
  if (max_owner_length < 1) fail("max_owner_length", "must be >= 1");
  if (max_objects < 1 || max_objects >= std::numeric_limits<uint32_t>::max()) {
    fail("max_objects", "must be in [1, 2^32 - 1)");
  }
  if (!std::isfinite(max_database_mb) || max_database_mb < 0.0) {
    fail("max_database_mb", "must be >= 0 (0 = unlimited)");
  }
}

std::vector<CellKey> attachmentCells(const VirtualObject& vo, double cell_size, double margin) {
  const bool line = vo.kind == VoKind::kLine;
  const Eigen::Vector3d a = line ? vo.start : vo.position;
  const Eigen::Vector3d b = line ? vo.end : vo.position;
  std::vector<CellKey> cells = traverse(a, b, cell_size);
  if (margin > 0.0) {
    // A cell within `margin` of the segment is a neighbour of a crossed cell
    // (margin < cell): test the 26 neighbours of each, expanded by the margin.
    const size_t crossed = cells.size();
    for (size_t k = 0; k < crossed; ++k) {
      const CellKey c = cells[k];
      for (int dx = -1; dx <= 1; ++dx) {
        for (int dy = -1; dy <= 1; ++dy) {
          for (int dz = -1; dz <= 1; ++dz) {
            if (dx == 0 && dy == 0 && dz == 0) continue;
            const CellKey n{c.x + dx, c.y + dy, c.z + dz};
            const Eigen::Vector3d lo =
                Eigen::Vector3d(n.x, n.y, n.z) * cell_size - Eigen::Vector3d::Constant(margin);
            const Eigen::Vector3d hi = Eigen::Vector3d(n.x + 1, n.y + 1, n.z + 1) * cell_size +
                                       Eigen::Vector3d::Constant(margin);
            if (segmentMeetsBox(a, b, lo, hi)) cells.push_back(n);
          }
        }
      }
    }
  }
  std::sort(cells.begin(), cells.end());
  cells.erase(std::unique(cells.begin(), cells.end()), cells.end());
  return cells;
}

// ---------------------------------------------------------------- database

// The SQLite connection: schema checks, loading, one transaction per change.
// Not thread-safe: VoStore calls it under write_mutex_ (or in its constructor).
class VoStore::Database {
 public:
  Database(const std::string& path, const VoStoreConfig& config) : path_(path) {
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

  ~Database() {
    finalizeAll();
    sqlite3_close(db_);
  }

  /// Calls `row` with every stored entry, by id; returns the stored id counter.
  template <typename F>
  uint32_t load(F&& row) {
    sqlite3_stmt* select = prepare(
        "SELECT id, kind, px, py, pz, sx, sy, sz, ex, ey, ez, r, g, b, width, nx, ny, nz, "
        "plane_id, owner, version, deleted, keyframe_id, last_editor, editor_since "
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
  bool write(const Entry& entry, std::optional<uint32_t> next_id, std::string* error) {
    return transaction(error, [&](std::string*) {
      return bindEntry(entry) && step(upsert_) && (!next_id || setNextId(*next_id));
    });
  }

  /// Writes object rows in one transaction. Returns false with `error` set
  /// when it fails (the transaction is rolled back).
  bool writeAll(const std::vector<const Entry*>& entries, std::string* error) {
    return transaction(error, [&](std::string*) {
      bool ok = true;
      for (size_t i = 0; ok && i < entries.size(); ++i)
        ok = bindEntry(*entries[i]) && step(upsert_);
      return ok;
    });
  }

  /// Replaces every row and the id counter in one transaction. Returns false
  /// with `error` set when it fails (the transaction is rolled back).
  bool replaceAll(const std::vector<const Entry*>& entries, uint32_t next_id, std::string* error) {
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
      const std::string schema = metaValue("schema_version");
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
        "editor_since) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, ?13, ?14, ?15, "
        "?16, ?17, ?18, ?19, ?20, ?21, ?22, ?23, ?24, ?25)");
    set_meta_ = prepare("INSERT OR REPLACE INTO meta (key, value) VALUES (?1, ?2)");
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
        " last_editor TEXT NOT NULL, editor_since INTEGER NOT NULL);"
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

  Entry readRow(sqlite3_stmt* s) {
    const long long id = sqlite3_column_int64(s, 0);
    auto bad = [&](const std::string& why) {
      throw Error(path_ + ": malformed VO database: object " + std::to_string(id) + ": " + why);
    };
    for (int col = 0; col < 25; ++col) {
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
    Entry e;
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
    if (!finiteVector(e.vo.position) || !finiteVector(e.vo.start) || !finiteVector(e.vo.end) ||
        !finiteVector(e.vo.normal) || !std::isfinite(e.vo.width)) {
      bad("a coordinate is not finite");
    }
    if (e.editor_since > e.vo.version) bad("editor_since is after its version");
    return e;
  }

  bool bindEntry(const Entry& e) {
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
    upsert_ = set_meta_ = nullptr;
  }

  std::string path_;
  sqlite3* db_ = nullptr;
  sqlite3_stmt* upsert_ = nullptr;
  sqlite3_stmt* set_meta_ = nullptr;
};

// ---------------------------------------------------------------- store

VoStore::VoStore(const VoStoreConfig& config)
    : config_((config.validate(), config)), map_min_(config.map_min), map_max_(config.map_max) {
  db_ = std::make_unique<Database>(config_.database_path, config_);
  uint32_t max_id = 0;
  const uint32_t stored_next = db_->load([&](Entry entry) {
    max_id = std::max(max_id, entry.vo.id.value);
    if (!entry.vo.deleted) {
      entry.cells = attachmentCells(entry.vo, config_.cell_size, config_.attach_margin);
      attach(entry);
      ++num_live_;
    }
    const ObjectId id = entry.vo.id;
    objects_.emplace(id, std::move(entry));
  });
  next_id_ = std::max(stored_next, max_id + 1);
}

VoStore::~VoStore() = default;

VoReject VoStore::check(VirtualObject* vo, std::string* reason) const {
  const uint8_t kind = static_cast<uint8_t>(vo->kind);
  if (kind > 1) {
    *reason = "kind " + std::to_string(kind) + " is neither LINE (0) nor ANCHOR (1)";
    return VoReject::kBadAttribute;
  }
  const bool line = vo->kind == VoKind::kLine;
  const std::pair<const char*, const Eigen::Vector3d*> vectors[] = {{"position", &vo->position},
                                                                    {"start", &vo->start},
                                                                    {"end", &vo->end},
                                                                    {"normal", &vo->normal}};
  for (const auto& [name, v] : vectors) {
    if (!finiteVector(*v)) {
      *reason = std::string(name) + " is not finite " + str(*v);
      return VoReject::kNotFinite;
    }
  }
  if (!std::isfinite(vo->width)) {
    *reason = "width is not finite (" + str(vo->width) + ")";
    return VoReject::kNotFinite;
  }
  if (line ? !(vo->width > 0.0f && vo->width <= config_.max_width)
           : !(vo->width >= 0.0f && vo->width <= config_.max_width)) {
    *reason = "width " + str(vo->width) + " m is not in " + (line ? "(0, " : "[0, ") +
              str(config_.max_width) + "] m";
    return VoReject::kBadAttribute;
  }
  if (vo->owner.size() > config_.max_owner_length) {
    *reason = "owner is longer than " + std::to_string(config_.max_owner_length) + " characters";
    return VoReject::kBadAttribute;
  }
  const double normal_norm = vo->normal.norm();
  if (normal_norm < 1e-9) {
    *reason = "normal is zero";
    return VoReject::kBadGeometry;
  }
  vo->normal /= normal_norm;
  if (line) {
    const double length = (vo->end - vo->start).norm();
    if (length < config_.min_line_length) {
      *reason = "line length " + str(length) + " m is below min_line_length " +
                str(config_.min_line_length) + " m";
      return VoReject::kBadGeometry;
    }
    if (length > config_.max_line_length) {
      *reason = "line length " + str(length) + " m exceeds max_line_length " +
                str(config_.max_line_length) + " m";
      return VoReject::kBadGeometry;
    }
    vo->position = 0.5 * (vo->start + vo->end);
  } else {
    vo->start = vo->end = vo->position;
  }
  // A line lies inside the (convex) bounds when its end points do.
  std::vector<std::pair<const char*, const Eigen::Vector3d*>> points;
  if (line) {
    points = {{"start", &vo->start}, {"end", &vo->end}};
  } else {
    points = {{"position", &vo->position}};
  }
  for (const auto& [name, p] : points) {
    if ((p->array() < map_min_.array()).any() || (p->array() > map_max_.array()).any()) {
      *reason = std::string(name) + " " + str(*p) + " is out of the map bounds " + str(map_min_) +
                " to " + str(map_max_);
      return VoReject::kOutOfMap;
    }
  }
  return VoReject::kNone;
}

VoReject VoStore::checkExisting(ObjectId id, uint32_t base_version, bool unconditional_ok,
                                const std::string& editor, std::string* reason,
                                const Entry** entry) const {
  const auto it = objects_.find(id);
  if (it == objects_.end()) {
    *reason = "unknown object id " + std::to_string(id.value);
    return VoReject::kUnknownId;
  }
  *entry = &it->second;
  const VirtualObject& vo = it->second.vo;
  if (vo.deleted) {
    *reason = "object " + std::to_string(id.value) + " was deleted (version " +
              std::to_string(vo.version) + ")";
    return VoReject::kDeleted;
  }
  if ((base_version == 0 && unconditional_ok) || base_version == vo.version) {
    return VoReject::kNone;
  }
  if (base_version > vo.version) {
    *reason = "base_version " + std::to_string(base_version) +
              " is newer than the store's version " + std::to_string(vo.version) + " of object " +
              std::to_string(id.value);
    return VoReject::kStaleVersion;
  }
  if (base_version > 0 && config_.accept_own_stale && !editor.empty() &&
      editor == it->second.last_editor && base_version >= it->second.editor_since) {
    return VoReject::kNone;
  }
  *reason = "stale base_version " + std::to_string(base_version) + ": the store has version " +
            std::to_string(vo.version) + " of object " + std::to_string(id.value);
  return VoReject::kStaleVersion;
}

void VoStore::attach(const Entry& entry) {
  for (const CellKey& c : entry.cells) cell_index_[c].push_back(entry.vo.id);
  if (entry.keyframe.valid()) keyframe_index_[entry.keyframe].push_back(entry.vo.id);
}

void VoStore::detach(const Entry& entry) {
  auto drop = [&](auto& index, const auto& key) {
    const auto it = index.find(key);
    if (it == index.end()) return;
    auto& ids = it->second;
    ids.erase(std::remove(ids.begin(), ids.end(), entry.vo.id), ids.end());
    if (ids.empty()) index.erase(it);
  };
  for (const CellKey& c : entry.cells) drop(cell_index_, c);
  if (entry.keyframe.valid()) drop(keyframe_index_, entry.keyframe);
}

namespace {
VoOutcome reject(VoReject code, std::string reason, ObjectId id, uint32_t version) {
  VoOutcome out;
  out.code = code;
  out.reason = std::move(reason);
  out.id = id;
  out.version = version;
  return out;
}

VoOutcome accept(ObjectId id, uint32_t version) {
  VoOutcome out;
  out.accepted = true;
  out.id = id;
  out.version = version;
  return out;
}
}  // namespace

VoOutcome VoStore::registerObject(const VirtualObject& request, KeyFrameId keyframe) {
  std::lock_guard<std::mutex> write(write_mutex_);
  Entry entry;
  entry.vo = request;
  std::string reason;
  VoReject code = check(&entry.vo, &reason);
  if (code != VoReject::kNone) return reject(code, reason, ObjectId(), 0);
  if (config_.attach_mode == VoAttachMode::kKeyFrame && !keyframe.valid()) {
    return reject(VoReject::kNoKeyFrame, "keyframe attachment needs the nearest keyframe",
                  ObjectId(), 0);
  }
  if (objects_.size() >= config_.max_objects || next_id_ == std::numeric_limits<uint32_t>::max()) {
    return reject(VoReject::kFull,
                  "the store is full (" + std::to_string(objects_.size()) + " objects)", ObjectId(),
                  0);
  }
  entry.vo.id = ObjectId(next_id_);
  entry.vo.version = 1;
  entry.vo.deleted = false;
  entry.keyframe = keyframe;
  entry.last_editor = entry.vo.owner;
  entry.editor_since = 0;
  entry.cells = attachmentCells(entry.vo, config_.cell_size, config_.attach_margin);
  std::string error;
  if (!db_->write(entry, next_id_ + 1, &error)) {
    return reject(VoReject::kStorage, "database write failed: " + error, ObjectId(), 0);
  }
  std::unique_lock<std::shared_mutex> state(state_mutex_);
  ++next_id_;
  attach(entry);
  ++num_live_;
  const ObjectId id = entry.vo.id;
  objects_.emplace(id, std::move(entry));
  return accept(id, 1);
}

VoOutcome VoStore::manipulate(ObjectId id, uint32_t base_version, const VirtualObject& new_state,
                              const std::string& editor) {
  std::lock_guard<std::mutex> write(write_mutex_);
  std::string reason;
  const Entry* old = nullptr;
  VoReject code = checkExisting(id, base_version, false, editor, &reason, &old);
  const uint32_t current = old ? old->vo.version : 0;
  if (code != VoReject::kNone) return reject(code, reason, id, current);
  Entry entry = *old;
  entry.vo = new_state;
  code = check(&entry.vo, &reason);
  if (code != VoReject::kNone) return reject(code, reason, id, current);
  entry.vo.id = id;
  entry.vo.owner = old->vo.owner;
  entry.vo.version = current + 1;
  entry.vo.deleted = false;
  if (editor.empty() || editor != old->last_editor) entry.editor_since = current;
  entry.last_editor = editor;
  entry.cells = attachmentCells(entry.vo, config_.cell_size, config_.attach_margin);
  std::string error;
  if (!db_->write(entry, std::nullopt, &error)) {
    return reject(VoReject::kStorage, "database write failed: " + error, id, current);
  }
  std::unique_lock<std::shared_mutex> state(state_mutex_);
  Entry& stored = objects_.at(id);
  detach(stored);
  stored = std::move(entry);
  attach(stored);
  return accept(id, current + 1);
}

VoOutcome VoStore::remove(ObjectId id, uint32_t base_version, const std::string& editor) {
  std::lock_guard<std::mutex> write(write_mutex_);
  std::string reason;
  const Entry* old = nullptr;
  const VoReject code = checkExisting(id, base_version, true, editor, &reason, &old);
  const uint32_t current = old ? old->vo.version : 0;
  if (code != VoReject::kNone) return reject(code, reason, id, current);
  Entry entry = *old;
  entry.vo.version = current + 1;
  entry.vo.deleted = true;
  if (editor.empty() || editor != old->last_editor) entry.editor_since = current;
  entry.last_editor = editor;
  entry.cells.clear();
  std::string error;
  if (!db_->write(entry, std::nullopt, &error)) {
    return reject(VoReject::kStorage, "database write failed: " + error, id, current);
  }
  std::unique_lock<std::shared_mutex> state(state_mutex_);
  Entry& stored = objects_.at(id);
  detach(stored);
  stored = std::move(entry);
  --num_live_;
  return accept(id, current + 1);
}

std::vector<VirtualObject> VoStore::objectsInCells(const std::vector<CellKey>& cells) const {
  std::shared_lock<std::shared_mutex> state(state_mutex_);
  std::vector<ObjectId> ids;
  for (const CellKey& c : cells) {
    const auto it = cell_index_.find(c);
    if (it != cell_index_.end()) ids.insert(ids.end(), it->second.begin(), it->second.end());
  }
  std::sort(ids.begin(), ids.end());
  ids.erase(std::unique(ids.begin(), ids.end()), ids.end());
  std::vector<VirtualObject> out;
  out.reserve(ids.size());
  for (ObjectId id : ids) out.push_back(objects_.at(id).vo);
  return out;
}

std::vector<VirtualObject> VoStore::objectsOfKeyFrames(
    const std::vector<KeyFrameId>& keyframes) const {
  std::shared_lock<std::shared_mutex> state(state_mutex_);
  std::vector<ObjectId> ids;
  for (KeyFrameId k : keyframes) {
    const auto it = keyframe_index_.find(k);
    if (it != keyframe_index_.end()) ids.insert(ids.end(), it->second.begin(), it->second.end());
  }
  std::sort(ids.begin(), ids.end());
  ids.erase(std::unique(ids.begin(), ids.end()), ids.end());
  std::vector<VirtualObject> out;
  out.reserve(ids.size());
  for (ObjectId id : ids) out.push_back(objects_.at(id).vo);
  return out;
}

std::optional<VirtualObject> VoStore::get(ObjectId id) const {
  std::shared_lock<std::shared_mutex> state(state_mutex_);
  const auto it = objects_.find(id);
  if (it == objects_.end()) return std::nullopt;
  return it->second.vo;
}

std::vector<VirtualObject> VoStore::objects(const std::vector<ObjectId>& ids) const {
  std::vector<ObjectId> sorted = ids;
  std::sort(sorted.begin(), sorted.end());
  sorted.erase(std::unique(sorted.begin(), sorted.end()), sorted.end());
  std::shared_lock<std::shared_mutex> state(state_mutex_);
  std::vector<VirtualObject> out;
  out.reserve(sorted.size());
  for (ObjectId id : sorted) {
    const auto it = objects_.find(id);
    if (it != objects_.end()) out.push_back(it->second.vo);
  }
  return out;
}

std::vector<VirtualObject> VoStore::allObjects() const {
  std::shared_lock<std::shared_mutex> state(state_mutex_);
  std::vector<VirtualObject> out;
  out.reserve(objects_.size());
  for (const auto& [id, entry] : objects_) out.push_back(entry.vo);
  std::sort(out.begin(), out.end(),
            [](const VirtualObject& a, const VirtualObject& b) { return a.id < b.id; });
  return out;
}

std::vector<CellKey> VoStore::cellsOf(ObjectId id) const {
  std::shared_lock<std::shared_mutex> state(state_mutex_);
  const auto it = objects_.find(id);
  return it == objects_.end() ? std::vector<CellKey>() : it->second.cells;
}

KeyFrameId VoStore::keyFrameOf(ObjectId id) const {
  std::shared_lock<std::shared_mutex> state(state_mutex_);
  const auto it = objects_.find(id);
  return it == objects_.end() ? KeyFrameId() : it->second.keyframe;
}

size_t VoStore::numObjects() const {
  std::shared_lock<std::shared_mutex> state(state_mutex_);
  return objects_.size();
}

size_t VoStore::numLive() const {
  std::shared_lock<std::shared_mutex> state(state_mutex_);
  return num_live_;
}

ObjectId VoStore::nextId() const {
  std::shared_lock<std::shared_mutex> state(state_mutex_);
  return ObjectId(next_id_);
}

void VoStore::setMapBounds(const Eigen::Vector3d& map_min, const Eigen::Vector3d& map_max) {
  VoStoreConfig check = config_;
  check.map_min = map_min;
  check.map_max = map_max;
  check.validate();
  std::lock_guard<std::mutex> write(write_mutex_);
  std::unique_lock<std::shared_mutex> state(state_mutex_);
  map_min_ = map_min;
  map_max_ = map_max;
}

void checkVoSnapshot(const VoSnapshot& snapshot, const std::string& context) {
  std::unordered_map<ObjectId, bool> seen;
  for (const VoRecord& r : snapshot.objects) {
    const VirtualObject& vo = r.vo;
    const std::string what = context + ": object " + std::to_string(vo.id.value);
    if (!vo.id.valid()) throw Error(context + ": an object has the invalid id 0");
    if (!seen.emplace(vo.id, true).second) throw Error(what + " appears twice");
    if (!(vo.id < snapshot.next_id)) {
      throw Error(what + ": id not below the id counter " + std::to_string(snapshot.next_id.value));
    }
    if (vo.kind != VoKind::kLine && vo.kind != VoKind::kAnchor)
      throw Error(what + ": unknown kind");
    if (!finiteVector(vo.position) || !finiteVector(vo.start) || !finiteVector(vo.end) ||
        !finiteVector(vo.normal) || !std::isfinite(vo.width)) {
      throw Error(what + ": a coordinate, the normal or the width is not finite");
    }
    if (vo.version < 1) throw Error(what + ": version 0");
    if (r.editor_since > vo.version) throw Error(what + ": editor_since is after its version");
  }
}

VoSnapshot VoStore::snapshot() const {
  std::shared_lock<std::shared_mutex> state(state_mutex_);
  VoSnapshot out;
  out.next_id = ObjectId(next_id_);
  out.objects.reserve(objects_.size());
  for (const auto& [id, e] : objects_) {
    out.objects.push_back(VoRecord{e.vo, e.keyframe, e.last_editor, e.editor_since});
  }
  std::sort(out.objects.begin(), out.objects.end(),
            [](const VoRecord& a, const VoRecord& b) { return a.vo.id < b.vo.id; });
  return out;
}

void VoStore::replaceAll(const VoSnapshot& snapshot) {
  checkVoSnapshot(snapshot, config_.database_path + ": replacing the VOs");
  std::unordered_map<ObjectId, Entry> objects;
  std::vector<const Entry*> rows;
  size_t live = 0;
  for (const VoRecord& r : snapshot.objects) {
    Entry e;
    e.vo = r.vo;
    e.keyframe = r.keyframe;
    e.last_editor = r.last_editor;
    e.editor_since = r.editor_since;
    if (!e.vo.deleted) {
      e.cells = attachmentCells(e.vo, config_.cell_size, config_.attach_margin);
      ++live;
    }
    objects.emplace(e.vo.id, std::move(e));
  }
  for (const VoRecord& r : snapshot.objects) rows.push_back(&objects.at(r.vo.id));
  std::lock_guard<std::mutex> write(write_mutex_);
  const uint32_t next_id = std::max(next_id_, snapshot.next_id.value);
  std::string error;
  if (!db_->replaceAll(rows, next_id, &error)) {
    throw Error(config_.database_path + ": replacing the VOs failed: " + error);
  }
  std::unique_lock<std::shared_mutex> state(state_mutex_);
  objects_ = std::move(objects);
  cell_index_.clear();
  keyframe_index_.clear();
  for (const auto& kv : objects_) {
    if (!kv.second.vo.deleted) attach(kv.second);
  }
  num_live_ = live;
  next_id_ = next_id;
}

size_t VoStore::moveKeyFrame(KeyFrameId from, KeyFrameId to) {
  if (!from.valid() || from == to) return 0;
  std::lock_guard<std::mutex> write(write_mutex_);
  std::vector<Entry> moved;
  {
    std::shared_lock<std::shared_mutex> state(state_mutex_);
    const auto it = keyframe_index_.find(from);
    if (it == keyframe_index_.end()) return 0;
    for (const ObjectId id : it->second) {
      moved.push_back(objects_.at(id));
      moved.back().keyframe = to;
    }
  }
  std::vector<const Entry*> rows;
  for (const Entry& e : moved) rows.push_back(&e);
  std::string error;
  if (!db_->writeAll(rows, &error)) {
    throw Error(config_.database_path + ": moving the objects of keyframe " +
                std::to_string(from.value) + " failed: " + error);
  }
  std::unique_lock<std::shared_mutex> state(state_mutex_);
  for (const Entry& e : moved) {
    Entry& stored = objects_.at(e.vo.id);
    detach(stored);
    stored.keyframe = to;
    attach(stored);
  }
  return moved.size();
}

void VoStore::backupTo(const std::string& path) const {
  std::lock_guard<std::mutex> write(write_mutex_);
  db_->backupTo(path);
}

}  // namespace ecar
