// Procedural surface textures for the synthetic world: non-repeating random
// shapes (rectangles, triangles, ellipses, strokes) over a smooth base, at sizes
// from centimetres to decimetres, so that ORB finds distinct corners from 0.5 m
// to 10 m. Each texture is stored as a mip pyramid (grey and packed BGRA) so
// the renderer can filter it without aliasing shimmer.
#pragma once

#include <cstdint>
#include <vector>

#include <opencv2/core.hpp>

#include "ecar_core/sim/scene.h"

namespace ecar {

struct TexturePyramid {
  double texel_size = 0.005;  ///< metres per texel at level 0
  std::vector<cv::Mat> gray;  ///< CV_8UC1 per level, level 0 finest
  std::vector<cv::Mat> bgra;  ///< CV_8UC4 per level (alpha unused)
};

/// Generates the texture of a width_m x height_m surface. The result depends
/// only on (params, surface_seed, tint); `tint` (BGR, 0..1) gives each surface
/// kind its overall colour.
TexturePyramid generateTexture(double width_m, double height_m, const TextureParams& params,
                               uint32_t surface_seed, const cv::Vec3f& tint);

}  // namespace ecar
