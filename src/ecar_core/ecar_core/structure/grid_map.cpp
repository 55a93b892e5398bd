#include "ecar_core/structure/grid_map.h"

#include <algorithm>
#include <mutex>
#include <string>

#include "ecar_core/common/error.h"
#include "ecar_core/structure/grid_cells.h"

namespace ecar {

void GridMap::unlinkLocked(KeyFrameId keyframe) {
  const auto it = keyframe_cells_.find(keyframe);
  if (it == keyframe_cells_.end()) return;
  for (CellKey c : it->second) {
    const auto kfs = cell_keyframes_.find(c);
    if (kfs == cell_keyframes_.end()) continue;
    auto& list = kfs->second;
    list.erase(std::remove(list.begin(), list.end(), keyframe), list.end());
    if (list.empty()) cell_keyframes_.erase(kfs);
  }
  keyframe_cells_.erase(it);
}

void GridMap::setKeyFrameCells(KeyFrameId keyframe, std::vector<CellKey> cells) {
  std::sort(cells.begin(), cells.end());
  cells.erase(std::unique(cells.begin(), cells.end()), cells.end());
  std::unique_lock<std::shared_mutex> lock(mutex_);
  unlinkLocked(keyframe);
  for (CellKey c : cells) cell_keyframes_[c].push_back(keyframe);
  keyframe_cells_[keyframe] = std::move(cells);
}

std::vector<CellKey> GridMap::cellsOfKeyFrame(KeyFrameId keyframe) const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  const auto it = keyframe_cells_.find(keyframe);
  return it == keyframe_cells_.end() ? std::vector<CellKey>() : it->second;
}

std::vector<KeyFrameId> GridMap::keyframesOfCell(CellKey cell) const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  const auto it = cell_keyframes_.find(cell);
  if (it == cell_keyframes_.end()) return {};
  std::vector<KeyFrameId> out = it->second;
  std::sort(out.begin(), out.end());
  return out;
}

void GridMap::eraseKeyFrame(KeyFrameId keyframe) {
  std::unique_lock<std::shared_mutex> lock(mutex_);
  unlinkLocked(keyframe);
}

bool GridMap::hasKeyFrame(KeyFrameId keyframe) const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  return keyframe_cells_.count(keyframe) > 0;
}

size_t GridMap::numKeyFrames() const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  return keyframe_cells_.size();
}

size_t GridMap::numCells() const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  return cell_keyframes_.size();
}

std::vector<std::pair<KeyFrameId, std::vector<CellKey>>> GridMap::save() const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  std::vector<std::pair<KeyFrameId, std::vector<CellKey>>> out(keyframe_cells_.begin(),
                                                               keyframe_cells_.end());
  std::sort(out.begin(), out.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
  return out;
}

void GridMap::load(const std::vector<std::pair<KeyFrameId, std::vector<CellKey>>>& links) {
  std::unordered_map<KeyFrameId, std::vector<CellKey>> kc;
  std::unordered_map<CellKey, std::vector<KeyFrameId>> ck;
  for (const auto& [kf, cells] : links) {
    if (!kf.valid()) throw Error("grid: keyframe link with invalid keyframe id 0");
    if (kc.count(kf)) {
      throw Error("grid: keyframe " + std::to_string(kf.value) + " appears twice");
    }
    std::vector<CellKey> sorted = cells;
    std::sort(sorted.begin(), sorted.end());
    sorted.erase(std::unique(sorted.begin(), sorted.end()), sorted.end());
    for (CellKey c : sorted) ck[c].push_back(kf);
    kc.emplace(kf, std::move(sorted));
  }
  std::unique_lock<std::shared_mutex> lock(mutex_);
  keyframe_cells_ = std::move(kc);
  cell_keyframes_ = std::move(ck);
}

void GridMap::clear() {
  std::unique_lock<std::shared_mutex> lock(mutex_);
  keyframe_cells_.clear();
  cell_keyframes_.clear();
  object_cells_.clear();
  cell_objects_.clear();
}

void GridMap::detachLocked(ObjectId id) {
  const auto it = object_cells_.find(id);
  if (it == object_cells_.end()) return;
  for (CellKey c : it->second) {
    const auto objects = cell_objects_.find(c);
    if (objects == cell_objects_.end()) continue;
    auto& list = objects->second;
    list.erase(std::remove(list.begin(), list.end(), id), list.end());
    if (list.empty()) cell_objects_.erase(objects);
  }
  object_cells_.erase(it);
}

void GridMap::attachLocked(ObjectId id, std::vector<CellKey> cells) {
  detachLocked(id);
  for (CellKey c : cells) cell_objects_[c].push_back(id);
  object_cells_[id] = std::move(cells);
}

void GridMap::attachObject(const VirtualObject& vo, double cell_size, double margin) {
  std::vector<CellKey> cells;
  if (!vo.deleted) cells = attachmentCells(vo, cell_size, margin);
  std::unique_lock<std::shared_mutex> lock(mutex_);
  if (vo.deleted) {
    detachLocked(vo.id);
  } else {
    attachLocked(vo.id, std::move(cells));
  }
}

void GridMap::attachObjects(const std::vector<VirtualObject>& objects, double cell_size,
                            double margin) {
  std::vector<std::pair<ObjectId, std::vector<CellKey>>> links;
  for (const VirtualObject& vo : objects) {
    if (!vo.deleted) links.emplace_back(vo.id, attachmentCells(vo, cell_size, margin));
  }
  std::unique_lock<std::shared_mutex> lock(mutex_);
  object_cells_.clear();
  cell_objects_.clear();
  for (auto& [id, cells] : links) attachLocked(id, std::move(cells));
}

std::vector<CellKey> GridMap::cellsOfObject(ObjectId id) const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  const auto it = object_cells_.find(id);
  return it == object_cells_.end() ? std::vector<CellKey>() : it->second;
}

std::vector<ObjectId> GridMap::objectsInCells(const std::vector<CellKey>& cells) const {
  std::vector<ObjectId> ids;
  {
    std::shared_lock<std::shared_mutex> lock(mutex_);
    for (const CellKey& c : cells) {
      const auto it = cell_objects_.find(c);
      if (it != cell_objects_.end()) ids.insert(ids.end(), it->second.begin(), it->second.end());
    }
  }
  std::sort(ids.begin(), ids.end());
  ids.erase(std::unique(ids.begin(), ids.end()), ids.end());
  return ids;
}

size_t GridMap::numObjects() const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  return object_cells_.size();
}

}  // namespace ecar
