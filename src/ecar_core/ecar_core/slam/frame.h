// One image's features, ready for tracking: keypoints (as detected, in the
// distorted image), their undistorted positions, descriptors, and a grid that
// finds the keypoints near a pixel quickly.
#pragma once

#include <cstdint>
#include <optional>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "ecar_core/common/camera.h"
#include "ecar_core/common/geometry.h"
#include "ecar_core/slam/features.h"
#include "ecar_core/slam/optimizer.h"

namespace ecar {

/// Keypoint indices bucketed by undistorted position, in two arrays (the
/// entries sorted by cell, and where each cell's entries start): a frame's grid
/// is two allocations whatever its size, and copying it (a keyframe keeps its
/// frame's) is two block copies.
class FeatureGrid {
 public:
  static constexpr int kCell = 16;  ///< px
  /// Buckets `points` lying in [min_u, max_u) x [min_v, max_v) (the camera's
  /// undistorted image box). Reuses the grid's memory.
  void build(const std::vector<Eigen::Vector2d>& points, const std::vector<cv::KeyPoint>& kps,
             double min_u, double min_v, double max_u, double max_v);
  /// Indices of keypoints within `radius` px of (u, v) whose octave lies in
  /// [min_level, max_level] (-1: no bound). Appends to *out after clearing it.
  void query(double u, double v, double radius, int min_level, int max_level,
             std::vector<int>* out) const;
  /// Empties the grid (queries find nothing), keeping its memory for the next build.
  void clear() {
    entries_.clear();
    cell_start_.clear();
  }
  /// Heap memory held (bytes).
  size_t memoryBytes() const {
    return entries_.capacity() * sizeof(Entry) + cell_start_.capacity() * sizeof(uint32_t);
  }

 private:
  struct Entry {
    float u, v;
    int index;
    int octave;
  };
  int cols_ = 0, rows_ = 0;
  double origin_u_ = 0.0, origin_v_ = 0.0;
  std::vector<Entry> entries_;        ///< by cell (row-major), then keypoint index
  std::vector<uint32_t> cell_start_;  ///< cols_ * rows_ + 1: cell c is [start[c], start[c+1])
};

/// Pyramid constants shared by frames and keyframes.
struct ScaleInfo {
  std::vector<float> scale, sigma2, inv_sigma2;
  float log_scale_factor = 0.0f;
  int levels() const { return static_cast<int>(scale.size()); }
  static ScaleInfo fromConfig(const OrbConfig& config);
};

struct Frame {
  uint32_t frame_index = 0;
  double timestamp = 0.0;
  int width = 0, height = 0;  ///< image size (px)
  /// Box of the undistorted image (PinholeCamera::minU() ...): where a
  /// projection (undistorted pixels) can meet a keypoint.
  double min_u = 0, min_v = 0, max_u = 0, max_v = 0;
  std::vector<cv::KeyPoint> keypoints;       ///< distorted pixels, angle, octave
  std::vector<Eigen::Vector2d> undistorted;  ///< undistorted pixels
  cv::Mat descriptors;                       ///< N x 32, CV_8U
  std::optional<Eigen::Vector3d> gravity_c;
  std::optional<SE3> T_o_c;  ///< device odometry, when the upload has it
  FeatureGrid grid;

  size_t size() const { return keypoints.size(); }
  /// Fills undistorted positions and the grid from keypoints (call after detection).
  void finalize(const PinholeCamera& camera);
  /// An empty frame that keeps its vectors' memory for the next image (a tracker
  /// refills one frame per image); the descriptors are released, not reused,
  /// since a keyframe may share them.
  void clear();
};

/// Intrinsics of the undistorted pinhole of a camera.
inline Intrinsics intrinsicsOf(const PinholeCamera& camera) { return camera.intrinsics(); }

}  // namespace ecar
