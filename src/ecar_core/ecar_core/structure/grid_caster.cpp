#include "ecar_core/structure/grid_caster.h"

#include <algorithm>
#include <cmath>
#include <mutex>
#include <string>

#include "ecar_core/common/error.h"
#include "ecar_core/common/math.h"

namespace ecar {
namespace {

constexpr double kMinRayParameter = 1e-9;

}  // namespace

void GridConfig::validate() const {
  auto fail = [](const std::string& key, const std::string& why) {
    throw Error("grid." + key + ": " + why);
  };
  if (window < 1) fail("window", "must be >= 1 px");
  if (!finitePositive(max_distance)) fail("max_distance", "must be > 0 m");
  if (!finitePositive(cell_size)) fail("cell_size", "must be > 0 m");
  if (!(std::isfinite(boundary_margin) && boundary_margin >= 0.0)) {
    fail("boundary_margin", "must be >= 0 m");
  }
}

// ---------------------------------------------------------------- GridPlanes

GridPlanes::GridPlanes(const std::vector<Plane>& planes, double boundary_margin) {
  if (!(std::isfinite(boundary_margin) && boundary_margin >= 0.0)) {
    throw Error("grid.boundary_margin: must be >= 0 m");
  }
  for (const Plane& plane : planes) {
    const std::string what = "grid: plane " + std::to_string(plane.id.value);
    if (!plane.normal.allFinite() || std::abs(plane.normal.norm() - 1.0) > 1e-6 ||
        !std::isfinite(plane.offset)) {
      throw Error(what + " has a non-unit normal or a non-finite offset");
    }
    if (plane.boundary.size() < 3) continue;
    Prepared p;
    p.id = plane.id;
    p.n = plane.normal;
    p.d = plane.offset;
    const size_t nb = plane.boundary.size();
    for (size_t i = 0; i < nb; ++i) {
      const Eigen::Vector3d& a = plane.boundary[i];
      const Eigen::Vector3d& b = plane.boundary[(i + 1) % nb];
      if (!a.allFinite()) throw Error(what + " has a non-finite boundary vertex");
      // Counter-clockwise about n: (b - a) x n points out of the polygon.
      const Eigen::Vector3d m = (b - a).cross(p.n);
      const double len = m.norm();
      if (len < 1e-12) continue;
      Edge e;
      e.m = m / len;
      e.b = e.m.dot(a) + boundary_margin;
      p.edges.push_back(e);
    }
    if (p.edges.size() >= 3) planes_.push_back(std::move(p));
  }
}

std::optional<RayHit> GridPlanes::intersect(const Eigen::Vector3d& origin_w,
                                            const Eigen::Vector3d& dir_w,
                                            double max_distance) const {
  const double len = dir_w.norm();
  if (!(len > 0.0) || !origin_w.allFinite() || !dir_w.allFinite()) return std::nullopt;
  double best_s = max_distance / len;
  const Prepared* best = nullptr;
  for (const Prepared& p : planes_) {
    const double s = -(p.n.dot(origin_w) + p.d) / p.n.dot(dir_w);
    if (!(s > kMinRayParameter && s <= best_s)) continue;
    if (inside(p, origin_w + s * dir_w)) {
      best_s = s;
      best = &p;
    }
  }
  if (best == nullptr) return std::nullopt;
  RayHit hit;
  hit.plane = best->id;
  hit.p_w = origin_w + best_s * dir_w;
  hit.distance = best_s * len;
  return hit;
}

// ---------------------------------------------------------------- GridCaster

GridCaster::GridCaster(const GridConfig& config, const PinholeCamera& camera)
    : config_(config), camera_(camera) {
  config_.validate();
  const int off = (config_.window - 1) / 2;
  for (int v = off; v < camera_.height(); v += config_.window) {
    for (int u = off; u < camera_.width(); u += config_.window) {
      const Eigen::Vector2d uv(u, v);
      const Eigen::Vector3d r = camera_.unproject(uv);
      pixels_.push_back(uv);
      rays_c_.push_back(r);
      ray_norms_.push_back(r.norm());
    }
  }
}

template <typename Emit>
void GridCaster::cast(const SE3& T_w_c, const GridPlanes& planes, Emit&& emit) const {
  const Eigen::Matrix3d R = T_w_c.linear();
  const Eigen::Vector3d o = T_w_c.translation();
  const std::vector<GridPlanes::Prepared>& prepared = planes.planes_;
  const size_t np = prepared.size();
  thread_local std::vector<double> numerator;  // n.o + d per plane
  numerator.resize(np);
  for (size_t i = 0; i < np; ++i) numerator[i] = prepared[i].n.dot(o) + prepared[i].d;
  for (size_t k = 0; k < rays_c_.size(); ++k) {
    const Eigen::Vector3d dir = R * rays_c_[k];
    double best_s = config_.max_distance / ray_norms_[k];
    int best = -1;
    Eigen::Vector3d best_x;
    for (size_t i = 0; i < np; ++i) {
      const double s = -numerator[i] / prepared[i].n.dot(dir);
      if (!(s > kMinRayParameter && s <= best_s)) continue;
      const Eigen::Vector3d x = o + s * dir;
      if (GridPlanes::inside(prepared[i], x)) {
        best_s = s;
        best = static_cast<int>(i);
        best_x = x;
      }
    }
    if (best >= 0) emit(k, prepared[best].id, best_x, best_s * ray_norms_[k]);
  }
}

void GridCaster::visibleCells(const SE3& T_w_c, const GridPlanes& planes,
                              std::vector<CellKey>* cells) const {
  cells->clear();
  const double cell = config_.cell_size;
  cast(T_w_c, planes, [&](size_t, PlaneId, const Eigen::Vector3d& x, double) {
    const CellKey c = cellOf(x, cell);
    // Neighbouring samples mostly fall into the same cell: skip the repeats early.
    if (cells->empty() || cells->back() != c) cells->push_back(c);
  });
  std::sort(cells->begin(), cells->end());
  cells->erase(std::unique(cells->begin(), cells->end()), cells->end());
}

void GridCaster::castSamples(const SE3& T_w_c, const GridPlanes& planes,
                             std::vector<SampleHit>* hits) const {
  hits->clear();
  const double cell = config_.cell_size;
  cast(T_w_c, planes, [&](size_t k, PlaneId id, const Eigen::Vector3d& x, double distance) {
    SampleHit h;
    h.sample = static_cast<int>(k);
    h.plane = id;
    h.p_w = x;
    h.distance = distance;
    h.cell = cellOf(x, cell);
    hits->push_back(h);
  });
}

bool GridCaster::isVisible(const SE3& T_w_c, const GridPlanes& planes, const Eigen::Vector3d& p_w,
                           double tolerance) const {
  if (!p_w.allFinite()) return false;
  const Eigen::Vector3d p_c = T_w_c.inverse() * p_w;
  const auto uv = camera_.project(p_c);
  if (!uv || !camera_.inImage(*uv)) return false;
  const Eigen::Vector3d o = T_w_c.translation();
  const Eigen::Vector3d dir = p_w - o;  // s = 1 at p_w
  const double distance = dir.norm();
  if (distance > config_.max_distance) return false;
  const double s_max = 1.0 - tolerance / distance;
  for (const GridPlanes::Prepared& p : planes.planes_) {
    // The plane p_w lies on (seen at a grazing angle, a millimetre off it is
    // centimetres along the ray) cannot hide it.
    if (std::abs(p.n.dot(p_w) + p.d) <= tolerance) continue;
    const double s = -(p.n.dot(o) + p.d) / p.n.dot(dir);
    if (s > kMinRayParameter && s < s_max && GridPlanes::inside(p, o + s * dir)) return false;
  }
  return true;
}

}  // namespace ecar
