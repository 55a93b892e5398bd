// ORB extraction in the manner of ORB-SLAM: on each pyramid level, FAST corners
// (per grid cell, with a lower threshold where a cell has none), thinned by a
// quadtree to a quota per level so that they cover the image evenly, oriented
// by the intensity centroid. OpenCV's rBRIEF describes them, run on each of our
// levels: ORB's learned test pattern matches better than a random one.
// The corner detection (FAST, grid cells, quadtree) is in features_corners.cpp.
#include "ecar_core/slam/features.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <string>
#include <vector>

#include <opencv2/features2d.hpp>
#include <opencv2/imgproc.hpp>

#include "ecar_core/common/error.h"
#include "ecar_core/slam/features_internal.h"

namespace ecar {
namespace {

using orb_internal::kBorder;
using orb_internal::kHalfPatch;
using orb_internal::kPatchSize;
using orb_internal::OrientationDisk;

constexpr int kMinImageSide = 64;
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

void OrbExtractor::Impl::buildPyramid(const cv::Mat& gray, int num_levels) {
  levels.resize(static_cast<size_t>(config.num_levels));
  scores.resize(levels.size());
  levels[0] = gray;
  for (int l = 1; l < num_levels; ++l) {
    // Each level from the previous one, as ORB-SLAM does.
    cv::resize(levels[l - 1], levels[l], levelSize(gray.size(), scale[l]), 0, 0, cv::INTER_LINEAR);
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

}  // namespace ecar
