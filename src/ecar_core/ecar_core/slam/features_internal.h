// Private to the ORB extractor (features.cpp, features_corners.cpp): its
// state between frames (OrbExtractor::Impl), the patch geometry both parts
// use, and the macro that compiles hot loops for AVX2 too.
#pragma once

#include <cstdint>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/features2d.hpp>

#include "ecar_core/slam/features.h"

// Hot loops are compiled twice, for AVX2 and for the baseline CPU, and the
// CPU picks one when the program loads. Not under ThreadSanitizer, whose
// instrumentation crashes the load-time resolvers (it is not yet set up then).
#if defined(__GNUC__) && defined(__x86_64__) && !defined(__AVX2__) && !defined(__SANITIZE_THREAD__)
#define ECAR_CLONE_AVX2 __attribute__((target_clones("avx2", "default")))
#else
#define ECAR_CLONE_AVX2
#endif

namespace ecar {
namespace orb_internal {

/// Keypoints lie at least this far (px at their level) from the level's
/// border, as in ORB-SLAM: the orientation disk (radius 15) and the rotated
/// descriptor pattern (up to 18.4 px) stay inside the level image. It is also
/// the edgeThreshold of OpenCV's ORB, which drops keypoints closer to the border.
constexpr int kBorder = 19;
constexpr int kPatchSize = 31;
constexpr int kHalfPatch = kPatchSize / 2;  ///< radius of the orientation disk

/// The orientation disk: offsets (u, v) with u^2 + v^2 <= r^2 + r, i.e. within
/// r + 1/2 px of the centre, r = kHalfPatch. Symmetric in u and v, so a 90
/// degree rotation maps it onto itself. As weights over rows of 32 pixels, u
/// from -r to r + 1 (so that the loops below have a fixed length of 32 and
/// vectorise): inside[v][u + r] is 1 in the disk, u_inside[v][u + r] = u there.
struct OrientationDisk {
  static constexpr int kWidth = 32;
  int16_t inside[kHalfPatch + 1][kWidth];
  int16_t u_inside[kHalfPatch + 1][kWidth];
  OrientationDisk() {
    for (int v = 0; v <= kHalfPatch; ++v) {
      for (int u = -kHalfPatch; u < kWidth - kHalfPatch; ++u) {
        const bool in = u * u + v * v <= kHalfPatch * kHalfPatch + kHalfPatch;
        inside[v][u + kHalfPatch] = in ? 1 : 0;
        u_inside[v][u + kHalfPatch] = static_cast<int16_t>(in ? u : 0);
      }
    }
  }
};

}  // namespace orb_internal

struct OrbExtractor::Impl {
  /// A FAST corner in level pixels; response = cv::FAST's (score - 1).
  struct Corner {
    float x, y;
    int response;
  };
  /// computeAt: keypoint `index` at pixel (x, y) of its level.
  struct Request {
    int x, y;
    int index;
  };
  /// A quadtree node: the corners corners[begin, end) lie in [x0, x1) x [y0, y1).
  struct Node {
    float x0, y0, x1, y1;
    int begin, end;
    int depth;
    bool split = false;
    int count() const { return end - begin; }
  };

  /// Levels [0, num_levels) of `gray`.
  void buildPyramid(const cv::Mat& gray, int num_levels);
  /// FAST corners of a level, thresholded per grid cell, in level pixels.
  void detectCorners(int level);
  /// Appends at most `target` of `corners` (the level's) to *out, spread
  /// evenly over [x0, x1) x [y0, y1) by a quadtree.
  void distribute(float x0, float y0, float x1, float y1, int target, std::vector<Corner>* out);
  /// Descriptors of level_keypoints (at pixels of `level`, class_id = row)
  /// into those rows of *descriptors, with (*valid)[row] = 1.
  void describe(int level, cv::Mat* descriptors, std::vector<uint8_t>* valid);

  OrbConfig config;
  std::vector<float> scale;
  std::vector<int> features_per_level;
  orb_internal::OrientationDisk disk;
  /// One-level ORB: run on each of our levels, so OpenCV builds no pyramid.
  cv::Ptr<cv::ORB> orb;

  // Buffers kept between frames.
  cv::Mat color_buffer;
  std::vector<cv::Mat> levels;  ///< levels[0] refers to the input image
  std::vector<cv::Mat> scores;  ///< FAST score maps
  std::vector<uint8_t> maxima;  ///< one row of local maxima
  std::vector<uint8_t> cell_has_corner;
  std::vector<Corner> corners;  ///< of the current level
  std::vector<Node> nodes;
  std::vector<int> heap;
  std::vector<Corner> selected;
  std::vector<Request> requests;
  std::vector<cv::KeyPoint> level_keypoints;  ///< of one level, in level pixels
  cv::Mat level_descriptors;
};

}  // namespace ecar
