// The server's store of virtual objects (VOs): registration, manipulation and
// deletion with versions, attachment to grid cells (or, the baseline, to a
// keyframe), and persistence in SQLite. No ROS: ecar_server converts
// ecar_msgs/Interaction into these calls and VoOutcome into InteractionResult.
//
//   VoStoreConfig config;
//   config.database_path = "/var/lib/ecar/vo.sqlite";
//   VoStore store(config);                        // opens (or creates) and loads the database
//   VoOutcome r = store.registerObject(vo, nearest_keyframe);
//   VoOutcome m = store.manipulate(r.id, r.version, moved, "device_1");
//   std::vector<VirtualObject> vos = store.objectsInCells(visible_cells);
//
// Durability: every accepted change is committed to the database (one
// transaction, WAL journal) before its outcome is returned, so a change that
// was acknowledged survives a kill -9 of the server. A change that cannot be
// written is rejected and the store is left as it was.
//
// Thread-safety: every public method is thread-safe. Changes are serialised
// by one writer mutex (held across the SQLite commit); the in-memory objects
// and indices are guarded by a reader-writer lock that writers take only for
// the short in-memory update after the commit, so readers (objectsInCells,
// objectsOfKeyFrames, get) never wait for a disk write.
#pragma once

#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <shared_mutex>
#include <string>
#include <unordered_map>
#include <vector>

#include <Eigen/Core>

#include "ecar_core/types.h"

struct sqlite3;

namespace ecar {

/// Values of VirtualObject::kind (the numbers of ecar_msgs/VirtualObject).
enum class VoKind : uint8_t { kLine = 0, kAnchor = 1 };

/// A virtual object, field for field ecar_msgs/VirtualObject.
struct VirtualObject {
  ObjectId id;  ///< assigned by the store; ignored in a registration request
  VoKind kind = VoKind::kLine;
  /// ANCHOR: the anchor point; LINE: the segment centre, which the store
  /// recomputes as (start + end) / 2. Map frame, m.
  Eigen::Vector3d position = Eigen::Vector3d::Zero();
  /// LINE: segment end points, map frame, m. ANCHOR: the store sets both to position.
  Eigen::Vector3d start = Eigen::Vector3d::Zero();
  Eigen::Vector3d end = Eigen::Vector3d::Zero();
  uint8_t r = 255, g = 255, b = 255;  ///< colour, 0-255
  float width = 0.01f;                ///< LINE width, m (ANCHOR: marker size, may be 0)
  /// Normal of the surface the object lies on, map frame; the store normalises it.
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();
  PlaneId plane;         ///< the plane the object lies on; 0 = none
  std::string owner;     ///< device that registered it ("rviz" from rviz); kept on manipulation
  uint32_t version = 0;  ///< 1 at registration, +1 on every accepted change
  bool deleted = false;  ///< a tombstone: the object was deleted
};

/// How VOs reach devices.
enum class VoAttachMode {
  kGrid = 0,      ///< through the grid cells their geometry lies in (eCAR)
  kKeyFrame = 1,  ///< through the keyframe nearest at registration (the baseline)
};

/// "grid" or "keyframe".
const char* toString(VoAttachMode mode);
/// Parses "grid" / "keyframe"; throws ecar::Error naming the value otherwise.
VoAttachMode parseVoAttachMode(const std::string& text);

struct VoStoreConfig {
  /// SQLite database file, created when missing (":memory:" = not persistent, for tests).
  std::string database_path = "ecar_vo.sqlite";
  /// "normal" (default): in WAL mode each commit writes the change to the WAL
  /// file (into the OS) before it returns, so an acknowledged change survives a
  /// kill -9 or crash of the server; only an OS crash or power cut can lose the
  /// last changes (the database stays consistent). "full" adds an fsync of the
  /// WAL per commit, surviving a power cut too, but costs a disk flush per
  /// change (about 4 ms here against 0.15 ms): the writer lock is held across
  /// it, so all devices together could make only a few hundred changes a
  /// second, while a drag sends one per frame per device.
  std::string synchronous = "normal";
  double cell_size = 0.1;  ///< grid cell edge, m (as the grid connection's)
  /// A VO is attached to every cell within this distance of its geometry (per
  /// axis), m: a stroke painted on the floor at z = 0 lies on the boundary of
  /// two cell layers, and the grid's ray hits on the same floor fall on either.
  double attach_margin = 0.02;
  VoAttachMode attach_mode = VoAttachMode::kGrid;
  /// Map bounds, map frame, m: a VO with a point outside is rejected ("out of the map").
  Eigen::Vector3d map_min = Eigen::Vector3d::Constant(-1000.0);
  Eigen::Vector3d map_max = Eigen::Vector3d::Constant(1000.0);
  double min_line_length = 0.001;  ///< m; shorter LINEs are rejected
  double max_line_length = 5.0;    ///< m; longer LINEs are rejected
  double max_width = 0.5;          ///< m; LINE width in (0, max_width], ANCHOR in [0, max_width]
  size_t max_owner_length = 64;    ///< characters of VirtualObject::owner
  /// Objects stored (live and deleted) at most; a registration beyond is rejected.
  size_t max_objects = 100000;
  /// While one editor keeps changing an object (a drag sends a MANIPULATE per
  /// frame before the previous one is acknowledged), accept its base_version
  /// when every change since that version was its own. Otherwise a stale
  /// base_version is always a conflict.
  bool accept_own_stale = true;
  /// Largest database file, MB (SQLite max_page_count); 0 = unlimited. Writes
  /// beyond it fail and the change is rejected.
  double max_database_mb = 0.0;

  /// Throws ecar::Error naming the first invalid key (e.g. "cell_size").
  void validate() const;
};

/// Why a change was rejected.
enum class VoReject {
  kNone = 0,      ///< accepted
  kNotFinite,     ///< NaN or inf in a coordinate, the normal or the width
  kUnknownId,     ///< no object has this id
  kDeleted,       ///< the object was deleted
  kStaleVersion,  ///< base_version is not the store's version (a conflict)
  kOutOfMap,      ///< a point lies outside the map bounds
  kBadGeometry,   ///< zero-length or oversized line, zero normal
  kBadAttribute,  ///< bad kind, width or owner
  kNoKeyFrame,    ///< keyframe mode: a registration without a keyframe
  kFull,          ///< max_objects reached
  kStorage,       ///< the database write failed
};

/// The answer to one change (ecar_msgs/InteractionResult).
struct VoOutcome {
  bool accepted = false;
  ObjectId id;           ///< the object concerned (the new id of an accepted registration)
  uint32_t version = 0;  ///< version after the change; when rejected, the store's (0 if none)
  VoReject code = VoReject::kNone;
  std::string reason;  ///< why it was rejected, naming the value; empty when accepted
};

/// Everything stored about one object (for saving and loading the map).
struct VoRecord {
  VirtualObject vo;           ///< latest state (a tombstone when vo.deleted)
  KeyFrameId keyframe;        ///< keyframe attachment (0 = none)
  std::string last_editor;    ///< who made the latest change
  uint32_t editor_since = 0;  ///< every change after this version was last_editor's
};

/// The whole store: every object (tombstones included) and the id counter.
struct VoSnapshot {
  std::vector<VoRecord> objects;  ///< by increasing id
  ObjectId next_id{1};            ///< the id the next registration gets
};

/// Checks a snapshot before it replaces a store's contents: ids valid, unique
/// and below next_id; versions >= 1; editor_since <= version; coordinates,
/// normal and width finite; kind known. Throws ecar::Error naming the object
/// and the field (`context` prefixes the text).
void checkVoSnapshot(const VoSnapshot& snapshot, const std::string& context);

/// The cells a VO is attached to in grid mode: every cell (floor(X / cell),
/// floor(Y / cell), floor(Z / cell)) its geometry crosses (an ANCHOR's point, a
/// LINE's segment by a 3D DDA), and every cell within `margin` (per axis) of
/// it. Sorted, without duplicates.
std::vector<CellKey> attachmentCells(const VirtualObject& vo, double cell_size, double margin);

class VoStore {
 public:
  /// Validates `config`, opens (or creates) config.database_path and loads
  /// every stored object at its latest version (tombstones included) and the
  /// id counter. Throws ecar::Error naming the file and the problem when the
  /// file is not an SQLite database, is another program's database, is
  /// malformed or is used by another process; such a file is not modified.
  explicit VoStore(const VoStoreConfig& config);
  ~VoStore();
  VoStore(const VoStore&) = delete;
  VoStore& operator=(const VoStore&) = delete;

  /// Registers a new object (its id, version and deleted fields are ignored):
  /// assigns the next id (never reused, also across restarts), version 1,
  /// attaches it to its cells and to `keyframe` (required in keyframe mode, the
  /// keyframe nearest the object; optional in grid mode) and stores it.
  VoOutcome registerObject(const VirtualObject& request, KeyFrameId keyframe = KeyFrameId());

  /// Replaces the state of object `id` by `new_state` (its id, owner, version
  /// and deleted fields are ignored) when `base_version` is the store's version
  /// (or, with accept_own_stale, an older one and every change since was by
  /// `editor`). Version + 1; the object is re-attached to the cells it moved to;
  /// its keyframe stays.
  VoOutcome manipulate(ObjectId id, uint32_t base_version, const VirtualObject& new_state,
                       const std::string& editor = std::string());

  /// Deletes object `id`: it becomes a tombstone at version + 1 and is detached
  /// from its cells and keyframe. `base_version` 0 = unconditional; otherwise
  /// checked as in manipulate().
  VoOutcome remove(ObjectId id, uint32_t base_version = 0,
                   const std::string& editor = std::string());

  /// Live objects attached to any of `cells` (grid attachment), each once, by id.
  std::vector<VirtualObject> objectsInCells(const std::vector<CellKey>& cells) const;
  /// Live objects attached to any of `keyframes` (keyframe attachment), each once, by id.
  std::vector<VirtualObject> objectsOfKeyFrames(const std::vector<KeyFrameId>& keyframes) const;
  /// Latest state of `id` (a tombstone included); nullopt when unknown.
  std::optional<VirtualObject> get(ObjectId id) const;
  /// Latest states of the known ones of `ids` (tombstones included), by id: what
  /// a device holding them must be sent when they change or are deleted.
  std::vector<VirtualObject> objects(const std::vector<ObjectId>& ids) const;
  /// Every stored object (tombstones included), by id.
  std::vector<VirtualObject> allObjects() const;
  /// The cells `id` is attached to (empty when unknown or deleted).
  std::vector<CellKey> cellsOf(ObjectId id) const;
  /// The keyframe `id` hangs on (0 when none).
  KeyFrameId keyFrameOf(ObjectId id) const;

  size_t numObjects() const;  ///< stored objects, tombstones included
  size_t numLive() const;     ///< objects not deleted
  ObjectId nextId() const;    ///< the id the next registration gets

  /// Re-hangs the objects attached to keyframe `from` (culled by the SLAM) on
  /// `to` (its heir; invalid: they hang on none and reach no device in keyframe
  /// mode). Not a change of the objects: versions stay. Written to the database
  /// before memory changes; throws ecar::Error naming the database when the
  /// write fails (nothing changes then). Returns how many moved.
  size_t moveKeyFrame(KeyFrameId from, KeyFrameId to);

  /// Replaces the map bounds (e.g. by the map's extent plus a margin) for the
  /// checks of later changes. Throws ecar::Error when min > max or not finite.
  void setMapBounds(const Eigen::Vector3d& map_min, const Eigen::Vector3d& map_max);

  /// Every object with its attachment and editor, and the id counter, taken
  /// under one lock (a consistent copy).
  VoSnapshot snapshot() const;
  /// Replaces every object by the snapshot's (a loaded map): checks it
  /// (checkVoSnapshot), rewrites the database in one transaction (all rows and
  /// the id counter) and only then swaps the objects in memory, so a failure
  /// (throws ecar::Error naming the database and the problem) leaves both the
  /// database and the store as they were, and a kill -9 right after the
  /// call keeps the loaded objects. Cells are recomputed from the geometry.
  /// Ids are never reused: the id counter becomes the larger of the
  /// snapshot's and the store's.
  void replaceAll(const VoSnapshot& snapshot);

  /// Writes a consistent copy of the database to `path` (SQLite online
  /// backup), e.g. to save a session. Throws ecar::Error when it fails.
  void backupTo(const std::string& path) const;

  const VoStoreConfig& config() const { return config_; }
  VoAttachMode attachMode() const { return config_.attach_mode; }

 private:
  struct Entry {
    VirtualObject vo;
    KeyFrameId keyframe;
    std::vector<CellKey> cells;
    std::string last_editor;    ///< who made the latest change
    uint32_t editor_since = 0;  ///< every change after this version was last_editor's
  };
  class Database;

  /// Checks a requested state and canonicalises it (LINE centre, ANCHOR end
  /// points, unit normal). Returns kNone or the rejection with `reason` set.
  VoReject check(VirtualObject* vo, std::string* reason) const;
  /// The checks of a change to an existing object (known, live, base version;
  /// base_version 0 passes when `unconditional_ok`). `entry` receives the
  /// object when it is known.
  VoReject checkExisting(ObjectId id, uint32_t base_version, bool unconditional_ok,
                         const std::string& editor, std::string* reason, const Entry** entry) const;
  /// Puts `entry` in the indices / takes it out. state_mutex_ held exclusively.
  void attach(const Entry& entry);
  void detach(const Entry& entry);

  const VoStoreConfig config_;
  /// Serialises changes; held across the database write. Guards db_.
  mutable std::mutex write_mutex_;
  std::unique_ptr<Database> db_;
  /// Guards the members below: they are written only while holding both
  /// write_mutex_ and state_mutex_ (exclusively), so either lock suffices to
  /// read them (a writer reads them under write_mutex_ alone).
  mutable std::shared_mutex state_mutex_;
  uint32_t next_id_ = 1;
  std::unordered_map<ObjectId, Entry> objects_;
  std::unordered_map<CellKey, std::vector<ObjectId>> cell_index_;
  std::unordered_map<KeyFrameId, std::vector<ObjectId>> keyframe_index_;
  size_t num_live_ = 0;
  Eigen::Vector3d map_min_, map_max_;
};

}  // namespace ecar
