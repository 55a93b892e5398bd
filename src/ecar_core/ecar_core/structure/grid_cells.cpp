#include "ecar_core/structure/grid_cells.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>

namespace ecar {
namespace {

int32_t& axis(CellKey& c, int i) { return i == 0 ? c.x : i == 1 ? c.y : c.z; }

// Whether the segment a + t (b - a), t in [0, 1], meets the closed box [lo, hi].
bool segmentMeetsBox(const Eigen::Vector3d& a, const Eigen::Vector3d& b, const Eigen::Vector3d& lo,
                     const Eigen::Vector3d& hi) {
  const Eigen::Vector3d d = b - a;
  double t_min = 0.0, t_max = 1.0;
  for (int i = 0; i < 3; ++i) {
    if (d[i] == 0.0) {
      if (a[i] < lo[i] || a[i] > hi[i]) return false;
      continue;
    }
    double t1 = (lo[i] - a[i]) / d[i], t2 = (hi[i] - a[i]) / d[i];
    if (t1 > t2) std::swap(t1, t2);
    t_min = std::max(t_min, t1);
    t_max = std::min(t_max, t2);
    if (t_min > t_max) return false;
  }
  return true;
}

// The cells the segment a-b crosses, in order (3D DDA; a point when a == b).
// Each step moves one axis towards the end point's cell, so the walk ends
// there even when rounding disagrees with floor() at a boundary.
std::vector<CellKey> traverse(const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                              double cell_size) {
  CellKey c = cellOf(a, cell_size);
  const CellKey goal = cellOf(b, cell_size);
  const Eigen::Vector3d d = b - a;
  const double inf = std::numeric_limits<double>::infinity();
  int step[3];
  double t_next[3], t_delta[3];
  for (int i = 0; i < 3; ++i) {
    const double k = axis(c, i);
    if (d[i] > 0.0) {
      step[i] = 1;
      t_next[i] = ((k + 1.0) * cell_size - a[i]) / d[i];
      t_delta[i] = cell_size / d[i];
    } else if (d[i] < 0.0) {
      step[i] = -1;
      t_next[i] = (k * cell_size - a[i]) / d[i];
      t_delta[i] = -cell_size / d[i];
    } else {
      step[i] = 0;
      t_next[i] = inf;
      t_delta[i] = inf;
    }
  }
  CellKey g = goal;
  std::vector<CellKey> cells{c};
  while (c != goal) {
    int best = -1;
    for (int i = 0; i < 3; ++i) {
      if (axis(c, i) == axis(g, i) || step[i] == 0) continue;
      if (best < 0 || t_next[i] < t_next[best]) best = i;
    }
    if (best < 0) {
      // Rounding left an axis short with no direction to move in; end at the goal.
      cells.push_back(goal);
      break;
    }
    axis(c, best) += step[best];
    t_next[best] += t_delta[best];
    cells.push_back(c);
  }
  return cells;
}

}  // namespace

CellKey cellOf(const Eigen::Vector3d& p_w, double cell_size) {
  CellKey c;
  c.x = static_cast<int32_t>(std::floor(p_w.x() / cell_size));
  c.y = static_cast<int32_t>(std::floor(p_w.y() / cell_size));
  c.z = static_cast<int32_t>(std::floor(p_w.z() / cell_size));
  return c;
}

Eigen::Vector3d cellCenter(CellKey cell, double cell_size) {
  return (Eigen::Vector3d(cell.x, cell.y, cell.z) + Eigen::Vector3d::Constant(0.5)) * cell_size;
}

bool containsCell(const std::vector<CellKey>& sorted_cells, CellKey cell, int radius) {
  for (int dx = -radius; dx <= radius; ++dx) {
    for (int dy = -radius; dy <= radius; ++dy) {
      for (int dz = -radius; dz <= radius; ++dz) {
        if (std::binary_search(sorted_cells.begin(), sorted_cells.end(),
                               CellKey{cell.x + dx, cell.y + dy, cell.z + dz})) {
          return true;
        }
      }
    }
  }
  return false;
}

std::vector<CellKey> attachmentCells(const VirtualObject& vo, double cell_size, double margin) {
  const bool line = vo.kind == VoKind::kLine;
  const Eigen::Vector3d a = line ? vo.start : vo.position;
  const Eigen::Vector3d b = line ? vo.end : vo.position;
  std::vector<CellKey> cells = traverse(a, b, cell_size);
  if (margin > 0.0) {
    // A cell within `margin` of the segment is a neighbour of a crossed cell
    // (margin < cell): test the 26 neighbours of each, expanded by the margin.
    const size_t crossed = cells.size();
    for (size_t k = 0; k < crossed; ++k) {
      const CellKey c = cells[k];
      for (int dx = -1; dx <= 1; ++dx) {
        for (int dy = -1; dy <= 1; ++dy) {
          for (int dz = -1; dz <= 1; ++dz) {
            if (dx == 0 && dy == 0 && dz == 0) continue;
            const CellKey n{c.x + dx, c.y + dy, c.z + dz};
            const Eigen::Vector3d lo =
                Eigen::Vector3d(n.x, n.y, n.z) * cell_size - Eigen::Vector3d::Constant(margin);
            const Eigen::Vector3d hi = Eigen::Vector3d(n.x + 1, n.y + 1, n.z + 1) * cell_size +
                                       Eigen::Vector3d::Constant(margin);
            if (segmentMeetsBox(a, b, lo, hi)) cells.push_back(n);
          }
        }
      }
    }
  }
  std::sort(cells.begin(), cells.end());
  cells.erase(std::unique(cells.begin(), cells.end()), cells.end());
  return cells;
}

}  // namespace ecar
