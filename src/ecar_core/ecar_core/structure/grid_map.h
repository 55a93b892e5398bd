// Keyframe-cell links of the grid connection: which 0.1 m cells each
// keyframe saw (grid_cells.h), for the map file and the per-cell lookups.
#pragma once

#include <cstddef>
#include <shared_mutex>
#include <unordered_map>
#include <utility>
#include <vector>

#include "ecar_core/common/types.h"

namespace ecar {

/// Keyframe-cell links. Thread-safety: every public method is safe to call
/// concurrently (own std::shared_mutex; readers take it shared and return copies).
class GridMap {
 public:
  /// Replaces the keyframe's cells (duplicates removed).
  void setKeyFrameCells(KeyFrameId keyframe, std::vector<CellKey> cells);
  /// The keyframe's cells, sorted (empty when unknown).
  std::vector<CellKey> cellsOfKeyFrame(KeyFrameId keyframe) const;
  /// The keyframes linked to a cell, by increasing id.
  std::vector<KeyFrameId> keyframesOfCell(CellKey cell) const;
  /// Removes a keyframe and its links.
  void eraseKeyFrame(KeyFrameId keyframe);
  size_t numKeyFrames() const;
  /// Cells linked to at least one keyframe.
  size_t numCells() const;

  /// Every keyframe with its cells, by increasing keyframe id.
  std::vector<std::pair<KeyFrameId, std::vector<CellKey>>> save() const;
  /// Replaces the contents. Throws ecar::Error on an invalid or repeated keyframe id.
  void load(const std::vector<std::pair<KeyFrameId, std::vector<CellKey>>>& links);
  void clear();

 private:
  // Hold mutex_ exclusively.
  void unlinkLocked(KeyFrameId keyframe);

  mutable std::shared_mutex mutex_;
  std::unordered_map<KeyFrameId, std::vector<CellKey>> keyframe_cells_;  // GUARDED_BY(mutex_)
  std::unordered_map<CellKey, std::vector<KeyFrameId>> cell_keyframes_;  // GUARDED_BY(mutex_)
};

}  // namespace ecar
