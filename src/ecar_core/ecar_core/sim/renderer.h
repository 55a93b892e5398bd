// Ray-casting renderer of a synthetic indoor Scene: grey or colour image,
// per-pixel depth and surface label for a camera pose, with exact geometry
// (ground truth for tests) and mip-mapped procedural textures.
//
// Speed: one pass over the pixels with a precomputed ray per pixel (so lens
// distortion costs nothing extra), a few slab tests per ray and one trilinear
// texture lookup. The output buffers are reused between frames.
#pragma once

#include <cstdint>
#include <optional>
#include <vector>

#include <opencv2/core.hpp>

#include "ecar_core/common/camera.h"
#include "ecar_core/common/geometry.h"
#include "ecar_core/sim/scene.h"
#include "ecar_core/sim/texture.h"

namespace ecar {

enum class SurfaceLabel : uint8_t { kNone = 0, kFloor = 1, kWall = 2, kCeiling = 3, kObject = 4 };
const char* toString(SurfaceLabel label);

struct RenderOptions {
  bool color = false;        ///< CV_8UC3 BGR image instead of CV_8UC1 grey
  bool depth = true;         ///< fill RenderOutput::depth
  bool labels = true;        ///< fill RenderOutput::labels
  float noise_sigma = 0.0f;  ///< additive image noise, grey levels
  uint32_t noise_seed = 0;   ///< e.g. the frame index: noise differs per frame
  /// Mip level selection: footprint = isotropic footprint * (1/cos)^power.
  /// 1 never aliases at grazing angles; smaller keeps floors sharper.
  float anisotropy_power = 0.8f;
  /// A blank view (a covered lens, a bare wall filling the image): uniform
  /// grey plus the noise; depth 0 and labels kNone, as for nothing seen.
  bool blank = false;
};

struct RenderOutput {
  cv::Mat image;   ///< CV_8UC1 or CV_8UC3
  cv::Mat depth;   ///< CV_32FC1, z in the camera frame (m); 0 where nothing is hit
  cv::Mat labels;  ///< CV_8UC1 SurfaceLabel values
};

/// A world surface: one face of a space (seen from inside) or of a solid
/// (seen from outside), axis-aligned.
struct Surface {
  int axis = 2;                ///< axis of the face normal (0 x, 1 y, 2 z)
  double coordinate = 0.0;     ///< the face lies at p[axis] == coordinate
  Eigen::Vector3d normal;      ///< unit normal pointing into the free space
  int s_axis = 0, t_axis = 1;  ///< texture axes
  double s0 = 0.0, t0 = 0.0;   ///< texture origin (the face's min corner)
  SurfaceLabel label = SurfaceLabel::kNone;
  TexturePyramid texture;
};

struct SceneHit {
  double t = 0.0;    ///< ray parameter: p = origin + t * direction
  int surface = -1;  ///< index into Renderer::surfaces()
  SurfaceLabel label = SurfaceLabel::kNone;
  Eigen::Vector3d p_w = Eigen::Vector3d::Zero();
};

class Renderer {
 public:
  /// Generates every surface texture (a fraction of a second for the corridor).
  /// Uses the scene's camera unless `camera` is given.
  explicit Renderer(const Scene& scene, const std::optional<PinholeCamera>& camera = std::nullopt);
  ~Renderer();
  Renderer(Renderer&&) noexcept;
  Renderer& operator=(Renderer&&) noexcept;

  const PinholeCamera& camera() const { return camera_; }
  const std::vector<Surface>& surfaces() const { return surfaces_; }

  /// Renders the view of a camera at T_w_c. Throws ecar::Error when the pose is
  /// not finite. A camera outside the free space sees nothing (label kNone).
  void render(const SE3& T_w_c, const RenderOptions& options, RenderOutput* out) const;

  /// Exact ray cast in double precision (origin in the free space). nullopt
  /// when the ray escapes (cannot happen inside a closed space).
  std::optional<SceneHit> castRay(const Eigen::Vector3d& origin_w,
                                  const Eigen::Vector3d& direction_w) const;

 private:
  struct BoxF {
    float min[3], max[3];
  };
  struct SurfaceView;  // flat per-surface constants for the pixel loop
  /// Per-row scratch: ray parameter, hit surface, texture coordinates, mip level.
  struct RowScratch;
  void rowGeometryFast(const float* R, const float* o, int v, RowScratch* row) const;
  template <bool kColor>
  void fetchRow(const RowScratch& row, uint8_t* img) const;
  void rowGeometryGeneral(const float* R, const float* o, int start_box, int v,
                          RowScratch* row) const;

  Scene scene_;
  PinholeCamera camera_;
  std::vector<Surface> surfaces_;  ///< 6 per space box, then 6 per solid box
  std::vector<BoxF> spaces_f_, solids_f_;
  std::vector<SurfaceView> views_;  ///< parallel to surfaces_
  /// Per pixel ray (x/z, y/z, 1) with distortion removed, as two planes.
  std::vector<float> ray_x_, ray_y_;
  float log2_inv_f_texel_ = 0.0f;       ///< log2(1 / (focal * texel))
  std::vector<float> max_lod_;          ///< coarsest mip level per surface
  std::vector<float> tex_s0_, tex_t0_;  ///< texture origin per surface
};

}  // namespace ecar
