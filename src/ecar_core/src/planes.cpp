#include "ecar_core/planes.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <mutex>
#include <random>
#include <string>

#include <Eigen/Eigenvalues>

#include "ecar_core/error.h"

namespace ecar {
namespace {

constexpr double kDegToRad = M_PI / 180.0;

bool finitePositive(double x) { return std::isfinite(x) && x > 0.0; }

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

double cross2(const Eigen::Vector2d& o, const Eigen::Vector2d& a, const Eigen::Vector2d& b) {
  return (a - o).x() * (b - o).y() - (a - o).y() * (b - o).x();
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

struct PlaneFrame {
  Eigen::Vector3d origin, e1, e2;
  explicit PlaneFrame(const Eigen::Vector3d& n, double d) : origin(-d * n) {
    planeBasis(n, &e1, &e2);
  }
  Eigen::Vector2d to2d(const Eigen::Vector3d& p) const {
    return Eigen::Vector2d(e1.dot(p - origin), e2.dot(p - origin));
  }
};

bool insideConvex(const std::vector<Eigen::Vector2d>& poly, const Eigen::Vector2d& p) {
  if (poly.size() < 3) return false;
  for (size_t i = 0; i < poly.size(); ++i) {
    if (cross2(poly[i], poly[(i + 1) % poly.size()], p) < -1e-12) return false;
  }
  return true;
}

double pointSegment(const Eigen::Vector2d& p, const Eigen::Vector2d& a, const Eigen::Vector2d& b) {
  const Eigen::Vector2d ab = b - a;
  const double len2 = ab.squaredNorm();
  const double t = len2 > 0.0 ? std::clamp((p - a).dot(ab) / len2, 0.0, 1.0) : 0.0;
  return (a + t * ab - p).norm();
}

bool segmentsCross(const Eigen::Vector2d& a, const Eigen::Vector2d& b, const Eigen::Vector2d& c,
                   const Eigen::Vector2d& d) {
  const double d1 = cross2(a, b, c), d2 = cross2(a, b, d);
  const double d3 = cross2(c, d, a), d4 = cross2(c, d, b);
  return ((d1 > 0) != (d2 > 0)) && ((d3 > 0) != (d4 > 0));
}

/// Distance between two convex polygons (0 when they overlap); a polygon of one
/// or two points counts as a point or a segment.
double polygonGap(const std::vector<Eigen::Vector2d>& a, const std::vector<Eigen::Vector2d>& b) {
  if (a.empty() || b.empty()) return std::numeric_limits<double>::infinity();
  for (const auto& p : a) {
    if (insideConvex(b, p)) return 0.0;
  }
  for (const auto& p : b) {
    if (insideConvex(a, p)) return 0.0;
  }
  double best = std::numeric_limits<double>::infinity();
  for (size_t i = 0; i < a.size(); ++i) {
    const auto& a0 = a[i];
    const auto& a1 = a[(i + 1) % a.size()];
    for (size_t j = 0; j < b.size(); ++j) {
      const auto& b0 = b[j];
      const auto& b1 = b[(j + 1) % b.size()];
      if (segmentsCross(a0, a1, b0, b1)) return 0.0;
      best = std::min({best, pointSegment(a0, b0, b1), pointSegment(a1, b0, b1),
                       pointSegment(b0, a0, a1), pointSegment(b1, a0, a1)});
    }
  }
  return best;
}

/// Indices (into `points`) of the largest 8-connected group of occupied cells.
std::vector<int> largestCluster(const std::vector<Eigen::Vector3d>& points,
                                const std::vector<int>& members, const PlaneFrame& frame,
                                double cell) {
  std::unordered_map<int64_t, std::vector<int>> cells;
  auto key = [](int64_t x, int64_t y) { return (x << 32) ^ (y & 0xFFFFFFFFll); };
  for (int i : members) {
    const Eigen::Vector2d q = frame.to2d(points[i]) / cell;
    cells[key(static_cast<int64_t>(std::floor(q.x())), static_cast<int64_t>(std::floor(q.y())))]
        .push_back(i);
  }
  std::unordered_map<int64_t, int> component;
  std::vector<int> best;
  for (const auto& [start, unused] : cells) {
    (void)unused;
    if (component.count(start)) continue;
    const int label = static_cast<int>(component.size());
    std::vector<int64_t> stack{start};
    component[start] = label;
    std::vector<int> found;
    while (!stack.empty()) {
      const int64_t k = stack.back();
      stack.pop_back();
      const auto& idx = cells.at(k);
      found.insert(found.end(), idx.begin(), idx.end());
      const int64_t x = k >> 32;
      const int64_t y = static_cast<int32_t>(k & 0xFFFFFFFFll);
      for (int dx = -1; dx <= 1; ++dx) {
        for (int dy = -1; dy <= 1; ++dy) {
          const int64_t nk = key(x + dx, y + dy);
          if (cells.count(nk) && !component.count(nk)) {
            component[nk] = label;
            stack.push_back(nk);
          }
        }
      }
    }
    if (found.size() > best.size() ||
        (found.size() == best.size() && *std::min_element(found.begin(), found.end()) <
                                            *std::min_element(best.begin(), best.end()))) {
      best = std::move(found);
    }
  }
  std::sort(best.begin(), best.end());
  return best;
}

double medianAbsDistance(const std::vector<Eigen::Vector3d>& points, const Eigen::Vector3d& n,
                         double d) {
  std::vector<double> dist(points.size());
  for (size_t i = 0; i < points.size(); ++i) dist[i] = std::abs(n.dot(points[i]) + d);
  if (dist.empty()) return std::numeric_limits<double>::infinity();
  auto mid = dist.begin() + static_cast<long>(dist.size() / 2);
  std::nth_element(dist.begin(), mid, dist.end());
  return *mid;
}

}  // namespace

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

// ---------------------------------------------------------------- segmenter

PlaneSegmenter::PlaneSegmenter(const PlaneConfig& config) : config_(config) { config_.validate(); }

std::vector<PlaneObservation> PlaneSegmenter::segment(const PlaneKeyFrameInput& input) const {
  if (!input.up_w.allFinite() || input.up_w.norm() < 1e-9) {
    throw Error("planes: up_w of keyframe " + std::to_string(input.keyframe.value) +
                " must be finite and non-zero");
  }
  if (!input.camera_center_w.allFinite()) {
    throw Error("planes: camera centre of keyframe " + std::to_string(input.keyframe.value) +
                " is not finite");
  }
  const Eigen::Vector3d up = input.up_w.normalized();
  const PlaneConfig& cfg = config_;
  std::vector<Eigen::Vector3d> pts;  // the finite input points
  std::vector<int> source;           // pts index -> input index
  for (size_t i = 0; i < input.points.size(); ++i) {
    if (!input.points[i].p_w.allFinite()) continue;
    pts.push_back(input.points[i].p_w);
    source.push_back(static_cast<int>(i));
  }
  std::vector<int> remaining(pts.size());
  for (size_t i = 0; i < pts.size(); ++i) remaining[i] = static_cast<int>(i);

  std::mt19937 rng(cfg.seed ^ (input.keyframe.value * 0x9E3779B9u));
  std::vector<PlaneObservation> out;
  const double thr = cfg.distance_threshold;
  auto inliersOf = [&](const Eigen::Vector3d& n, double d) {
    std::vector<int> in;
    for (int i : remaining) {
      if (std::abs(n.dot(pts[i]) + d) < thr) in.push_back(i);
    }
    return in;
  };

  for (int attempt = 0;
       attempt < 2 * cfg.max_planes && static_cast<int>(out.size()) < cfg.max_planes &&
       static_cast<int>(remaining.size()) >= cfg.min_inliers;
       ++attempt) {
    std::uniform_int_distribution<size_t> pick(0, remaining.size() - 1);
    int best_count = 0;
    Eigen::Vector3d best_n = Eigen::Vector3d::UnitZ();
    double best_d = 0.0;
    for (int it = 0; it < cfg.iterations; ++it) {
      const size_t a = pick(rng), b = pick(rng), c = pick(rng);
      if (a == b || b == c || a == c) continue;
      const Eigen::Vector3d& p0 = pts[remaining[a]];
      Eigen::Vector3d n = (pts[remaining[b]] - p0).cross(pts[remaining[c]] - p0);
      const double len = n.norm();
      if (len < 1e-9) continue;
      n /= len;
      const double d = -n.dot(p0);
      int count = 0;
      for (int i : remaining) count += std::abs(n.dot(pts[i]) + d) < thr;
      if (count > best_count) {
        best_count = count;
        best_n = n;
        best_d = d;
      }
    }
    if (best_count < cfg.min_inliers) break;

    // Least squares on the inliers, twice (the refined plane gathers its inliers again).
    std::vector<int> in = inliersOf(best_n, best_d);
    for (int round = 0; round < 2 && in.size() >= 3; ++round) {
      std::vector<Eigen::Vector3d> sel;
      for (int i : in) sel.push_back(pts[i]);
      fitPlane(sel, &best_n, &best_d);
      in = inliersOf(best_n, best_d);
    }
    const PlaneFrame frame(best_n, best_d);
    std::vector<int> kept = largestCluster(pts, in, frame, cfg.cluster_cell);
    const std::vector<int>& drop = static_cast<int>(kept.size()) >= cfg.min_inliers ? kept : in;
    std::vector<char> taken(pts.size(), 0);
    for (int i : drop) taken[i] = 1;
    remaining.erase(
        std::remove_if(remaining.begin(), remaining.end(), [&](int i) { return taken[i] != 0; }),
        remaining.end());
    if (static_cast<int>(kept.size()) < cfg.min_inliers) continue;

    PlaneObservation obs;
    std::vector<Eigen::Vector3d> sel;
    for (int i : kept) sel.push_back(pts[i]);
    fitPlane(sel, &obs.normal, &obs.offset);
    if (obs.normal.dot(input.camera_center_w) + obs.offset < 0.0) {
      obs.normal = -obs.normal;
      obs.offset = -obs.offset;
    }
    double sq = 0.0;
    for (const auto& p : sel) sq += std::pow(obs.normal.dot(p) + obs.offset, 2);
    obs.rms = std::sqrt(sq / static_cast<double>(sel.size()));
    for (int i : kept) obs.inliers.push_back(input.points[source[i]]);
    obs.boundary = planeHull(sel, obs.normal, obs.offset);
    obs.label = labelPlane(obs.normal, obs.offset, input.camera_center_w, up, cfg);
    out.push_back(std::move(obs));
  }
  return out;
}

// ---------------------------------------------------------------- plane map

PlaneMap::PlaneMap(const PlaneConfig& config) : config_(config) { config_.validate(); }

bool PlaneMap::matches(const Entry& entry, const std::vector<Eigen::Vector3d>& points_w,
                       const std::vector<Eigen::Vector3d>& hull, const Eigen::Vector3d& normal,
                       double* median_distance) const {
  const Plane& p = entry.plane;
  if (std::abs(normal.dot(p.normal)) < std::cos(config_.merge_angle_deg * kDegToRad)) return false;
  const double md = medianAbsDistance(points_w, p.normal, p.offset);
  if (md > config_.merge_distance) return false;
  const PlaneFrame frame(p.normal, p.offset);
  std::vector<Eigen::Vector2d> a, b;
  for (const auto& v : p.boundary) a.push_back(frame.to2d(v));
  for (const auto& v : hull) b.push_back(frame.to2d(v));
  if (polygonGap(a, b) > config_.merge_gap) return false;
  *median_distance = md;
  return true;
}

void PlaneMap::reestimate(Entry* entry, const Eigen::Vector3d& camera_center_w,
                          const Eigen::Vector3d& up_w) {
  Plane& plane = entry->plane;
  std::vector<Eigen::Vector3d> pts;
  auto fit = [&]() {
    pts.clear();
    for (const auto& kv : entry->points) pts.push_back(kv.second);
    if (pts.size() < 3) return;
    Eigen::Vector3d n;
    double d;
    fitPlane(pts, &n, &d);
    if (n.dot(plane.normal) < 0.0) {  // keep the side it was seen from
      n = -n;
      d = -d;
    }
    plane.normal = n;
    plane.offset = d;
  };
  const double keep = config_.keep_factor * config_.distance_threshold;
  auto dropFar = [&](double limit) {
    bool dropped = false;
    for (auto it = entry->points.begin(); it != entry->points.end();) {
      if (std::abs(plane.signedDistance(it->second)) > limit) {
        point_owner_.erase(it->first);
        it = entry->points.erase(it);
        dropped = true;
      } else {
        ++it;
      }
    }
    return dropped;
  };
  // Points far from the current estimate (moved by bundle adjustment) leave
  // before the fit, so that they cannot tilt it (leniently: points just merged
  // in may lie up to merge_distance off it); then strictly after it.
  dropFar(keep + config_.merge_distance);
  fit();
  if (dropFar(keep)) fit();
  plane.boundary = planeHull(pts, plane.normal, plane.offset);
  plane.label = labelPlane(plane.normal, plane.offset, camera_center_w, up_w, config_);
  plane.num_points = static_cast<uint32_t>(entry->points.size());
  ++plane.version;
}

void PlaneMap::absorb(Entry* into, Entry* from) {
  for (const auto& [pid, p_w] : from->points) {
    into->points[pid] = p_w;
    point_owner_[pid] = into->plane.id;
  }
  for (KeyFrameId kf : from->keyframes) {
    into->keyframes.insert(kf);
    auto& list = keyframe_planes_[kf];
    list.erase(std::remove(list.begin(), list.end(), from->plane.id), list.end());
    if (std::find(list.begin(), list.end(), into->plane.id) == list.end()) {
      list.push_back(into->plane.id);
    }
  }
}

PlaneMapUpdate PlaneMap::integrate(const PlaneKeyFrameInput& input,
                                   const std::vector<PlaneObservation>& observations) {
  if (!input.up_w.allFinite() || input.up_w.norm() < 1e-9 || !input.camera_center_w.allFinite()) {
    throw Error("planes: up_w and camera centre of keyframe " +
                std::to_string(input.keyframe.value) + " must be finite (up non-zero)");
  }
  const Eigen::Vector3d up = input.up_w.normalized();
  const Eigen::Vector3d& cam = input.camera_center_w;
  std::unique_lock<std::shared_mutex> lock(mutex_);
  PlaneMapUpdate update;

  for (const auto& p : input.points) {
    const auto owner = point_owner_.find(p.id);
    if (owner != point_owner_.end() && p.p_w.allFinite()) {
      planes_.at(owner->second).points[p.id] = p.p_w;
    }
  }

  std::vector<PlaneId> touched;
  for (const auto& obs : observations) {
    std::vector<Eigen::Vector3d> pts;
    for (const auto& p : obs.inliers) pts.push_back(p.p_w);
    PlaneId best;
    double best_distance = std::numeric_limits<double>::infinity();
    for (const auto& [id, entry] : planes_) {
      double md = 0.0;
      if (matches(entry, pts, obs.boundary, obs.normal, &md) &&
          (md < best_distance || (md == best_distance && id < best))) {
        best = id;
        best_distance = md;
      }
    }
    Entry fresh;
    Entry* target = nullptr;
    if (best.valid()) {
      target = &planes_.at(best);
    } else {
      fresh.plane.id = PlaneId(next_id_);
      fresh.plane.normal = obs.normal;
      fresh.plane.offset = obs.offset;
      target = &fresh;
    }
    for (const auto& p : obs.inliers) {
      const auto owner = point_owner_.find(p.id);
      if (owner == point_owner_.end() || owner->second == target->plane.id) {
        target->points[p.id] = p.p_w;
      }
    }
    if (!best.valid()) {
      if (static_cast<int>(fresh.points.size()) < config_.min_inliers) continue;
      ++next_id_;
      best = fresh.plane.id;
      target = &planes_.emplace(best, std::move(fresh)).first->second;
      update.created.push_back(best);
    }
    for (const auto& kv : target->points) point_owner_[kv.first] = best;
    target->keyframes.insert(input.keyframe);
    auto& links = keyframe_planes_[input.keyframe];
    if (std::find(links.begin(), links.end(), best) == links.end()) links.push_back(best);
    if (std::find(touched.begin(), touched.end(), best) == touched.end()) touched.push_back(best);
  }
  for (PlaneId id : touched) reestimate(&planes_.at(id), cam, up);

  // Planes joined by this keyframe may now be one physical plane with another.
  for (size_t t = 0; t < touched.size(); ++t) {
    bool merged = true;
    while (merged && planes_.count(touched[t])) {
      merged = false;
      for (auto& [other_id, other] : planes_) {
        if (other_id == touched[t]) continue;
        Entry& self = planes_.at(touched[t]);
        std::vector<Eigen::Vector3d> pts;
        for (const auto& kv : self.points) pts.push_back(kv.second);
        double md = 0.0;
        if (!matches(other, pts, self.plane.boundary, self.plane.normal, &md)) continue;
        const PlaneId keep = std::min(other_id, touched[t]);
        const PlaneId gone = std::max(other_id, touched[t]);
        absorb(&planes_.at(keep), &planes_.at(gone));
        planes_.erase(gone);
        update.removed.push_back(gone);
        for (auto& id : touched) {
          if (id == gone) id = keep;
        }
        reestimate(&planes_.at(keep), cam, up);
        if (std::find(touched.begin(), touched.end(), keep) == touched.end()) {
          touched.push_back(keep);
        }
        merged = true;
        break;
      }
    }
  }

  std::sort(touched.begin(), touched.end());
  touched.erase(std::unique(touched.begin(), touched.end()), touched.end());
  auto gone = [&](PlaneId id) { return planes_.count(id) == 0; };
  update.created.erase(std::remove_if(update.created.begin(), update.created.end(), gone),
                       update.created.end());
  for (PlaneId id : touched) {
    if (!gone(id) &&
        std::find(update.created.begin(), update.created.end(), id) == update.created.end()) {
      update.updated.push_back(id);
    }
  }
  std::sort(update.removed.begin(), update.removed.end());
  auto links = keyframe_planes_.find(input.keyframe);
  if (links != keyframe_planes_.end()) {
    std::sort(links->second.begin(), links->second.end());
    update.keyframe_planes = links->second;
  }
  if (!touched.empty()) ++revision_;
  return update;
}

std::vector<Plane> PlaneMap::planes() const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  std::vector<Plane> out;
  out.reserve(planes_.size());
  for (const auto& kv : planes_) out.push_back(kv.second.plane);
  std::sort(out.begin(), out.end(), [](const Plane& a, const Plane& b) { return a.id < b.id; });
  return out;
}

std::vector<Plane> PlaneMap::planes(const std::vector<PlaneId>& ids) const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  std::vector<Plane> out;
  for (PlaneId id : ids) {
    const auto it = planes_.find(id);
    if (it != planes_.end()) out.push_back(it->second.plane);
  }
  return out;
}

std::optional<Plane> PlaneMap::plane(PlaneId id) const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  const auto it = planes_.find(id);
  if (it == planes_.end()) return std::nullopt;
  return it->second.plane;
}

size_t PlaneMap::size() const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  return planes_.size();
}

uint64_t PlaneMap::revision() const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  return revision_;
}

std::vector<PlaneId> PlaneMap::planesOfKeyFrame(KeyFrameId keyframe) const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  const auto it = keyframe_planes_.find(keyframe);
  if (it == keyframe_planes_.end()) return {};
  std::vector<PlaneId> out = it->second;
  std::sort(out.begin(), out.end());
  return out;
}

std::vector<KeyFrameId> PlaneMap::keyframesOfPlane(PlaneId id) const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  const auto it = planes_.find(id);
  if (it == planes_.end()) return {};
  std::vector<KeyFrameId> out(it->second.keyframes.begin(), it->second.keyframes.end());
  std::sort(out.begin(), out.end());
  return out;
}

std::vector<MapPointId> PlaneMap::pointsOfPlane(PlaneId id) const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  const auto it = planes_.find(id);
  if (it == planes_.end()) return {};
  std::vector<MapPointId> out;
  out.reserve(it->second.points.size());
  for (const auto& kv : it->second.points) out.push_back(kv.first);
  std::sort(out.begin(), out.end());
  return out;
}

std::optional<PlaneId> PlaneMap::planeOfPoint(MapPointId point) const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  const auto it = point_owner_.find(point);
  if (it == point_owner_.end()) return std::nullopt;
  return it->second;
}

void PlaneMap::eraseKeyFrame(KeyFrameId keyframe) {
  std::unique_lock<std::shared_mutex> lock(mutex_);
  const auto it = keyframe_planes_.find(keyframe);
  if (it == keyframe_planes_.end()) return;
  for (PlaneId id : it->second) {
    const auto p = planes_.find(id);
    if (p != planes_.end()) p->second.keyframes.erase(keyframe);
  }
  keyframe_planes_.erase(it);
  ++revision_;
}

std::vector<PlaneRecord> PlaneMap::save() const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  std::vector<PlaneRecord> out;
  for (const auto& [id, entry] : planes_) {
    PlaneRecord r;
    r.plane = entry.plane;
    for (const auto& [pid, p_w] : entry.points) r.points.push_back({pid, p_w});
    std::sort(r.points.begin(), r.points.end(),
              [](const PlanePoint& a, const PlanePoint& b) { return a.id < b.id; });
    r.keyframes.assign(entry.keyframes.begin(), entry.keyframes.end());
    std::sort(r.keyframes.begin(), r.keyframes.end());
    out.push_back(std::move(r));
  }
  std::sort(out.begin(), out.end(),
            [](const PlaneRecord& a, const PlaneRecord& b) { return a.plane.id < b.plane.id; });
  return out;
}

uint32_t PlaneMap::nextId() const {
  std::shared_lock<std::shared_mutex> lock(mutex_);
  return next_id_;
}

void PlaneMap::load(const std::vector<PlaneRecord>& records, uint32_t next_id) {
  std::unordered_map<PlaneId, Entry> planes;
  std::unordered_map<MapPointId, PlaneId> owner;
  std::unordered_map<KeyFrameId, std::vector<PlaneId>> links;
  uint32_t next = std::max<uint32_t>(1, next_id);
  for (const auto& r : records) {
    const PlaneId id = r.plane.id;
    const std::string what = "planes: record of plane " + std::to_string(id.value);
    if (!id.valid()) throw Error("planes: record with invalid plane id 0");
    if (planes.count(id)) throw Error(what + " appears twice");
    if (!r.plane.normal.allFinite() || std::abs(r.plane.normal.norm() - 1.0) > 1e-6 ||
        !std::isfinite(r.plane.offset)) {
      throw Error(what + " has a non-unit normal or a non-finite offset");
    }
    Entry e;
    e.plane = r.plane;
    for (const auto& p : r.points) {
      e.points[p.id] = p.p_w;
      const auto held = owner.emplace(p.id, id);
      if (held.first->second != id) {
        throw Error(what + ": point " + std::to_string(p.id.value) + " is held by plane " +
                    std::to_string(held.first->second.value) + " too");
      }
    }
    for (KeyFrameId kf : r.keyframes) {
      e.keyframes.insert(kf);
      links[kf].push_back(id);
    }
    e.plane.num_points = static_cast<uint32_t>(e.points.size());
    next = std::max(next, id.value + 1);
    planes.emplace(id, std::move(e));
  }
  std::unique_lock<std::shared_mutex> lock(mutex_);
  planes_ = std::move(planes);
  point_owner_ = std::move(owner);
  keyframe_planes_ = std::move(links);
  next_id_ = next;
  ++revision_;
}

void PlaneMap::clear() {
  std::unique_lock<std::shared_mutex> lock(mutex_);
  planes_.clear();
  point_owner_.clear();
  keyframe_planes_.clear();
  next_id_ = 1;
  ++revision_;
}

}  // namespace ecar
