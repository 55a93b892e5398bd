// ORB features on a scale pyramid, spread evenly over the image.
#pragma once

#include <cstdint>
#include <cstring>
#include <memory>
#include <vector>

#include <opencv2/core.hpp>

namespace ecar {

struct OrbConfig {
  int num_features = 1000;    ///< keypoints per image (over all levels)
  float scale_factor = 1.2f;  ///< between pyramid levels
  int num_levels = 8;
  int fast_threshold = 20;     ///< FAST threshold tried first in each grid cell
  int min_fast_threshold = 7;  ///< fallback threshold for cells without corners
  int cell_size = 35;          ///< grid cell (px at each level) for the even spread
};

/// Bytes of one ORB descriptor (a row of the descriptor matrices, CV_8U).
constexpr int kDescriptorBytes = 32;

/// Hamming distance of two 32-byte ORB descriptors (0..256). Inline, since
/// the matchers call it in their inner loops: four popcnt instructions where
/// the build host has them (ecar_core's users are built with -mpopcnt then,
/// see its CMakeLists.txt), a call per pair would cost as much again.
inline int descriptorDistance(const uint8_t* a, const uint8_t* b) {
  int distance = 0;
  for (int i = 0; i < kDescriptorBytes; i += 8) {
    uint64_t wa, wb;
    std::memcpy(&wa, a + i, sizeof(wa));
    std::memcpy(&wb, b + i, sizeof(wb));
    distance += __builtin_popcountll(wa ^ wb);
  }
  return distance;
}
inline int descriptorDistance(const cv::Mat& a, int ia, const cv::Mat& b, int ib) {
  return descriptorDistance(a.ptr<uint8_t>(ia), b.ptr<uint8_t>(ib));
}

/// Not thread-safe (it keeps its pyramid between calls to avoid allocations):
/// give each thread its own extractor, constructed rather than copied (copies
/// share those buffers).
class OrbExtractor {
 public:
  explicit OrbExtractor(const OrbConfig& config = OrbConfig());

  /// Keypoints (pt in level-0 pixels of the image as given, i.e. distorted;
  /// angle in degrees; octave = pyramid level; size = patch size at that level)
  /// spread over the image, with their descriptors (N x 32, CV_8U; skipped when
  /// `descriptors` is null). An empty, non-8-bit or tiny (< 64 px) image gives
  /// no keypoints (no exception); colour images are converted to grey.
  void detectAndCompute(const cv::Mat& gray, std::vector<cv::KeyPoint>* keypoints,
                        cv::Mat* descriptors);

  /// Descriptors at given keypoints (pt, angle, octave as detectAndCompute
  /// returns them) on another image of the same scene, e.g. the device's own
  /// image at the keypoints the server sends. (*valid)[i] is 0 where a keypoint
  /// is too close to the border or its octave is out of range; its descriptor
  /// row is then zero. descriptors has one row per keypoint.
  void computeAt(const cv::Mat& gray, const std::vector<cv::KeyPoint>& keypoints,
                 cv::Mat* descriptors, std::vector<uint8_t>* valid);

  const OrbConfig& config() const { return config_; }
  const std::vector<float>& scaleFactors() const { return scale_; }  ///< per level
  const std::vector<float>& levelSigma2() const { return sigma2_; }  ///< scale^2
  const std::vector<float>& invLevelSigma2() const { return inv_sigma2_; }

 private:
  OrbConfig config_;
  std::vector<float> scale_, sigma2_, inv_sigma2_;
  struct Impl;
  std::shared_ptr<Impl> impl_;
};

}  // namespace ecar
