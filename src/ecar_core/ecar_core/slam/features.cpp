// ORB extraction in the manner of ORB-SLAM: on each pyramid level, FAST corners
// (per grid cell, with a lower threshold where a cell has none), thinned by a
// quadtree to a quota per level so that they cover the image evenly, oriented
// by the intensity centroid. OpenCV's rBRIEF describes them, run on each of our
// levels: ORB's learned test pattern matches better than a random one.
#include "ecar_core/slam/features.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <string>

#include <opencv2/features2d.hpp>
#include <opencv2/imgproc.hpp>

#include "ecar_core/common/error.h"

namespace ecar {
namespace {

/// Keypoints lie at least this far (px at their level) from the level's
/// border, as in ORB-SLAM: the orientation disk (radius 15) and the rotated
/// descriptor pattern (up to 18.4 px) stay inside the level image. It is also
/// the edgeThreshold of OpenCV's ORB, which drops keypoints closer to the border.
constexpr int kBorder = 19;
constexpr int kPatchSize = 31;
constexpr int kHalfPatch = kPatchSize / 2;  ///< radius of the orientation disk
constexpr int kMinImageSide = 64;
constexpr int kDescriptorBytes = 32;
constexpr int kMaxLevels = 32;

/// 8-bit grey view of `image` (converted into *buffer when it has colour).
/// False for an unsupported type or an image too small to extract from.
bool toGray(const cv::Mat& image, cv::Mat* buffer, cv::Mat* gray) {
  if (image.empty() || image.depth() != CV_8U) return false;
  if (image.cols < kMinImageSide || image.rows < kMinImageSide) return false;
  switch (image.channels()) {
    case 1:
      *gray = image;
      return true;
    case 3:
      cv::cvtColor(image, *buffer, cv::COLOR_BGR2GRAY);
      *gray = *buffer;
      return true;
    case 4:
      cv::cvtColor(image, *buffer, cv::COLOR_BGRA2GRAY);
      *gray = *buffer;
      return true;
    default:
      return false;
  }
}

cv::Size levelSize(const cv::Size& image, float scale) {
  return cv::Size(cvRound(image.width / scale), cvRound(image.height / scale));
}

// cv::resize (INTER_LINEAR) maps pixel centres: a level pixel x is the image
// point (x + 0.5) * (W / w) - 0.5, with the exact size ratio of the level (not
// the nominal scale, which rounding of the level size makes differ by up to
// 1.4 px at the coarsest level's far edge).
cv::Point2f levelToImage(float x, float y, const cv::Size& image, const cv::Size& level) {
  const float sx = static_cast<float>(image.width) / static_cast<float>(level.width);
  const float sy = static_cast<float>(image.height) / static_cast<float>(level.height);
  return {(x + 0.5f) * sx - 0.5f, (y + 0.5f) * sy - 0.5f};
}

cv::Point2f imageToLevel(float x, float y, const cv::Size& image, const cv::Size& level) {
  const float sx = static_cast<float>(level.width) / static_cast<float>(image.width);
  const float sy = static_cast<float>(level.height) / static_cast<float>(image.height);
  return {(x + 0.5f) * sx - 0.5f, (y + 0.5f) * sy - 0.5f};
}

bool levelUsable(const cv::Size& size) {
  return size.width > 2 * kBorder && size.height > 2 * kBorder;
}

// ---------------------------------------------------------------------------
// FAST-9 (9 contiguous pixels of the 16 on a radius-3 circle all brighter, or
// all darker, than the centre by more than a threshold) as a score per pixel:
// score = the largest d such that 9 contiguous circle pixels differ from the
// centre by at least d on the same side. A pixel is a corner at threshold t
// iff score > t, and score - 1 is cv::FAST's response. One score map per
// level serves both thresholds of the per-cell retry.

/// The circle, in order around it.
constexpr int kCircleX[16] = {0, 1, 2, 3, 3, 3, 2, 1, 0, -1, -2, -3, -3, -3, -2, -1};
constexpr int kCircleY[16] = {-3, -3, -2, -1, 0, 1, 2, 3, 3, 3, 2, 1, 0, -1, -2, -3};

uint8_t fastScorePixel(const uint8_t* center, const std::ptrdiff_t* offsets) {
  const int c = center[0];
  int best = 0;
  for (int start = 0; start < 16; ++start) {
    int brighter = 255, darker = 255;
    for (int k = 0; k < 9; ++k) {
      const int p = center[offsets[(start + k) & 15]];
      brighter = std::min(brighter, std::max(0, p - c));
      darker = std::min(darker, std::max(0, c - p));
    }
    best = std::max(best, std::max(brighter, darker));
  }
  return static_cast<uint8_t>(best);
}

// Hot loops are compiled twice, for AVX2 and for the baseline CPU, and the
// CPU picks one when the program loads. Not under ThreadSanitizer, whose
// instrumentation crashes the load-time resolvers (it is not yet set up then).
#if defined(__GNUC__) && defined(__x86_64__) && !defined(__AVX2__) && !defined(__SANITIZE_THREAD__)
#define ECAR_CLONE_AVX2 __attribute__((target_clones("avx2", "default")))
#else
#define ECAR_CLONE_AVX2
#endif

// The score loop is written with GCC vector extensions, 32 pixels per
// operation (portable C++ elsewhere), and checked against cv::FAST in the tests.
#if defined(__GNUC__) && !defined(__clang__)
#define ECAR_FAST_VECTORS 1
// Functions returning 32-byte vectors are all inlined into one target clone,
// so the ABI difference GCC warns about never applies.
#pragma GCC diagnostic ignored "-Wpsabi"

typedef uint8_t Bytes32 __attribute__((vector_size(32)));
inline Bytes32 load32(const uint8_t* p) {
  Bytes32 v;
  std::memcpy(&v, p, sizeof(v));
  return v;
}
// (Arguments by reference: by value, GCC notes an ABI change at every call.)
inline Bytes32 min32(const Bytes32& a, const Bytes32& b) { return a < b ? a : b; }
inline Bytes32 max32(const Bytes32& a, const Bytes32& b) { return a > b ? a : b; }
inline Bytes32 subSaturated32(const Bytes32& a, const Bytes32& b) { return a - min32(a, b); }

/// max over the 16 arcs of 9 of the min of d: minima over arcs of 2, 4, 8, 9.
inline Bytes32 bestArc32(const Bytes32* d) {
  Bytes32 m2[16], m4[16];
  for (int i = 0; i < 16; ++i) m2[i] = min32(d[i], d[(i + 1) & 15]);
  for (int i = 0; i < 16; ++i) m4[i] = min32(m2[i], m2[(i + 2) & 15]);
  Bytes32 best = min32(min32(m4[0], m4[4]), d[8]);
  for (int i = 1; i < 16; ++i) {
    best = max32(best, min32(min32(m4[i], m4[(i + 4) & 15]), d[(i + 8) & 15]));
  }
  return best;
}

/// Scores of n consecutive pixels from `center` (n >= 32).
ECAR_CLONE_AVX2
void fastScoreRow(const uint8_t* center, const std::ptrdiff_t* offsets, int n, uint8_t* out) {
  for (int x = 0;; x += 32) {
    x = std::min(x, n - 32);  // the last block overlaps the one before
    const Bytes32 c = load32(center + x);
    Bytes32 brighter[16], darker[16];
    for (int i = 0; i < 16; ++i) {
      const Bytes32 p = load32(center + x + offsets[i]);
      brighter[i] = subSaturated32(p, c);
      darker[i] = subSaturated32(c, p);
    }
    const Bytes32 score = max32(bestArc32(brighter), bestArc32(darker));
    std::memcpy(out + x, &score, sizeof(score));
    if (x + 32 == n) return;
  }
}
#endif  // ECAR_FAST_VECTORS

void fastScores(const uint8_t* center, const std::ptrdiff_t* offsets, int n, uint8_t* out) {
#ifdef ECAR_FAST_VECTORS
  if (n >= 32) {
    fastScoreRow(center, offsets, n, out);
    return;
  }
#endif
  for (int x = 0; x < n; ++x) out[x] = fastScorePixel(center + x, offsets);
}

/// out[x] = score[x] where it exceeds `threshold` and its 8 neighbours (the
/// non-maximum suppression of cv::FAST), else 0.
ECAR_CLONE_AVX2
void localMaxima(const uint8_t* above, const uint8_t* row, const uint8_t* below, int n,
                 uint8_t threshold, uint8_t* out) {
  for (int x = 0; x < n; ++x) {
    uint8_t m = std::max(std::max(above[x - 1], above[x]), above[x + 1]);
    m = std::max(m, std::max(std::max(below[x - 1], below[x]), below[x + 1]));
    m = std::max(m, std::max(std::max(row[x - 1], row[x + 1]), threshold));
    out[x] = row[x] > m ? row[x] : 0;
  }
}

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

/// Angle (degrees, [0, 360)) from (x, y) to the intensity centroid of the
/// orientation disk around it: atan2(m01, m10) of the disk's first moments.
ECAR_CLONE_AVX2
float intensityCentroidAngle(const cv::Mat& image, int x, int y, const OrientationDisk& disk) {
  constexpr int kWidth = OrientationDisk::kWidth;
  const std::ptrdiff_t step = static_cast<std::ptrdiff_t>(image.step);
  const uint8_t* center = image.ptr<uint8_t>(y) + x - kHalfPatch;  // row start
  int m10 = 0, m01 = 0;
  for (int i = 0; i < kWidth; ++i) m10 += disk.u_inside[0][i] * center[i];
  for (int v = 1; v <= kHalfPatch; ++v) {
    const uint8_t* below = center + v * step;
    const uint8_t* above = center - v * step;
    int row_difference = 0;
    for (int i = 0; i < kWidth; ++i) {
      row_difference += disk.inside[v][i] * (below[i] - above[i]);
      m10 += disk.u_inside[v][i] * (below[i] + above[i]);
    }
    m01 += v * row_difference;
  }
  float angle = static_cast<float>(std::atan2(static_cast<double>(m01), static_cast<double>(m10)) *
                                   (180.0 / CV_PI));
  if (angle < 0.0f) angle += 360.0f;
  if (angle >= 360.0f) angle -= 360.0f;
  return angle;
}

void checkConfig(const OrbConfig& c) {
  auto fail = [](const std::string& key, const std::string& why) {
    throw Error("OrbConfig." + key + ": " + why);
  };
  if (c.num_features < 1) fail("num_features", "must be >= 1");
  if (!(c.scale_factor > 1.0f) || !(c.scale_factor < 4.0f)) {
    fail("scale_factor", "must be in (1, 4)");
  }
  if (c.num_levels < 1 || c.num_levels > kMaxLevels) {
    fail("num_levels", "must be in [1, " + std::to_string(kMaxLevels) + "]");
  }
  if (c.fast_threshold < 1 || c.fast_threshold > 254) fail("fast_threshold", "must be in [1, 254]");
  if (c.min_fast_threshold < 1 || c.min_fast_threshold > c.fast_threshold) {
    fail("min_fast_threshold", "must be in [1, fast_threshold]");
  }
  if (c.cell_size < 8) fail("cell_size", "must be >= 8 px");
}

}  // namespace

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
  OrientationDisk disk;
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

void OrbExtractor::Impl::buildPyramid(const cv::Mat& gray, int num_levels) {
  levels.resize(static_cast<size_t>(config.num_levels));
  scores.resize(levels.size());
  levels[0] = gray;
  for (int l = 1; l < num_levels; ++l) {
    // Each level from the previous one, as ORB-SLAM does.
    cv::resize(levels[l - 1], levels[l], levelSize(gray.size(), scale[l]), 0, 0, cv::INTER_LINEAR);
  }
}

void OrbExtractor::Impl::detectCorners(int level) {
  const cv::Mat& image = levels[level];
  cv::Mat& score = scores[level];
  score.create(image.size(), CV_8U);
  std::ptrdiff_t offsets[16];
  for (int i = 0; i < 16; ++i) offsets[i] = kCircleY[i] * image.step + kCircleX[i];
  // Corners lie in [kBorder, cols - kBorder) x [kBorder, rows - kBorder);
  // scores one pixel beyond, for the non-maximum suppression (as cv::FAST
  // would find them on the whole level).
  const int width = image.cols - 2 * kBorder, height = image.rows - 2 * kBorder;
  for (int y = kBorder - 1; y <= kBorder + height; ++y) {
    fastScores(image.ptr<uint8_t>(y) + kBorder - 1, offsets, width + 2,
               score.ptr<uint8_t>(y) + kBorder - 1);
  }

  // Local maxima scoring above fast_threshold; then, in the grid cells
  // without one, those above min_fast_threshold (ORB-SLAM's retry).
  const int cols = std::max(1, width / config.cell_size);
  const int rows = std::max(1, height / config.cell_size);
  const int cell_w = (width + cols - 1) / cols, cell_h = (height + rows - 1) / rows;
  cell_has_corner.assign(static_cast<size_t>(cols * rows), 0);
  corners.clear();
  maxima.resize(static_cast<size_t>(width) + 8);
  // Appends the corners of row y in [x0, x1) (offsets from kBorder); true if any.
  auto collect = [&](int y, int x0, int x1, int threshold) {
    const size_t before = corners.size();
    localMaxima(score.ptr<uint8_t>(y - 1) + kBorder + x0, score.ptr<uint8_t>(y) + kBorder + x0,
                score.ptr<uint8_t>(y + 1) + kBorder + x0, x1 - x0, static_cast<uint8_t>(threshold),
                maxima.data());
    const int n = x1 - x0;
    std::memset(&maxima[n], 0, 8);  // the last word's padding
    for (int x = 0; x < n; x += 8) {
      uint64_t word;  // skips 8 pixels without a corner at once (most)
      std::memcpy(&word, &maxima[x], sizeof(word));
      if (word == 0) continue;
      for (int k = x; k < std::min(x + 8, n); ++k) {
        if (maxima[k] == 0) continue;
        corners.push_back(
            Corner{static_cast<float>(kBorder + x0 + k), static_cast<float>(y), maxima[k] - 1});
      }
    }
    return corners.size() > before;
  };
  for (int y = kBorder; y < kBorder + height; ++y) {
    const size_t before = corners.size();
    if (!collect(y, 0, width, config.fast_threshold)) continue;
    uint8_t* cell_row = &cell_has_corner[static_cast<size_t>((y - kBorder) / cell_h * cols)];
    for (size_t i = before; i < corners.size(); ++i) {
      cell_row[(static_cast<int>(corners[i].x) - kBorder) / cell_w] = 1;
    }
  }
  for (int cy = 0; cy < rows; ++cy) {
    for (int cx = 0; cx < cols; ++cx) {
      if (cell_has_corner[cy * cols + cx]) continue;
      const int x0 = cx * cell_w, x1 = std::min(width, x0 + cell_w);
      const int y1 = std::min(height, (cy + 1) * cell_h);
      for (int y = cy * cell_h; y < y1 && x0 < x1; ++y) {
        collect(kBorder + y, x0, x1, config.min_fast_threshold);
      }
    }
  }
}

void OrbExtractor::Impl::distribute(float x0, float y0, float x1, float y1, int target,
                                    std::vector<Corner>* out) {
  if (target <= 0 || corners.empty()) return;
  if (static_cast<int>(corners.size()) <= target) {
    out->insert(out->end(), corners.begin(), corners.end());
    return;
  }
  nodes.clear();
  heap.clear();
  // Splits the widest nodes first (equal cell sizes: an even spread), among
  // nodes of one size those with the most corners.
  auto lower_priority = [this](int a, int b) {
    const Node& na = nodes[a];
    const Node& nb = nodes[b];
    if (na.depth != nb.depth) return na.depth > nb.depth;
    return na.count() < nb.count();
  };
  int leaves = 0;
  auto add = [&](float ax0, float ay0, float ax1, float ay1, int begin, int end, int depth) {
    if (begin == end) return;
    nodes.push_back(Node{ax0, ay0, ax1, ay1, begin, end, depth});
    ++leaves;
    // Corners are distinct pixels, so a node of two or more always separates;
    // the depth cap only guards against a degenerate input.
    if (end - begin > 1 && depth < 24) {
      heap.push_back(static_cast<int>(nodes.size()) - 1);
      std::push_heap(heap.begin(), heap.end(), lower_priority);
    }
  };

  // Roots: about square, side by side (wide images get several).
  const int num_roots = std::max(1, static_cast<int>(std::lround((x1 - x0) / (y1 - y0))));
  const float root_w = (x1 - x0) / num_roots;
  auto first = corners.begin();
  for (int r = 0; r < num_roots; ++r) {
    const float rx0 = x0 + r * root_w, rx1 = r + 1 == num_roots ? x1 : x0 + (r + 1) * root_w;
    auto last = r + 1 == num_roots ? corners.end()
                                   : std::partition(first, corners.end(),
                                                    [rx1](const Corner& c) { return c.x < rx1; });
    add(rx0, y0, rx1, y1, static_cast<int>(first - corners.begin()),
        static_cast<int>(last - corners.begin()), 0);
    first = last;
  }

  while (leaves < target && !heap.empty()) {
    std::pop_heap(heap.begin(), heap.end(), lower_priority);
    const int index = heap.back();
    heap.pop_back();
    nodes[index].split = true;
    --leaves;
    const Node n = nodes[index];  // copy: add() may reallocate `nodes`
    const float xm = 0.5f * (n.x0 + n.x1), ym = 0.5f * (n.y0 + n.y1);
    auto begin = corners.begin() + n.begin, end = corners.begin() + n.end;
    auto mid_y = std::partition(begin, end, [ym](const Corner& c) { return c.y < ym; });
    auto left_of = [xm](const Corner& c) { return c.x < xm; };
    auto mid_top = std::partition(begin, mid_y, left_of);
    auto mid_bottom = std::partition(mid_y, end, left_of);
    auto at = [&](std::vector<Corner>::iterator it) {
      return static_cast<int>(it - corners.begin());
    };
    add(n.x0, n.y0, xm, ym, n.begin, at(mid_top), n.depth + 1);
    add(xm, n.y0, n.x1, ym, at(mid_top), at(mid_y), n.depth + 1);
    add(n.x0, ym, xm, n.y1, at(mid_y), at(mid_bottom), n.depth + 1);
    add(xm, ym, n.x1, n.y1, at(mid_bottom), n.end, n.depth + 1);
  }

  // The strongest corner of each leaf; when the last split overshot the
  // target, the weakest of those go.
  const size_t out_begin = out->size();
  for (const Node& n : nodes) {
    if (n.split) continue;
    auto best =
        std::max_element(corners.begin() + n.begin, corners.begin() + n.end,
                         [](const Corner& a, const Corner& b) { return a.response < b.response; });
    out->push_back(*best);
  }
  if (out->size() - out_begin > static_cast<size_t>(target)) {
    std::nth_element(out->begin() + out_begin, out->begin() + out_begin + target, out->end(),
                     [](const Corner& a, const Corner& b) { return a.response > b.response; });
    out->resize(out_begin + target);
  }
}

void OrbExtractor::Impl::describe(int level, cv::Mat* descriptors, std::vector<uint8_t>* valid) {
  if (level_keypoints.empty()) return;
  // OpenCV keeps the given angle; it drops keypoints within kBorder px of the
  // border and may reorder the rest: class_id says which row each one fills.
  orb->compute(levels[level], level_keypoints, level_descriptors);
  for (size_t i = 0; i < level_keypoints.size(); ++i) {
    const int row = level_keypoints[i].class_id;
    std::memcpy(descriptors->ptr<uint8_t>(row), level_descriptors.ptr<uint8_t>(static_cast<int>(i)),
                kDescriptorBytes);
    (*valid)[row] = 1;
  }
}

OrbExtractor::OrbExtractor(const OrbConfig& config) : config_(config) {
  checkConfig(config_);
  const int L = config_.num_levels;
  scale_.resize(L);
  sigma2_.resize(L);
  inv_sigma2_.resize(L);
  for (int l = 0; l < L; ++l) {
    scale_[l] = static_cast<float>(std::pow(static_cast<double>(config_.scale_factor), l));
    sigma2_[l] = scale_[l] * scale_[l];
    inv_sigma2_[l] = 1.0f / sigma2_[l];
  }

  impl_ = std::make_shared<Impl>();
  Impl& m = *impl_;
  m.config = config_;
  m.scale = scale_;
  // Features per level: a geometric series in 1/scale_factor, as in ORB-SLAM.
  const double inv = 1.0 / config_.scale_factor;
  double per_level = config_.num_features * (1.0 - inv) / (1.0 - std::pow(inv, L));
  m.features_per_level.resize(L);
  int assigned = 0;
  for (int l = 0; l + 1 < L; ++l) {
    m.features_per_level[l] = static_cast<int>(std::lround(per_level));
    assigned += m.features_per_level[l];
    per_level *= inv;
  }
  m.features_per_level[L - 1] = std::max(0, config_.num_features - assigned);

  m.orb = cv::ORB::create(config_.num_features, config_.scale_factor, 1, kBorder, 0, 2,
                          cv::ORB::HARRIS_SCORE, kPatchSize, config_.fast_threshold);
}

void OrbExtractor::detectAndCompute(const cv::Mat& image, std::vector<cv::KeyPoint>* keypoints,
                                    cv::Mat* descriptors) {
  if (keypoints == nullptr) return;
  keypoints->clear();
  // A new matrix, never written in place: the caller's may share its data.
  if (descriptors != nullptr) *descriptors = cv::Mat(0, kDescriptorBytes, CV_8U);
  Impl& m = *impl_;
  cv::Mat gray;
  if (!toGray(image, &m.color_buffer, &gray)) return;

  int num_levels = 0;  // levels large enough to hold a keypoint
  while (num_levels < config_.num_levels &&
         levelUsable(levelSize(gray.size(), scale_[num_levels]))) {
    ++num_levels;
  }
  m.buildPyramid(gray, num_levels);

  // Coarsest level first: a level short of corners passes its unused quota on
  // to the finer levels, which have more.
  int level_begin[kMaxLevels];
  int carry = 0;
  for (int l = config_.num_levels - 1; l >= num_levels; --l) carry += m.features_per_level[l];
  m.selected.clear();
  for (int l = num_levels - 1; l >= 0; --l) {
    const cv::Mat& level = m.levels[l];
    const int target = m.features_per_level[l] + carry;
    level_begin[l] = static_cast<int>(m.selected.size());
    m.detectCorners(l);
    m.distribute(kBorder, kBorder, static_cast<float>(level.cols - kBorder),
                 static_cast<float>(level.rows - kBorder), target, &m.selected);
    carry = target - (static_cast<int>(m.selected.size()) - level_begin[l]);
  }

  // Keypoints ordered by level, finest first.
  const int n = static_cast<int>(m.selected.size());
  keypoints->reserve(n);
  cv::Mat out;
  std::vector<uint8_t> valid;
  if (descriptors != nullptr) {
    out.create(n, kDescriptorBytes, CV_8U);
    valid.assign(static_cast<size_t>(n), 0);
  }
  for (int l = 0; l < num_levels; ++l) {
    const int end = l == 0 ? n : level_begin[l - 1];
    m.level_keypoints.clear();
    for (int i = level_begin[l]; i < end; ++i) {
      const Impl::Corner& c = m.selected[i];
      const float angle =
          intensityCentroidAngle(m.levels[l], static_cast<int>(c.x), static_cast<int>(c.y), m.disk);
      const int row = static_cast<int>(keypoints->size());
      const cv::Point2f pt = levelToImage(c.x, c.y, gray.size(), m.levels[l].size());
      keypoints->emplace_back(pt.x, pt.y, kPatchSize * scale_[l], angle,
                              static_cast<float>(c.response), l);
      m.level_keypoints.emplace_back(c.x, c.y, kPatchSize, angle, 0.0f, 0, row);
    }
    if (descriptors != nullptr) m.describe(l, &out, &valid);
  }
  if (descriptors == nullptr) return;
  // Every keypoint is kBorder px inside its level, so OpenCV keeps them all;
  // this only guards the contract of one descriptor row per keypoint.
  int kept = 0;
  for (int i = 0; i < n; ++i) {
    if (!valid[i]) continue;
    if (kept != i) {
      (*keypoints)[kept] = (*keypoints)[i];
      out.row(i).copyTo(out.row(kept));
    }
    ++kept;
  }
  keypoints->resize(kept);
  *descriptors = kept == n ? out : out.rowRange(0, kept).clone();
}

void OrbExtractor::computeAt(const cv::Mat& image, const std::vector<cv::KeyPoint>& keypoints,
                             cv::Mat* descriptors, std::vector<uint8_t>* valid) {
  if (descriptors == nullptr || valid == nullptr) return;
  const int n = static_cast<int>(keypoints.size());
  // A new matrix, never written in place: the caller's may share its data.
  *descriptors = cv::Mat(n, kDescriptorBytes, CV_8U, cv::Scalar(0));
  valid->assign(static_cast<size_t>(n), 0);
  Impl& m = *impl_;
  cv::Mat gray;
  if (n == 0 || !toGray(image, &m.color_buffer, &gray)) return;

  // Keep what the detector could have returned on an image of this size: a
  // pyramid level that exists, a finite angle, kBorder px inside the level
  // (at the pixel detectAndCompute found it at).
  std::vector<Impl::Request>& requests = m.requests;
  requests.clear();
  int num_levels = 0;
  for (int i = 0; i < n; ++i) {
    const cv::KeyPoint& kp = keypoints[i];
    if (kp.octave < 0 || kp.octave >= config_.num_levels) continue;
    if (!std::isfinite(kp.angle) || !std::isfinite(kp.pt.x) || !std::isfinite(kp.pt.y)) continue;
    if (kp.pt.x < 0.0f || kp.pt.y < 0.0f || kp.pt.x >= gray.cols || kp.pt.y >= gray.rows) continue;
    const cv::Size size = levelSize(gray.size(), scale_[kp.octave]);
    const cv::Point2f at = imageToLevel(kp.pt.x, kp.pt.y, gray.size(), size);
    const int x = cvRound(at.x), y = cvRound(at.y);
    if (x < kBorder || y < kBorder || x >= size.width - kBorder || y >= size.height - kBorder) {
      continue;
    }
    requests.push_back(Impl::Request{x, y, i});
    num_levels = std::max(num_levels, kp.octave + 1);
  }
  if (num_levels == 0) return;
  m.buildPyramid(gray, num_levels);
  for (int l = 0; l < num_levels; ++l) {
    m.level_keypoints.clear();
    for (const Impl::Request& r : requests) {
      const cv::KeyPoint& kp = keypoints[r.index];
      if (kp.octave != l) continue;
      m.level_keypoints.emplace_back(static_cast<float>(r.x), static_cast<float>(r.y), kPatchSize,
                                     kp.angle, 0.0f, 0, r.index);
    }
    m.describe(l, descriptors, valid);
  }
}

#if defined(__GNUC__) && defined(__x86_64__) && !defined(__POPCNT__) && \
    !defined(__SANITIZE_THREAD__)
// The matcher calls this in its inner loops: use the popcnt instruction where
// the CPU has it (chosen once at load time).
__attribute__((target_clones("popcnt", "default")))
#endif
int descriptorDistance(const uint8_t* a, const uint8_t* b) {
  int distance = 0;
  for (int i = 0; i < kDescriptorBytes; i += 8) {
    uint64_t wa, wb;
    std::memcpy(&wa, a + i, sizeof(wa));
    std::memcpy(&wb, b + i, sizeof(wb));
    distance += __builtin_popcountll(wa ^ wb);
  }
  return distance;
}

}  // namespace ecar
