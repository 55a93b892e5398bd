// Renderer::castRay: the exact ray cast through the scene's spaces and solids,
// in double precision (the analytic reference that tests and tools check the
// rendered depth and labels against). Apart from renderer.cpp, whose pixel
// loop is built with -ffast-math.
#include "ecar_core/sim/renderer.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace ecar {

std::optional<SceneHit> Renderer::castRay(const Eigen::Vector3d& o,
                                          const Eigen::Vector3d& d) const {
  if (!o.allFinite() || !d.allFinite() || d.squaredNorm() == 0.0) return std::nullopt;
  // Walk out of the union of spaces: leave the farthest-reaching box that
  // contains the current point until the point is in no space.
  double t = 0.0;
  int box = -1, face = -1;
  for (size_t iter = 0; iter <= scene_.spaces.size(); ++iter) {
    const Eigen::Vector3d p = o + (t + 1e-9 * (1.0 + t)) * d;
    double best = -1.0;
    int best_box = -1, best_face = -1;
    for (size_t b = 0; b < scene_.spaces.size(); ++b) {
      const auto& B = scene_.spaces[b];
      if (!B.contains(p)) continue;
      double exit_t = std::numeric_limits<double>::infinity();
      int exit_face = -1;
      for (int a = 0; a < 3; ++a) {
        if (d[a] == 0.0) continue;
        const int side = d[a] > 0 ? 1 : 0;
        const double ta = ((side ? B.max[a] : B.min[a]) - o[a]) / d[a];
        if (ta < exit_t) {
          exit_t = ta;
          exit_face = a * 2 + side;
        }
      }
      if (exit_t > best) {
        best = exit_t;
        best_box = static_cast<int>(b);
        best_face = exit_face;
      }
    }
    if (best_box < 0) break;
    t = best;
    box = best_box;
    face = best_face;
  }
  if (box < 0) return std::nullopt;
  int surface = box * 6 + face;
  // Solids in front of the wall.
  const size_t solid_base = scene_.spaces.size() * 6;
  for (size_t b = 0; b < scene_.solids.size(); ++b) {
    const auto& B = scene_.solids[b];
    double t_near = -std::numeric_limits<double>::infinity();
    double t_far = std::numeric_limits<double>::infinity();
    int near_face = -1;
    bool miss = false;
    for (int a = 0; a < 3; ++a) {
      if (d[a] == 0.0) {
        if (o[a] <= B.min[a] || o[a] >= B.max[a]) miss = true;
        continue;
      }
      double t0 = (B.min[a] - o[a]) / d[a], t1 = (B.max[a] - o[a]) / d[a];
      int side = 0;
      if (t0 > t1) {
        std::swap(t0, t1);
        side = 1;
      }
      if (t0 > t_near) {
        t_near = t0;
        near_face = a * 2 + side;
      }
      t_far = std::min(t_far, t1);
    }
    if (!miss && t_near <= t_far && t_near > 0.0 && t_near < t) {
      t = t_near;
      surface = static_cast<int>(solid_base + b * 6) + near_face;
    }
  }
  SceneHit hit;
  hit.t = t;
  hit.surface = surface;
  hit.label = surfaces_[surface].label;
  hit.p_w = o + t * d;
  return hit;
}

}  // namespace ecar
