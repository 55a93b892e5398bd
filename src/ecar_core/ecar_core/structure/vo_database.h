// The SQLite database of the VO store: schema checks, loading, one
// transaction per change (WAL journal), online backup. A file of another
// program or another schema is refused and never modified; while open, the
// file is locked exclusively (one server per database).
//
//   VoDatabase db(config);                         // opens or creates config.database_path
//   uint32_t next_id = db.load([](VoRecord r) { ... });
//   std::string error;
//   if (!db.write(record, next_id + 1, &error)) { /* rejected: nothing changed */ }
//
// Not thread-safe: VoStore calls it under its writer mutex.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "ecar_core/structure/virtual_object.h"

namespace ecar {

class VoDatabase {
 public:
  /// Opens (or creates) config.database_path with config.synchronous and
  /// config.max_database_mb. Throws ecar::Error naming the file and the
  /// problem (not SQLite, another program's tables, another schema version,
  /// malformed, locked by another process).
  explicit VoDatabase(const VoStoreConfig& config);
  ~VoDatabase();
  VoDatabase(const VoDatabase&) = delete;
  VoDatabase& operator=(const VoDatabase&) = delete;

  /// Calls `row` with every stored record, by id; returns the stored id
  /// counter. Throws ecar::Error naming the object and the column of a
  /// malformed row.
  uint32_t load(const std::function<void(VoRecord)>& row);
  /// Writes one record and, when given, the id counter, in one transaction.
  /// Returns false with `error` set when it fails (rolled back).
  bool write(const VoRecord& record, std::optional<uint32_t> next_id, std::string* error);
  /// Writes records and, when given, the id counter in one transaction; false
  /// with `error` set when it fails.
  bool writeAll(const std::vector<const VoRecord*>& records, std::string* error,
                std::optional<uint32_t> next_id = std::nullopt);
  /// Deletes the rows of `ids` (compacted tombstones) in one transaction;
  /// false with `error` set when it fails.
  bool eraseAll(const std::vector<ObjectId>& ids, std::string* error);
  /// Replaces every row and the id counter in one transaction; false with
  /// `error` set when it fails.
  bool replaceAll(const std::vector<const VoRecord*>& records, uint32_t next_id,
                  std::string* error);
  /// Copies the database to `path` (online backup). Throws ecar::Error.
  void backupTo(const std::string& path) const;

 private:
  class Connection;
  std::unique_ptr<Connection> connection_;
};

}  // namespace ecar
