// Ray casting for the grid connection (eCAR's grid of 0.1 m cells on the
// structure planes; grid_cells.h).
//
// Pixels are sampled on a regular window (default every 5 px) and cast through
// the camera at a pose; the nearest plane hit within max_distance that lies
// inside the plane's boundary (plus a margin) is mapped to its cell
// (floor(X / cell), floor(Y / cell), floor(Z / cell)). The paper writes the ray of
// pixel (u, v) for the world-to-camera pose [R | t] as
//   l_w = R^T K^-1 (u, v, 1)^T - R^T t,
// the point at depth 1 on the ray; its origin is the camera centre -R^T t. Here
// T_w_c = [R^T | -R^T t], so the ray is origin t_w_c, direction R_w_c r_c with
// r_c = K^-1 (u, v, 1)^T (lens distortion removed first when the camera has any).
//
// Use on the server:
//   GridCaster grid(config, camera);                      // once per camera: rays precomputed
//   auto planes = std::make_shared<const GridPlanes>(plane_map.planes(), config.boundary_margin);
//   grid.visibleCells(T_w_c, *planes, &cells);            // every upload, any thread
//   grid_map.setKeyFrameCells(kf, cells);                 // per keyframe with planes
// A nodelet rebuilds GridPlanes when PlaneMap::revision() changes and swaps a
// std::shared_ptr<const GridPlanes> (readers copy the pointer under a small
// mutex or with std::atomic_load), so casting never waits for plane updates.
#pragma once

#include <cstdint>
#include <optional>
#include <vector>

#include <Eigen/Core>

#include "ecar_core/common/camera.h"
#include "ecar_core/common/geometry.h"
#include "ecar_core/common/types.h"
#include "ecar_core/structure/grid_cells.h"
#include "ecar_core/structure/plane.h"

namespace ecar {

struct GridConfig {
  int window = 5;  ///< px between sampled pixels, in u and in v
  /// m: hits farther from the camera centre are ignored (40: a 30 m corridor end to end).
  double max_distance = 40.0;
  double cell_size = 0.1;        ///< m: edge of a grid cell
  double boundary_margin = 0.1;  ///< m: a hit may lie this far outside a plane's boundary

  /// Throws ecar::Error naming the first invalid key (e.g. "grid.window").
  void validate() const;
};

/// A ray's nearest plane hit.
struct RayHit {
  PlaneId plane;
  Eigen::Vector3d p_w = Eigen::Vector3d::Zero();  ///< map frame, m
  double distance = 0.0;                          ///< from the ray origin, m
};

/// Planes prepared for ray casting: each boundary as half-spaces widened by the
/// margin. Immutable after construction, so one instance may be read by any
/// number of threads. Planes with fewer than 3 boundary vertices are skipped.
class GridPlanes {
 public:
  GridPlanes() = default;
  /// Throws ecar::Error when a plane's normal is not unit or a value is not finite.
  GridPlanes(const std::vector<Plane>& planes, double boundary_margin);

  /// Planes kept (with a boundary).
  size_t size() const { return planes_.size(); }

  /// The nearest hit of the ray origin_w + s * dir_w (s > 0; dir_w need not be
  /// unit) within max_distance of origin_w and inside a boundary (with margin).
  std::optional<RayHit> intersect(const Eigen::Vector3d& origin_w, const Eigen::Vector3d& dir_w,
                                  double max_distance) const;

 private:
  friend class GridCaster;
  struct Edge {
    Eigen::Vector3d m;  ///< outward in-plane unit normal of the edge
    double b = 0.0;     ///< inside: m.x <= b (margin included)
  };
  struct Prepared {
    PlaneId id;
    Eigen::Vector3d n;
    double d = 0.0;
    std::vector<Edge> edges;
  };
  static bool inside(const Prepared& p, const Eigen::Vector3d& x) {
    for (const Edge& e : p.edges) {
      if (e.m.dot(x) > e.b) return false;
    }
    return true;
  }
  std::vector<Prepared> planes_;
};

/// One sampled pixel's hit (castSamples).
struct SampleHit {
  int sample = 0;  ///< index into GridCaster::samplePixels()
  PlaneId plane;
  Eigen::Vector3d p_w = Eigen::Vector3d::Zero();
  double distance = 0.0;  ///< from the camera centre, m
  CellKey cell;
};

/// Casts the sampled pixels of one camera. Immutable after construction: every
/// method is const and safe to call from several threads at once (per-call
/// scratch is thread_local; nothing is allocated per call once the output
/// vector and the thread's scratch have grown to size).
class GridCaster {
 public:
  /// Samples pixel (off + i * window, off + j * window), off = (window - 1) / 2,
  /// over the whole image, and stores their rays. Throws ecar::Error when the
  /// config is invalid.
  GridCaster(const GridConfig& config, const PinholeCamera& camera);

  const GridConfig& config() const { return config_; }
  const PinholeCamera& camera() const { return camera_; }
  /// The sampled pixels (u, v), row by row.
  const std::vector<Eigen::Vector2d>& samplePixels() const { return pixels_; }
  size_t numSamples() const { return pixels_.size(); }

  /// The cells hit by the sampled rays from pose T_w_c: sorted, each once.
  /// `cells` is overwritten (its capacity is reused).
  void visibleCells(const SE3& T_w_c, const GridPlanes& planes, std::vector<CellKey>* cells) const;

  /// Every sampled ray's hit from pose T_w_c, by sample index (samples without
  /// a hit are left out). `hits` is overwritten.
  void castSamples(const SE3& T_w_c, const GridPlanes& planes, std::vector<SampleHit>* hits) const;

  /// True when p_w projects into the image from T_w_c, lies within max_distance,
  /// and no plane hides it: a plane hides p_w when the segment from the camera
  /// centre to p_w crosses it inside its boundary more than `tolerance` (m) before
  /// p_w; the planes p_w lies on (closer than tolerance) never hide it. An exact
  /// per-point test (e.g. for a VO's position) without the sampling's gaps: at
  /// 20-30 m along a corridor the 5 px samples hit only a few percent of the
  /// floor cells (ecar_bench_grid prints the coverage).
  bool isVisible(const SE3& T_w_c, const GridPlanes& planes, const Eigen::Vector3d& p_w,
                 double tolerance = 0.05) const;

 private:
  template <typename Emit>
  void cast(const SE3& T_w_c, const GridPlanes& planes, Emit&& emit) const;

  GridConfig config_;
  PinholeCamera camera_;
  std::vector<Eigen::Vector2d> pixels_;
  std::vector<Eigen::Vector3d> rays_c_;  ///< r_c = (x, y, 1), undistorted
  std::vector<double> ray_norms_;        ///< |r_c|
};

}  // namespace ecar
