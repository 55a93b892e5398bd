#include "ecar_core/structure/grid_map.h"

#include <algorithm>
#include <mutex>
#include <string>

#include "ecar_core/common/error.h"

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
}

}  // namespace ecar
