// Small numeric helpers shared across ecar_core (angles, value checks, 2D geometry).
#pragma once

#include <cmath>

#include <Eigen/Core>

namespace ecar {

constexpr double kDegToRad = M_PI / 180.0;
constexpr double kRadToDeg = 180.0 / M_PI;

/// True for a finite x > 0 (a config value that must be positive).
inline bool finitePositive(double x) { return std::isfinite(x) && x > 0.0; }
/// True for a finite x >= 0.
inline bool finiteNonNegative(double x) { return std::isfinite(x) && x >= 0.0; }

/// z of the cross product (a - o) x (b - o): > 0 when o, a, b turn counter-clockwise.
inline double cross2(const Eigen::Vector2d& o, const Eigen::Vector2d& a, const Eigen::Vector2d& b) {
  return (a - o).x() * (b - o).y() - (a - o).y() * (b - o).x();
}

}  // namespace ecar
