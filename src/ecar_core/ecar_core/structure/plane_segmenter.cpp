#include "ecar_core/structure/plane_segmenter.h"

#include <algorithm>
#include <cmath>
#include <random>
#include <unordered_map>

#include "ecar_core/common/error.h"

namespace ecar {
namespace {

/// Indices (into `points`) of the largest 8-connected group of occupied cells.
std::vector<int> largestCluster(const std::vector<Eigen::Vector3d>& points,
                                const std::vector<int>& members, const PlaneFrame& frame,
                                double cell) {
  std::unordered_map<int64_t, std::vector<int>> cells;
  // Packed as unsigned: shifting a negative cell index is undefined (UBSan).
  auto key = [](int64_t x, int64_t y) {
    return static_cast<int64_t>((static_cast<uint64_t>(x) << 32) ^
                                (static_cast<uint64_t>(y) & 0xFFFFFFFFull));
  };
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

// Whether a plane with unit normal n through `points` is the depth noise of
// one of the planes found before: nearly parallel to it (|cos| of the normals
// at least cos_parallel) with the points' median distance to it below
// min_separation.
bool isNoiseOf(const std::vector<PlaneObservation>& found, const Eigen::Vector3d& n,
               const std::vector<Eigen::Vector3d>& points, double cos_parallel,
               double min_separation, std::vector<double>* distances) {
  for (const PlaneObservation& earlier : found) {
    if (std::abs(earlier.normal.dot(n)) < cos_parallel) continue;
    distances->clear();
    for (const auto& p : points)
      distances->push_back(std::abs(earlier.normal.dot(p) + earlier.offset));
    auto mid = distances->begin() + distances->size() / 2;
    std::nth_element(distances->begin(), mid, distances->end());
    if (*mid < min_separation) return true;
  }
  return false;
}

}  // namespace

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
  const double cos_parallel = std::cos(cfg.merge_angle_deg * M_PI / 180.0);
  std::vector<double> distances;  // isNoiseOf's scratch
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
    // The noise of a plane found before (its points are left out with it).
    if (isNoiseOf(out, obs.normal, sel, cos_parallel, cfg.min_separation, &distances)) continue;
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

}  // namespace ecar
