#include "ecar_core/slam/frame.h"

#include <algorithm>
#include <cmath>

namespace ecar {

void FeatureGrid::build(const std::vector<Eigen::Vector2d>& points,
                        const std::vector<cv::KeyPoint>& kps, double min_u, double min_v,
                        double max_u, double max_v) {
  origin_u_ = std::floor(min_u);
  origin_v_ = std::floor(min_v);
  cols_ = std::max(1, static_cast<int>(std::ceil((max_u - origin_u_) / kCell)));
  rows_ = std::max(1, static_cast<int>(std::ceil((max_v - origin_v_) / kCell)));
  const size_t cells = static_cast<size_t>(cols_) * rows_;
  // Counting sort by cell: count, prefix sums, place. cell_start_[c + 1] counts
  // cell c first; after placing, cell_start_[c] has moved to where c ends.
  cell_start_.assign(cells + 1, 0);
  const auto cellOf = [&](const Eigen::Vector2d& p) -> long {
    const double fx = std::floor((p.x() - origin_u_) / kCell);
    const double fy = std::floor((p.y() - origin_v_) / kCell);
    if (!(fx >= 0 && fy >= 0 && fx < cols_ && fy < rows_)) return -1;  // NaN included
    return static_cast<long>(fy) * cols_ + static_cast<long>(fx);
  };
  for (const Eigen::Vector2d& p : points) {
    const long c = cellOf(p);
    if (c >= 0) ++cell_start_[c + 1];
  }
  for (size_t c = 0; c < cells; ++c) cell_start_[c + 1] += cell_start_[c];
  entries_.resize(cell_start_[cells]);
  std::vector<uint32_t>& next = cell_start_;  // next free place of each cell
  for (size_t i = 0; i < points.size(); ++i) {
    const long c = cellOf(points[i]);
    if (c < 0) continue;
    entries_[next[c]++] = {static_cast<float>(points[i].x()), static_cast<float>(points[i].y()),
                           static_cast<int>(i), kps[i].octave};
  }
  // next[c] is now the end of cell c, the start of c + 1: shift back by one.
  for (size_t c = cells; c > 0; --c) cell_start_[c] = cell_start_[c - 1];
  cell_start_[0] = 0;
}

void FeatureGrid::query(double u, double v, double radius, int min_level, int max_level,
                        std::vector<int>* out) const {
  out->clear();
  if (cell_start_.empty() || !(std::fabs(u) < 1e6) || !(std::fabs(v) < 1e6) || !(radius < 1e4)) {
    return;
  }
  const double gu = u - origin_u_, gv = v - origin_v_;
  const int x0 = std::max(0, static_cast<int>(std::floor((gu - radius) / kCell)));
  const int x1 = std::min(cols_ - 1, static_cast<int>(std::floor((gu + radius) / kCell)));
  const int y0 = std::max(0, static_cast<int>(std::floor((gv - radius) / kCell)));
  const int y1 = std::min(rows_ - 1, static_cast<int>(std::floor((gv + radius) / kCell)));
  if (x0 > x1) return;
  const double r2 = radius * radius;
  for (int y = y0; y <= y1; ++y) {
    // The cells x0..x1 of a row are contiguous in entries_.
    const Entry* e = entries_.data() + cell_start_[y * cols_ + x0];
    const Entry* end = entries_.data() + cell_start_[y * cols_ + x1 + 1];
    for (; e != end; ++e) {
      if ((min_level >= 0 && e->octave < min_level) || (max_level >= 0 && e->octave > max_level)) {
        continue;
      }
      const double du = e->u - u, dv = e->v - v;
      if (du * du + dv * dv <= r2) out->push_back(e->index);
    }
  }
}

ScaleInfo ScaleInfo::fromConfig(const OrbConfig& config) {
  ScaleInfo s;
  float scale = 1.0f;
  for (int l = 0; l < config.num_levels; ++l) {
    s.scale.push_back(scale);
    s.sigma2.push_back(scale * scale);
    s.inv_sigma2.push_back(1.0f / (scale * scale));
    scale *= config.scale_factor;
  }
  s.log_scale_factor = std::log(config.scale_factor);
  return s;
}

void Frame::finalize(const PinholeCamera& camera) {
  width = camera.width();
  height = camera.height();
  undistorted.resize(keypoints.size());
  for (size_t i = 0; i < keypoints.size(); ++i) {
    undistorted[i] = camera.undistortPoint(Eigen::Vector2d(keypoints[i].pt.x, keypoints[i].pt.y));
  }
  min_u = camera.minU();
  min_v = camera.minV();
  max_u = camera.maxU();
  max_v = camera.maxV();
  grid.build(undistorted, keypoints, min_u, min_v, max_u, max_v);
}

void Frame::clear() {
  frame_index = 0;
  timestamp = 0.0;
  width = height = 0;
  min_u = min_v = max_u = max_v = 0.0;
  keypoints.clear();
  undistorted.clear();
  descriptors.release();
  gravity_c.reset();
  T_o_c.reset();
  grid.clear();
}

}  // namespace ecar
