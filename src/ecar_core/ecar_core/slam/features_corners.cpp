// The corner detection of the ORB extractor: FAST-9 scores and local maxima
// per pyramid level (the per-pixel loops), thresholded per grid cell, and the
// quadtree that spreads the corners evenly over the level.
#include "ecar_core/slam/features_internal.h"

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <vector>

#include <opencv2/core.hpp>

#include "ecar_core/slam/features.h"

namespace ecar {
namespace {

using orb_internal::kBorder;

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

}  // namespace

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

}  // namespace ecar
