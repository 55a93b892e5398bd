// Virtual objects (VOs) and what the server stores about them: the object as
// ecar_msgs/VirtualObject carries it, its stored record, the store's options,
// and the outcome of a change. Used by the VO store (vo_store.h), its SQLite
// database (vo_database.h), the map file (io/structure_codec.h) and devices
// (device/device_objects.h).
#pragma once

#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "ecar_core/common/types.h"

namespace ecar {

/// Values of VirtualObject::kind (the numbers of ecar_msgs/VirtualObject).
enum class VoKind : uint8_t { kLine = 0, kAnchor = 1 };

/// A virtual object, field for field ecar_msgs/VirtualObject.
struct VirtualObject {
  ObjectId id;  ///< assigned by the store; ignored in a registration request
  /// The atlas map whose coordinates position, start and end are in (0 where
  /// there is one map). A merge moves the object into the merged map.
  MapId map;
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

/// True when the object's position, start, end, normal and width are all finite.
inline bool coordinatesFinite(const VirtualObject& vo) {
  return vo.position.allFinite() && vo.start.allFinite() && vo.end.allFinite() &&
         vo.normal.allFinite() && std::isfinite(vo.width);
}

/// How VOs reach devices.
enum class VoAttachMode {
  kGrid = 0,      ///< through the grid cells their geometry lies in (eCAR)
  kKeyFrame = 1,  ///< through the keyframe nearest at registration (the baseline)
};

/// "grid" or "keyframe".
const char* toString(VoAttachMode mode);
/// Parses "grid" / "keyframe"; throws ecar::Error naming the value otherwise.
VoAttachMode parseVoAttachMode(const std::string& text);

/// Who may change whose objects (the server's vo.policy). Everyone may
/// register; VoStoreConfig::privileged_editor and the server itself (an empty
/// editor: map corrections) are never restricted.
enum class VoPolicy {
  kOpen = 0,         ///< anyone manipulates and deletes anything
  kOwnerDelete = 1,  ///< anyone manipulates; only the owner deletes (default)
  kOwnerOnly = 2,    ///< only the owner manipulates or deletes
};

/// "open", "owner_delete" or "owner_only".
const char* toString(VoPolicy policy);
/// Parses those names; throws ecar::Error naming the value otherwise.
VoPolicy parseVoPolicy(const std::string& text);

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
  /// Live objects at most; a registration beyond is rejected (kFull) until
  /// some are deleted. Tombstones do not count (see max_tombstones).
  size_t max_objects = 100000;
  VoPolicy policy = VoPolicy::kOwnerDelete;
  /// The operator's user, exempt from the policy ("" = none).
  std::string privileged_editor = "rviz";
  /// s: a tombstone is kept at least this long, so that devices holding the
  /// object are told (and after that they are told by the graphs' composer,
  /// which sends a tombstone for a held object the store no longer knows);
  /// compactTombstones() removes older ones.
  double tombstone_retention = 3600.0;
  /// Tombstones kept at most; beyond, the oldest are removed at once.
  size_t max_tombstones = 10000;
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
  kStaleMap,      ///< made in a map that merged into another since (other coordinates)
  kNotOwner,      ///< the policy reserves this change to the object's owner
  kRateLimited,   ///< the device sent more interactions than its rate allows
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

/// Values of VoRequest::type (the numbers of ecar_msgs/Interaction).
enum class VoRequestType : uint8_t { kRegister = 0, kManipulate = 1, kDelete = 2 };

/// One interaction, as a device sends it and the server applies it to its VO
/// store (ecar_msgs/Interaction without the header).
struct VoRequest {
  std::string device;  ///< who asks (a device name, or "rviz")
  uint32_t request_id = 0;
  VoRequestType type = VoRequestType::kRegister;
  ObjectId object_id;         ///< MANIPULATE / DELETE target
  VirtualObject object;       ///< desired state (map frame); unused for DELETE
  uint32_t base_version = 0;  ///< version the device holds; 0 for REGISTER
};

/// The server's answer to one VoRequest (ecar_msgs/InteractionResult without the header).
struct VoResult {
  std::string device;  ///< the request's
  uint32_t request_id = 0;
  bool accepted = false;
  ObjectId object_id;    ///< the object concerned (the new id of an accepted registration)
  uint32_t version = 0;  ///< version after the change; when rejected, the store's (0 if none)
  std::string reason;    ///< why it was rejected; empty when accepted
};

/// The answer to `request` with the store's `outcome`.
inline VoResult resultOf(const VoRequest& request, const VoOutcome& outcome) {
  VoResult r;
  r.device = request.device;
  r.request_id = request.request_id;
  r.accepted = outcome.accepted;
  r.object_id = outcome.id;
  r.version = outcome.version;
  r.reason = outcome.reason;
  return r;
}

}  // namespace ecar
