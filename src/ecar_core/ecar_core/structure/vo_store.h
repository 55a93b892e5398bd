// The server's store of virtual objects (VOs): registration, manipulation and
// deletion with versions and their rules (checks, conflicts), attachment to a
// keyframe (the baseline; grid-cell attachment is the grid connection's,
// grid_map.h), and persistence in SQLite (vo_database.h). No ROS: ecar_server
// converts ecar_msgs/Interaction into these calls and VoOutcome into
// InteractionResult.
//
//   VoStoreConfig config;
//   config.database_path = "/var/lib/ecar/vo.sqlite";
//   VoStore store(config);                        // opens (or creates) and loads the database
//   VoOutcome r = store.registerObject(vo, nearest_keyframe);
//   VoOutcome m = store.manipulate(r.id, r.version, moved, "device_1");
//   std::vector<VirtualObject> vos = store.objects(grid.objectsInCells(visible_cells));
//
// Durability: every accepted change is committed to the database (one
// transaction, WAL journal) before its outcome is returned, so a change that
// was acknowledged survives a kill -9 of the server. A change that cannot be
// written is rejected and the store is left as it was.
//
// Thread-safety: every public method is thread-safe. Changes are serialised
// by one writer mutex (held across the SQLite commit); the in-memory objects
// and indices are guarded by a reader-writer lock that writers take only for
// the short in-memory update after the commit, so readers (objects,
// objectsOfKeyFrames, get, forEachLive) never wait for a disk write.
#pragma once

#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <shared_mutex>
#include <string>
#include <unordered_map>
#include <vector>

#include <Eigen/Core>

#include "ecar_core/common/geometry.h"
#include "ecar_core/common/types.h"
#include "ecar_core/structure/virtual_object.h"

namespace ecar {

class VoDatabase;

/// Checks a snapshot before it replaces a store's contents: ids valid, unique
/// and below next_id; versions >= 1; editor_since <= version; coordinates,
/// normal and width finite; kind known. Throws ecar::Error naming the object
/// and the field (`context` prefixes the text).
void checkVoSnapshot(const VoSnapshot& snapshot, const std::string& context);

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
  /// `editor`) and the policy lets `editor` change it (an empty editor is the
  /// server itself). Version + 1; the object is re-attached to the cells it
  /// moved to; its keyframe stays.
  VoOutcome manipulate(ObjectId id, uint32_t base_version, const VirtualObject& new_state,
                       const std::string& editor = std::string());

  /// Deletes object `id`: it becomes a tombstone at version + 1 and is detached
  /// from its cells and keyframe. `base_version` is checked as in manipulate()
  /// (0, an unconditional delete, is refused). With max_tombstones exceeded
  /// the oldest tombstones are removed.
  VoOutcome remove(ObjectId id, uint32_t base_version, const std::string& editor);

  /// Removes the tombstones deleted at least tombstone_retention s before
  /// `now` (ecar::steadySeconds(), common/timing.h) from memory and the
  /// database; returns how many. (A failed database write keeps them for the
  /// next call.)
  size_t compactTombstones(double now);
  size_t numTombstones() const;  ///< tombstones held

  /// Live objects attached to any of `keyframes` (keyframe attachment), each once, by id.
  std::vector<VirtualObject> objectsOfKeyFrames(const std::vector<KeyFrameId>& keyframes) const;
  /// Latest state of `id` (a tombstone included); nullopt when unknown.
  std::optional<VirtualObject> get(ObjectId id) const;
  /// Latest states of the known ones of `ids` (tombstones included), by id: what
  /// a device holding them must be sent when they change or are deleted.
  std::vector<VirtualObject> objects(const std::vector<ObjectId>& ids) const;
  /// Every stored object (tombstones included), by id.
  std::vector<VirtualObject> allObjects() const;
  /// Calls `visit` with every live object, by increasing id, under the
  /// store's read lock (no copies; `visit` must not call the store).
  void forEachLive(const std::function<void(const VirtualObject&)>& visit) const;
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

  /// Moves live objects with the map around them (a loop closure or a merge
  /// moved keyframes and points): `correction` gives an object's similarity,
  /// or nullopt to leave it. Each moved object becomes version + 1 (edited by
  /// `editor`, so every device holding it is sent the new position); all rows
  /// are written in one database transaction before memory changes. Throws
  /// ecar::Error naming the database when the write fails (nothing changes
  /// then). `into` valid: the moved objects now belong to that map (a merge).
  /// Returns the ids moved.
  std::vector<ObjectId> transformObjects(
      const std::function<std::optional<Sim3>(const VirtualObject&)>& correction,
      const std::string& editor, MapId into = MapId());

  /// Replaces the map bounds (e.g. by the map's extent plus a margin) for the
  /// checks of later changes. Throws ecar::Error when min > max or not finite.
  void setMapBounds(const Eigen::Vector3d& map_min, const Eigen::Vector3d& map_max);

  /// Every object with its attachment and editor, and the id counter, taken
  /// under one lock (a consistent copy).
  VoSnapshot snapshot() const;
  /// Replaces every object by the snapshot's (a loaded map): checks it
  /// (checkVoSnapshot and the limits a registration checks: outer map bounds,
  /// line length, width, owner, max_objects), rewrites the database in one transaction (all rows
  /// and the id counter) and only then swaps the objects in memory, so a failure (throws
  /// ecar::Error naming the database and the problem) leaves both the database and the store as
  /// they were, and a kill -9 right after the call keeps the loaded objects. Cells are recomputed
  /// from the geometry. Ids are never reused: the id counter becomes the larger of the snapshot's
  /// and the store's.
  void replaceAll(const VoSnapshot& snapshot);
  /// What mergeNewer did.
  struct MergeCounts {
    size_t from_snapshot = 0;  ///< objects taken from the snapshot (newer there, or only there)
    size_t kept = 0;           ///< objects kept as the store has them (newer or as new here)
  };
  /// Merges a snapshot of this store's own past (the autosave a crashed server
  /// resumes from) into it: per object the higher version wins, the store's
  /// on a tie; objects only in the store are kept, objects only in the
  /// snapshot added; the id counter is the larger. Unlike replaceAll, nothing
  /// the database holds is lost: every change acknowledged after the snapshot
  /// was taken stays. Same checks and order as replaceAll (only the rows taken
  /// from the snapshot are written, in one transaction; none when the
  /// database is newer throughout, so a full disk does not stop a resume).
  MergeCounts mergeNewer(const VoSnapshot& snapshot);

  /// Writes a consistent copy of the database to `path` (SQLite online
  /// backup), e.g. to save a session. Throws ecar::Error when it fails.
  void backupTo(const std::string& path) const;

  const VoStoreConfig& config() const { return config_; }
  VoAttachMode attachMode() const { return config_.attach_mode; }

 private:
  /// Checks a requested state and canonicalises it (LINE centre, ANCHOR end
  /// points, unit normal). Returns kNone or the rejection with `reason` set.
  VoReject check(VirtualObject* vo, std::string* reason) const;
  /// The checks of a change to an existing object (known, live, the policy for
  /// `editor`, a base version that is not 0 and is current). `entry`
  /// receives the object when it is known.
  VoReject checkExisting(ObjectId id, uint32_t base_version, bool deleting,
                         const std::string& editor, std::string* reason,
                         const VoRecord** entry) const;
  /// Writes `entry` as the next version of `old` (edited by `editor`) to the
  /// database, then in memory; a failed write changes nothing (kStorage).
  /// write_mutex_ held.
  VoOutcome commitVersion(VoRecord entry, const VoRecord& old, const std::string& editor);
  /// Throws ecar::Error (prefixed by `context`) when a snapshot's live objects
  /// break the limits a registration checks (outer map bounds, line length,
  /// width, owner, max_objects) or it holds implausibly many tombstones.
  void checkLimits(const VoSnapshot& snapshot, const std::string& context) const;
  /// Swaps `objects` in as the store's (attachments and tombstone times made
  /// anew); write_mutex_ held, the database already written.
  void install(std::map<ObjectId, VoRecord> objects, uint32_t next_id);
  /// compactTombstones with write_mutex_ held; `over_count`: also the oldest
  /// beyond max_tombstones.
  size_t compactLocked(double now, bool over_count);
  /// Puts `record` in the keyframe index / takes it out. state_mutex_ held exclusively.
  void attach(const VoRecord& record);
  void detach(const VoRecord& record);

  const VoStoreConfig config_;
  /// Serialises changes; held across the database write. Guards db_.
  mutable std::mutex write_mutex_;
  std::unique_ptr<VoDatabase> db_;
  /// Guards the members below: they are written only while holding both
  /// write_mutex_ and state_mutex_ (exclusively), so either lock suffices to
  /// read them (a writer reads them under write_mutex_ alone).
  mutable std::shared_mutex state_mutex_;
  uint32_t next_id_ = 1;
  std::map<ObjectId, VoRecord> objects_;  ///< by id: readers list them in order
  std::unordered_map<KeyFrameId, std::vector<ObjectId>> keyframe_index_;
  size_t num_live_ = 0;
  std::map<ObjectId, double> deleted_at_;  ///< tombstones: when deleted (steady s)
  Eigen::Vector3d map_min_, map_max_;
};

}  // namespace ecar
