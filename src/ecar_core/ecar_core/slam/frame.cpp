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
  if (cells_.size() != static_cast<size_t>(cols_ * rows_)) cells_.assign(cols_ * rows_, {});
  for (auto& c : cells_) c.clear();
  for (size_t i = 0; i < points.size(); ++i) {
    const int cx = static_cast<int>(std::floor((points[i].x() - origin_u_) / kCell));
    const int cy = static_cast<int>(std::floor((points[i].y() - origin_v_) / kCell));
    if (cx < 0 || cy < 0 || cx >= cols_ || cy >= rows_) continue;
    cells_[cy * cols_ + cx].push_back({static_cast<float>(points[i].x()),
                                       static_cast<float>(points[i].y()), static_cast<int>(i),
                                       kps[i].octave});
  }
}

void FeatureGrid::query(double u, double v, double radius, int min_level, int max_level,
                        std::vector<int>* out) const {
  out->clear();
  if (cells_.empty() || !(std::fabs(u) < 1e6) || !(std::fabs(v) < 1e6) || !(radius < 1e4)) return;
  const double gu = u - origin_u_, gv = v - origin_v_;
  const int x0 = std::max(0, static_cast<int>(std::floor((gu - radius) / kCell)));
  const int x1 = std::min(cols_ - 1, static_cast<int>(std::floor((gu + radius) / kCell)));
  const int y0 = std::max(0, static_cast<int>(std::floor((gv - radius) / kCell)));
  const int y1 = std::min(rows_ - 1, static_cast<int>(std::floor((gv + radius) / kCell)));
  const double r2 = radius * radius;
  for (int y = y0; y <= y1; ++y) {
    for (int x = x0; x <= x1; ++x) {
      for (const Entry& e : cells_[y * cols_ + x]) {
        if ((min_level >= 0 && e.octave < min_level) || (max_level >= 0 && e.octave > max_level)) {
          continue;
        }
        const double du = e.u - u, dv = e.v - v;
        if (du * du + dv * dv <= r2) out->push_back(e.index);
      }
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

}  // namespace ecar
