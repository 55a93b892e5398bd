// The grid connection's links (the paper's grid of 0.1 m cells, grid_cells.h):
// which cells each keyframe saw from its pose, and which cells each live
// virtual object is attached to. Keyframe links are saved with the map (their
// cells depend on the planes at the time); object links are derived from the
// objects' geometry (attachObject) and rebuilt from it after a load.
//
//   GridMap grid;
//   grid.setKeyFrameCells(kf, caster.visibleCells(T_w_c, planes));  // per keyframe
//   grid.attachObject(vo, cell_size, margin);                        // per VO change
//   std::vector<CellKey> cells = grid.cellsOfObject(vo.id);
//
// Thread-safety: every public method is safe to call concurrently (one
// std::shared_mutex; readers take it shared and return copies).
#pragma once

#include <cstddef>
#include <shared_mutex>
#include <unordered_map>
#include <utility>
#include <vector>

#include "ecar_core/common/types.h"
#include "ecar_core/structure/virtual_object.h"

namespace ecar {

class GridMap {
 public:
  // ---- keyframe-cell links
  /// Replaces the keyframe's cells (duplicates removed).
  void setKeyFrameCells(KeyFrameId keyframe, std::vector<CellKey> cells);
  /// The keyframe's cells, sorted (empty when unknown).
  std::vector<CellKey> cellsOfKeyFrame(KeyFrameId keyframe) const;
  /// The keyframes linked to a cell, by increasing id.
  std::vector<KeyFrameId> keyframesOfCell(CellKey cell) const;
  /// Removes a keyframe and its links.
  void eraseKeyFrame(KeyFrameId keyframe);
  size_t numKeyFrames() const;
  /// True when the keyframe has links (it was linked and not erased).
  bool hasKeyFrame(KeyFrameId keyframe) const;
  /// Cells linked to at least one keyframe.
  size_t numCells() const;

  // ---- object-cell links
  /// Attaches a live object to its attachmentCells(vo, cell_size, margin)
  /// (replacing the cells it had); detaches a deleted one.
  void attachObject(const VirtualObject& vo, double cell_size, double margin);
  /// The object's cells, sorted (empty when unknown or deleted).
  std::vector<CellKey> cellsOfObject(ObjectId id) const;
  /// Objects attached to any of `cells`, each once, by increasing id.
  std::vector<ObjectId> objectsInCells(const std::vector<CellKey>& cells) const;
  /// Replaces every object link by those of `objects` (deleted ones left out).
  void attachObjects(const std::vector<VirtualObject>& objects, double cell_size, double margin);
  size_t numObjects() const;

  /// Every keyframe with its cells, by increasing keyframe id.
  std::vector<std::pair<KeyFrameId, std::vector<CellKey>>> save() const;
  /// Replaces the keyframe links. Throws ecar::Error on an invalid or repeated
  /// keyframe id (nothing changes then).
  void load(const std::vector<std::pair<KeyFrameId, std::vector<CellKey>>>& links);
  /// Removes every keyframe and object link.
  void clear();

 private:
  // Hold mutex_ exclusively.
  void unlinkLocked(KeyFrameId keyframe);
  void detachLocked(ObjectId id);
  void attachLocked(ObjectId id, std::vector<CellKey> cells);

  mutable std::shared_mutex mutex_;
  std::unordered_map<KeyFrameId, std::vector<CellKey>> keyframe_cells_;  // GUARDED_BY(mutex_)
  std::unordered_map<CellKey, std::vector<KeyFrameId>> cell_keyframes_;  // GUARDED_BY(mutex_)
  std::unordered_map<ObjectId, std::vector<CellKey>> object_cells_;      // GUARDED_BY(mutex_)
  std::unordered_map<CellKey, std::vector<ObjectId>> cell_objects_;      // GUARDED_BY(mutex_)
};

}  // namespace ecar
