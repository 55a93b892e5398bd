// The grid of 0.1 m cells in the map frame (the paper's grid connection):
// the cell of a point, cells near a cell, and the cells a virtual object is
// attached to.
#pragma once

#include <vector>

#include <Eigen/Core>

#include "ecar_core/common/types.h"
#include "ecar_core/structure/virtual_object.h"

namespace ecar {

/// The cell of a map-frame point: (floor(X / cell), floor(Y / cell), floor(Z / cell)).
CellKey cellOf(const Eigen::Vector3d& p_w, double cell_size);
/// Centre of a cell, map frame, m.
Eigen::Vector3d cellCenter(CellKey cell, double cell_size);

/// True when `cell`, or a cell within `radius` cells of it in x, y and z, is in
/// `sorted_cells` (sorted, as visibleCells returns them). A plane lying along a
/// cell border (a floor at z = 0.1 k) puts its hits on either side of it, and a
/// re-estimated plane moves them by millimetres: the cell of a VO's position and
/// the cells of the rays that hit its plane can differ by one; radius 1 absorbs it.
bool containsCell(const std::vector<CellKey>& sorted_cells, CellKey cell, int radius = 0);

/// The cells a VO is attached to in grid mode: every cell (floor(X / cell),
/// floor(Y / cell), floor(Z / cell)) its geometry crosses (an ANCHOR's point, a
/// LINE's segment by a 3D DDA), and every cell within `margin` (per axis) of
/// it. Sorted, without duplicates.
std::vector<CellKey> attachmentCells(const VirtualObject& vo, double cell_size, double margin);

}  // namespace ecar
