#include "ecar_core/structure/vo_store.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <utility>

#include "ecar_core/common/error.h"
#include "ecar_core/common/timing.h"
#include "ecar_core/structure/vo_database.h"

namespace ecar {

namespace {

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

}  // namespace

// ---------------------------------------------------------------- store

VoStore::VoStore(const VoStoreConfig& config)
    : config_((config.validate(), config)), map_min_(config.map_min), map_max_(config.map_max) {
  db_ = std::make_unique<VoDatabase>(config_);
  uint32_t max_id = 0;
  const double now = steadySeconds();
  const uint32_t stored_next = db_->load([&](VoRecord entry) {
    max_id = std::max(max_id, entry.vo.id.value);
    if (!entry.vo.deleted) {
      attach(entry);
      ++num_live_;
    } else {
      deleted_at_[entry.vo.id] = now;  // when it was deleted is not stored: its retention restarts
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
    if (!v->allFinite()) {
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

VoReject VoStore::checkExisting(ObjectId id, uint32_t base_version, bool deleting,
                                const std::string& editor, std::string* reason,
                                const VoRecord** entry) const {
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
  const bool restricted = !editor.empty() && editor != config_.privileged_editor &&
                          editor != vo.owner &&
                          (config_.policy == VoPolicy::kOwnerOnly ||
                           (deleting && config_.policy == VoPolicy::kOwnerDelete));
  if (restricted) {
    *reason = std::string(deleting ? "deleting" : "changing") + " object " +
              std::to_string(id.value) + " is for its owner " + vo.owner + " only (vo.policy " +
              toString(config_.policy) + ")";
    return VoReject::kNotOwner;
  }
  if (base_version == 0) {
    *reason = std::string("a ") + (deleting ? "delete" : "change") +
              " must name the version it applies to (base_version 0; object " +
              std::to_string(id.value) + " is at version " + std::to_string(vo.version) + ")";
    return VoReject::kStaleVersion;
  }
  if (base_version == vo.version) return VoReject::kNone;
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

void VoStore::attach(const VoRecord& entry) {
  if (entry.keyframe.valid()) keyframe_index_[entry.keyframe].push_back(entry.vo.id);
}

void VoStore::detach(const VoRecord& entry) {
  auto drop = [&](auto& index, const auto& key) {
    const auto it = index.find(key);
    if (it == index.end()) return;
    auto& ids = it->second;
    ids.erase(std::remove(ids.begin(), ids.end(), entry.vo.id), ids.end());
    if (ids.empty()) index.erase(it);
  };
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
  VoRecord entry;
  entry.vo = request;
  std::string reason;
  VoReject code = check(&entry.vo, &reason);
  if (code != VoReject::kNone) return reject(code, reason, ObjectId(), 0);
  if (config_.attach_mode == VoAttachMode::kKeyFrame && !keyframe.valid()) {
    return reject(VoReject::kNoKeyFrame, "keyframe attachment needs the nearest keyframe",
                  ObjectId(), 0);
  }
  if (num_live_ >= config_.max_objects || next_id_ == std::numeric_limits<uint32_t>::max()) {
    return reject(VoReject::kFull,
                  "the store is full (" + std::to_string(num_live_) +
                      " live objects, max_objects): delete some first",
                  ObjectId(), 0);
  }
  entry.vo.id = ObjectId(next_id_);
  entry.vo.version = 1;
  entry.vo.deleted = false;
  entry.keyframe = keyframe;
  entry.last_editor = entry.vo.owner;
  entry.editor_since = 0;
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
  const VoRecord* old = nullptr;
  VoReject code = checkExisting(id, base_version, /*deleting=*/false, editor, &reason, &old);
  const uint32_t current = old ? old->vo.version : 0;
  if (code != VoReject::kNone) return reject(code, reason, id, current);
  VoRecord entry = *old;
  entry.vo = new_state;
  code = check(&entry.vo, &reason);
  if (code != VoReject::kNone) return reject(code, reason, id, current);
  entry.vo.id = id;
  entry.vo.owner = old->vo.owner;
  entry.vo.map = old->vo.map;
  entry.vo.deleted = false;
  return commitVersion(std::move(entry), *old, editor);
}

VoOutcome VoStore::remove(ObjectId id, uint32_t base_version, const std::string& editor) {
  std::lock_guard<std::mutex> write(write_mutex_);
  std::string reason;
  const VoRecord* old = nullptr;
  const VoReject code = checkExisting(id, base_version, /*deleting=*/true, editor, &reason, &old);
  const uint32_t current = old ? old->vo.version : 0;
  if (code != VoReject::kNone) return reject(code, reason, id, current);
  VoRecord entry = *old;
  entry.vo.deleted = true;
  return commitVersion(std::move(entry), *old, editor);
}

VoOutcome VoStore::commitVersion(VoRecord entry, const VoRecord& old, const std::string& editor) {
  const ObjectId id = old.vo.id;
  const uint32_t current = old.vo.version;
  const bool was_live = !old.vo.deleted;
  entry.vo.version = current + 1;
  if (editor.empty() || editor != old.last_editor) entry.editor_since = current;
  entry.last_editor = editor;
  std::string error;
  if (!db_->write(entry, std::nullopt, &error)) {
    return reject(VoReject::kStorage, "database write failed: " + error, id, current);
  }
  std::unique_lock<std::shared_mutex> state(state_mutex_);
  VoRecord& stored = objects_.at(id);
  detach(stored);
  stored = std::move(entry);
  if (!stored.vo.deleted) attach(stored);
  if (was_live && stored.vo.deleted) {
    --num_live_;
    deleted_at_[id] = steadySeconds();
  }
  state.unlock();
  if (deleted_at_.size() > config_.max_tombstones) compactLocked(steadySeconds(), true);
  return accept(id, current + 1);
}

size_t VoStore::compactTombstones(double now) {
  std::lock_guard<std::mutex> write(write_mutex_);
  return compactLocked(now, false);
}

size_t VoStore::compactLocked(double now, bool over_count) {
  // By deletion time: the retention's expired ones, then (over_count) the oldest beyond
  // max_tombstones.
  std::vector<std::pair<double, ObjectId>> by_age;
  by_age.reserve(deleted_at_.size());
  for (const auto& [id, at] : deleted_at_) by_age.emplace_back(at, id);
  std::sort(by_age.begin(), by_age.end());
  std::vector<ObjectId> ids;
  for (size_t i = 0; i < by_age.size(); ++i) {
    const bool expired = now - by_age[i].first >= config_.tombstone_retention;
    const bool excess = over_count && by_age.size() - i > config_.max_tombstones;
    if (!expired && !excess) break;
    ids.push_back(by_age[i].second);
  }
  if (ids.empty()) return 0;
  std::string error;
  if (!db_->eraseAll(ids, &error)) return 0;  // kept: tried again at the next compaction
  std::unique_lock<std::shared_mutex> state(state_mutex_);
  for (const ObjectId id : ids) {
    objects_.erase(id);
    deleted_at_.erase(id);
  }
  return ids.size();
}

size_t VoStore::numTombstones() const {
  std::shared_lock<std::shared_mutex> state(state_mutex_);
  return deleted_at_.size();
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
  return out;
}

void VoStore::forEachLive(const std::function<void(const VirtualObject&)>& visit) const {
  std::shared_lock<std::shared_mutex> state(state_mutex_);
  for (const auto& [id, entry] : objects_) {
    if (!entry.vo.deleted) visit(entry.vo);
  }
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
    if (!coordinatesFinite(vo)) {
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
    out.objects.push_back(e);
  }
  return out;
}

void VoStore::checkLimits(const VoSnapshot& snapshot, const std::string& context) const {
  // A well-formed but hostile file must not make the server walk billions of cells or hold
  // more than it would have accepted object by object.
  size_t live = 0, tombstones = 0;
  for (const VoRecord& r : snapshot.objects) {
    const VirtualObject& vo = r.vo;
    const std::string what = context + ": object " + std::to_string(vo.id.value);
    if (vo.deleted) {
      ++tombstones;
      continue;
    }
    ++live;
    for (const Eigen::Vector3d* p : {&vo.position, &vo.start, &vo.end}) {
      if ((p->array() < config_.map_min.array()).any() ||
          (p->array() > config_.map_max.array()).any()) {
        throw Error(what + ": a point lies outside the map bounds (vo.map_min, vo.map_max)");
      }
    }
    if (vo.kind == VoKind::kLine && (vo.end - vo.start).norm() > config_.max_line_length * 1.001) {
      throw Error(what + ": a line of " + std::to_string((vo.end - vo.start).norm()) +
                  " m, longer than max_line_length");
    }
    if (vo.width < 0.0f || vo.width > config_.max_width * 1.001) {
      throw Error(what + ": width " + std::to_string(vo.width) + " m outside [0, max_width]");
    }
    if (vo.owner.size() > config_.max_owner_length) throw Error(what + ": owner too long");
  }
  if (live > config_.max_objects) {
    throw Error(context + ": " + std::to_string(live) + " live objects, more than max_objects " +
                std::to_string(config_.max_objects));
  }
  if (tombstones > 10 * config_.max_tombstones + 100000) {
    throw Error(context + ": " + std::to_string(tombstones) + " tombstones (corrupted?)");
  }
}

void VoStore::replaceAll(const VoSnapshot& snapshot) {
  checkVoSnapshot(snapshot, config_.database_path + ": replacing the VOs");
  checkLimits(snapshot, config_.database_path + ": replacing the VOs");
  std::map<ObjectId, VoRecord> objects;
  std::vector<const VoRecord*> rows;
  for (const VoRecord& r : snapshot.objects) objects.emplace(r.vo.id, r);
  for (const VoRecord& r : snapshot.objects) rows.push_back(&objects.at(r.vo.id));
  std::lock_guard<std::mutex> write(write_mutex_);
  const uint32_t next_id = std::max(next_id_, snapshot.next_id.value);
  std::string error;
  if (!db_->replaceAll(rows, next_id, &error)) {
    throw Error(config_.database_path + ": replacing the VOs failed: " + error);
  }
  install(std::move(objects), next_id);
}

void VoStore::install(std::map<ObjectId, VoRecord> objects, uint32_t next_id) {
  std::unique_lock<std::shared_mutex> state(state_mutex_);
  objects_ = std::move(objects);
  keyframe_index_.clear();
  deleted_at_.clear();
  num_live_ = 0;
  const double now = steadySeconds();
  for (const auto& kv : objects_) {
    if (!kv.second.vo.deleted) {
      attach(kv.second);
      ++num_live_;
    } else {
      deleted_at_[kv.first] = now;
    }
  }
  next_id_ = next_id;
}

size_t VoStore::moveKeyFrame(KeyFrameId from, KeyFrameId to) {
  if (!from.valid() || from == to) return 0;
  std::lock_guard<std::mutex> write(write_mutex_);
  std::vector<VoRecord> moved;
  {
    std::shared_lock<std::shared_mutex> state(state_mutex_);
    const auto it = keyframe_index_.find(from);
    if (it == keyframe_index_.end()) return 0;
    for (const ObjectId id : it->second) {
      moved.push_back(objects_.at(id));
      moved.back().keyframe = to;
    }
  }
  std::vector<const VoRecord*> rows;
  for (const VoRecord& e : moved) rows.push_back(&e);
  std::string error;
  if (!db_->writeAll(rows, &error)) {
    throw Error(config_.database_path + ": moving the objects of keyframe " +
                std::to_string(from.value) + " failed: " + error);
  }
  std::unique_lock<std::shared_mutex> state(state_mutex_);
  for (const VoRecord& e : moved) {
    VoRecord& stored = objects_.at(e.vo.id);
    detach(stored);
    stored.keyframe = to;
    attach(stored);
  }
  return moved.size();
}

std::vector<ObjectId> VoStore::transformObjects(
    const std::function<std::optional<Sim3>(const VirtualObject&)>& correction,
    const std::string& editor, MapId into) {
  std::lock_guard<std::mutex> write(write_mutex_);
  std::vector<VoRecord> moved;
  {
    std::shared_lock<std::shared_mutex> state(state_mutex_);
    for (const auto& [id, record] : objects_) {
      if (record.vo.deleted) continue;
      const std::optional<Sim3> S = correction(record.vo);
      if (!S) continue;
      VoRecord next = record;
      VirtualObject& vo = next.vo;
      vo.position = *S * vo.position;
      vo.start = *S * vo.start;
      vo.end = *S * vo.end;
      vo.normal = (S->R * vo.normal).normalized();
      vo.version = record.vo.version + 1;
      if (into.valid()) vo.map = into;
      if (editor.empty() || editor != record.last_editor) next.editor_since = record.vo.version;
      next.last_editor = editor;
      if (!vo.position.allFinite() || !vo.start.allFinite() || !vo.end.allFinite()) continue;
      moved.push_back(std::move(next));
    }
  }
  std::vector<ObjectId> ids;
  if (moved.empty()) return ids;
  std::vector<const VoRecord*> rows;
  for (const VoRecord& e : moved) rows.push_back(&e);
  std::string error;
  if (!db_->writeAll(rows, &error)) {
    throw Error(config_.database_path + ": moving " + std::to_string(moved.size()) +
                " objects with the map failed: " + error);
  }
  std::unique_lock<std::shared_mutex> state(state_mutex_);
  for (VoRecord& e : moved) {
    VoRecord& stored = objects_.at(e.vo.id);
    detach(stored);
    ids.push_back(e.vo.id);
    stored = std::move(e);
    attach(stored);
  }
  return ids;
}

void VoStore::backupTo(const std::string& path) const {
  std::lock_guard<std::mutex> write(write_mutex_);
  db_->backupTo(path);
}

}  // namespace ecar
