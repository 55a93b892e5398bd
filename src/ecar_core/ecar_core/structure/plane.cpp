#include "ecar_core/structure/plane.h"

#include <algorithm>
#include <cmath>
#include <string>

#include <Eigen/Eigenvalues>

#include "ecar_core/common/error.h"
#include "ecar_core/common/math.h"

namespace ecar {
namespace {

/// Orthonormal in-plane axes (e1, e2) with e1 x e2 = n.
void planeBasis(const Eigen::Vector3d& n, Eigen::Vector3d* e1, Eigen::Vector3d* e2) {
  Eigen::Vector3d a = Eigen::Vector3d::UnitX();
  if (std::abs(n.y()) < std::abs(n.x()) && std::abs(n.y()) <= std::abs(n.z())) {
    a = Eigen::Vector3d::UnitY();
  } else if (std::abs(n.z()) < std::abs(n.x())) {
    a = Eigen::Vector3d::UnitZ();
  }
  *e1 = n.cross(a).normalized();
  *e2 = n.cross(*e1);
}

/// Andrew's monotone chain: counter-clockwise hull without collinear points.
std::vector<Eigen::Vector2d> hull2d(std::vector<Eigen::Vector2d> p) {
  std::sort(p.begin(), p.end(), [](const Eigen::Vector2d& a, const Eigen::Vector2d& b) {
    return a.x() != b.x() ? a.x() < b.x() : a.y() < b.y();
  });
  p.erase(std::unique(p.begin(), p.end()), p.end());
  if (p.size() < 3) return p;
  std::vector<Eigen::Vector2d> h(2 * p.size());
  size_t k = 0;
  for (size_t i = 0; i < p.size(); ++i) {
    while (k >= 2 && cross2(h[k - 2], h[k - 1], p[i]) <= 0.0) --k;
    h[k++] = p[i];
  }
  for (size_t i = p.size() - 1, lower = k + 1; i-- > 0;) {
    while (k >= lower && cross2(h[k - 2], h[k - 1], p[i]) <= 0.0) --k;
    h[k++] = p[i];
  }
  h.resize(k - 1);
  return h;
}

}  // namespace

PlaneFrame::PlaneFrame(const Eigen::Vector3d& n, double d) : origin(-d * n) {
  planeBasis(n, &e1, &e2);
}

const char* toString(PlaneLabel label) {
  switch (label) {
    case PlaneLabel::kFloor:
      return "floor";
    case PlaneLabel::kWall:
      return "wall";
    case PlaneLabel::kCeiling:
      return "ceiling";
    case PlaneLabel::kOther:
      return "other";
  }
  return "other";
}

Eigen::Vector3d upFromGravity(const SE3& T_w_c, const Eigen::Vector3d& f_c) {
  if (!f_c.allFinite() || f_c.norm() < 1e-6) {
    throw Error("gravity: specific force must be finite and non-zero");
  }
  return (T_w_c.linear() * f_c).normalized();
}

void PlaneConfig::validate() const {
  auto fail = [](const std::string& key, const std::string& why) {
    throw Error("planes." + key + ": " + why);
  };
  if (!finitePositive(distance_threshold)) fail("distance_threshold", "must be > 0 m");
  if (min_inliers < 3) fail("min_inliers", "must be >= 3");
  if (iterations < 1) fail("iterations", "must be >= 1");
  if (max_planes < 1) fail("max_planes", "must be >= 1");
  if (!finitePositive(cluster_cell)) fail("cluster_cell", "must be > 0 m");
  if (!finitePositive(min_separation)) fail("min_separation", "must be > 0 m");
  if (!(horizontal_tolerance_deg > 0.0 && horizontal_tolerance_deg < 45.0)) {
    fail("horizontal_tolerance_deg", "must be in (0, 45) degrees");
  }
  if (!(vertical_tolerance_deg > 0.0 && vertical_tolerance_deg < 45.0)) {
    fail("vertical_tolerance_deg", "must be in (0, 45) degrees");
  }
  if (!(merge_angle_deg > 0.0 && merge_angle_deg < 90.0)) {
    fail("merge_angle_deg", "must be in (0, 90) degrees");
  }
  if (!finitePositive(merge_distance)) fail("merge_distance", "must be > 0 m");
  if (!(std::isfinite(merge_gap) && merge_gap >= 0.0)) fail("merge_gap", "must be >= 0 m");
  if (!(std::isfinite(keep_factor) && keep_factor >= 1.0)) fail("keep_factor", "must be >= 1");
}

void fitPlane(const std::vector<Eigen::Vector3d>& points_w, Eigen::Vector3d* normal,
              double* offset) {
  if (points_w.size() < 3) throw Error("fitPlane: needs at least 3 points");
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const auto& p : points_w) mean += p;
  mean /= static_cast<double>(points_w.size());
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  for (const auto& p : points_w) cov.noalias() += (p - mean) * (p - mean).transpose();
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(cov);
  *normal = eig.eigenvectors().col(0).normalized();
  *offset = -normal->dot(mean);
}

std::vector<Eigen::Vector3d> planeHull(const std::vector<Eigen::Vector3d>& points_w,
                                       const Eigen::Vector3d& normal, double offset) {
  const PlaneFrame frame(normal, offset);
  std::vector<Eigen::Vector2d> q;
  q.reserve(points_w.size());
  for (const auto& p : points_w) q.push_back(frame.to2d(p));
  std::vector<Eigen::Vector3d> out;
  for (const auto& h : hull2d(std::move(q))) {
    out.push_back(frame.origin + h.x() * frame.e1 + h.y() * frame.e2);
  }
  return out;
}

PlaneLabel labelPlane(const Eigen::Vector3d& normal, double offset,
                      const Eigen::Vector3d& camera_center_w, const Eigen::Vector3d& up_w,
                      const PlaneConfig& config) {
  const double c = std::abs(normal.dot(up_w));
  if (c >= std::cos(config.horizontal_tolerance_deg * kDegToRad)) {
    // Height of the camera above the plane, along up.
    const double height = up_w.dot(camera_center_w + offset * normal);
    return height > 0.0 ? PlaneLabel::kFloor : PlaneLabel::kCeiling;
  }
  if (c <= std::sin(config.vertical_tolerance_deg * kDegToRad)) return PlaneLabel::kWall;
  return PlaneLabel::kOther;
}

}  // namespace ecar
