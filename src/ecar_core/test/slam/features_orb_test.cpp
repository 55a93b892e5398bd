// OrbExtractor on a rendered corridor view and on a KITTI image: count,
// spread over the image and the pyramid, orientation, descriptor repeatability
// and bad input.
#include <algorithm>
#include <bitset>
#include <cmath>
#include <limits>
#include <random>
#include <string>
#include <tuple>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/features2d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "ecar_core/common/error.h"
#include "ecar_core/sim/renderer.h"
#include "ecar_core/slam/features.h"

namespace ecar {
namespace {

const char kKittiImage[] = "/work/shared/data/kitti07_0-159/image_0/000000.png";

// A view along the corridor: walls, floor, ceiling and the far end.
const cv::Mat& corridorImage() {
  static const cv::Mat image = [] {
    const Scene scene = loadScene(ECAR_REPO_ROOT "/config/scenes/corridor.yaml");
    const Renderer renderer(scene);
    RenderOutput out;
    renderer.render(lookAt(Eigen::Vector3d(4.0, 1.0, 1.5), Eigen::Vector3d(8.0, 1.4, 1.2)),
                    RenderOptions(), &out);
    return out.image.clone();
  }();
  return image;
}

cv::Mat kittiImage() { return cv::imread(kKittiImage, cv::IMREAD_GRAYSCALE); }

int occupiedCells(const std::vector<cv::KeyPoint>& kps, const cv::Size& size, int cols, int rows) {
  std::vector<bool> cell(static_cast<size_t>(cols * rows), false);
  for (const auto& kp : kps) {
    const int cx = std::min(cols - 1, static_cast<int>(kp.pt.x) * cols / size.width);
    const int cy = std::min(rows - 1, static_cast<int>(kp.pt.y) * rows / size.height);
    cell[cy * cols + cx] = true;
  }
  return static_cast<int>(std::count(cell.begin(), cell.end(), true));
}

// Properties every extraction must have.
void expectWellFormed(const OrbExtractor& orb, const cv::Size& size,
                      const std::vector<cv::KeyPoint>& kps, const cv::Mat& desc) {
  ASSERT_EQ(desc.rows, static_cast<int>(kps.size()));
  if (!kps.empty()) {
    EXPECT_EQ(desc.cols, 32);
    EXPECT_EQ(desc.type(), CV_8U);
  }
  const int levels = orb.config().num_levels;
  for (const auto& kp : kps) {
    ASSERT_GE(kp.octave, 0);
    ASSERT_LT(kp.octave, levels);
    const float s = orb.scaleFactors()[kp.octave];
    EXPECT_FLOAT_EQ(kp.size, 31.0f * s);
    EXPECT_GE(kp.angle, 0.0f);
    EXPECT_LT(kp.angle, 360.0f);
    EXPECT_GE(kp.response, orb.config().min_fast_threshold);
    // At least 19 px from the border at the keypoint's level.
    EXPECT_GE(kp.pt.x / s, 18.99f);
    EXPECT_GE(kp.pt.y / s, 18.99f);
    EXPECT_LE(kp.pt.x / s, size.width / s - 19.0f);
    EXPECT_LE(kp.pt.y / s, size.height / s - 19.0f);
  }
}

std::vector<int> perLevel(const std::vector<cv::KeyPoint>& kps, int levels) {
  std::vector<int> n(static_cast<size_t>(levels), 0);
  for (const auto& kp : kps) ++n[kp.octave];
  return n;
}

TEST(OrbExtractorTest, ScalesAndLevelSigmas) {
  OrbExtractor orb;
  ASSERT_EQ(orb.scaleFactors().size(), 8u);
  for (int l = 0; l < 8; ++l) {
    EXPECT_NEAR(orb.scaleFactors()[l], std::pow(1.2, l), 1e-5);
    EXPECT_NEAR(orb.levelSigma2()[l], std::pow(1.44, l), 1e-4);
    EXPECT_NEAR(orb.invLevelSigma2()[l] * orb.levelSigma2()[l], 1.0, 1e-6);
  }
}

TEST(OrbExtractorTest, SyntheticImageKeypointsOnAllLevelsSpreadOverTheImage) {
  const cv::Mat& image = corridorImage();
  ASSERT_EQ(image.type(), CV_8UC1);
  OrbExtractor orb;
  std::vector<cv::KeyPoint> kps;
  cv::Mat desc;
  orb.detectAndCompute(image, &kps, &desc);
  expectWellFormed(orb, image.size(), kps, desc);
  EXPECT_NEAR(static_cast<double>(kps.size()), 1000.0, 100.0);
  const std::vector<int> n = perLevel(kps, 8);
  for (int l = 0; l < 8; ++l) EXPECT_GT(n[l], 0) << "level " << l;
  // More on fine levels than on coarse ones (a geometric series).
  EXPECT_GT(n[0], n[7]);
  EXPECT_GE(occupiedCells(kps, image.size(), 8, 6), 39) << "of 48";  // 80 %
  // Spread, not clustered: no 8 x 6 cell holds more than a tenth of them.
  std::vector<int> count(48, 0);
  for (const auto& kp : kps) {
    ++count[static_cast<int>(kp.pt.y) * 6 / image.rows * 8 +
            static_cast<int>(kp.pt.x) * 8 / image.cols];
  }
  EXPECT_LE(*std::max_element(count.begin(), count.end()), static_cast<int>(kps.size()) / 10);
}

TEST(OrbExtractorTest, RealImageKeypointsOnAllLevels) {
  const cv::Mat image = kittiImage();
  if (image.empty()) GTEST_SKIP() << kKittiImage << " not found";
  OrbExtractor orb;
  std::vector<cv::KeyPoint> kps;
  cv::Mat desc;
  orb.detectAndCompute(image, &kps, &desc);
  expectWellFormed(orb, image.size(), kps, desc);
  EXPECT_NEAR(static_cast<double>(kps.size()), 1000.0, 100.0);
  const std::vector<int> n = perLevel(kps, 8);
  for (int l = 0; l < 8; ++l) EXPECT_GT(n[l], 0) << "level " << l;
  EXPECT_GE(occupiedCells(kps, image.size(), 8, 6), 34) << "of 48";  // 70 %: sky and road
}

// The extractor's own FAST (vectorised, one score map per level) against
// OpenCV's on level 0, which is the image itself.
TEST(OrbExtractorTest, LevelZeroKeypointsAreFastCornersWithTheirResponse) {
  for (const bool real : {false, true}) {
    const cv::Mat image = real ? kittiImage() : corridorImage();
    if (image.empty()) continue;
    OrbExtractor orb;
    std::vector<cv::KeyPoint> kps;
    orb.detectAndCompute(image, &kps, nullptr);
    std::vector<cv::KeyPoint> corners;
    cv::FAST(image, corners, orb.config().min_fast_threshold, true);
    cv::Mat response(image.size(), CV_32F, cv::Scalar(-1));
    for (const auto& c : corners) response.at<float>(c.pt) = c.response;
    int level0 = 0;
    for (const auto& kp : kps) {
      if (kp.octave != 0) continue;
      ++level0;
      ASSERT_EQ(kp.pt.x, std::round(kp.pt.x));
      EXPECT_EQ(kp.response, response.at<float>(kp.pt)) << kp.pt;
    }
    EXPECT_GT(level0, 150);
  }
}

TEST(OrbExtractorTest, FewerFeaturesAndOtherPyramids) {
  const cv::Mat& image = corridorImage();
  for (const auto& [features, levels, factor] : {std::tuple<int, int, float>{300, 8, 1.2f},
                                                 {2000, 8, 1.2f},
                                                 {500, 1, 1.2f},
                                                 {1000, 4, 1.5f}}) {
    OrbConfig config;
    config.num_features = features;
    config.num_levels = levels;
    config.scale_factor = factor;
    OrbExtractor orb(config);
    std::vector<cv::KeyPoint> kps;
    cv::Mat desc;
    orb.detectAndCompute(image, &kps, &desc);
    expectWellFormed(orb, image.size(), kps, desc);
    EXPECT_NEAR(static_cast<double>(kps.size()), features, 0.1 * features)
        << features << " features, " << levels << " levels, factor " << factor;
    const std::vector<int> n = perLevel(kps, levels);
    for (int l = 0; l < levels; ++l) EXPECT_GT(n[l], 0) << "level " << l;
  }
}

TEST(OrbExtractorTest, BuffersReusedAcrossImageSizesGiveTheSameResult) {
  const cv::Mat& synthetic = corridorImage();
  cv::Mat other = kittiImage();
  if (other.empty()) cv::resize(synthetic, other, cv::Size(900, 300));
  OrbExtractor fresh, reused;
  std::vector<cv::KeyPoint> kps_fresh, kps_reused;
  cv::Mat desc_fresh, desc_reused;
  fresh.detectAndCompute(synthetic, &kps_fresh, &desc_fresh);
  reused.detectAndCompute(other, &kps_reused, &desc_reused);
  const cv::Mat kept = desc_reused;  // the caller keeps the last frame's descriptors
  const cv::Mat kept_copy = kept.clone();
  reused.detectAndCompute(synthetic, &kps_reused, &desc_reused);
  EXPECT_EQ(cv::norm(kept, kept_copy, cv::NORM_INF), 0.0) << "descriptors written in place";
  ASSERT_EQ(kps_fresh.size(), kps_reused.size());
  for (size_t i = 0; i < kps_fresh.size(); ++i) {
    EXPECT_EQ(kps_fresh[i].pt, kps_reused[i].pt);
    EXPECT_EQ(kps_fresh[i].angle, kps_reused[i].angle);
    EXPECT_EQ(kps_fresh[i].octave, kps_reused[i].octave);
  }
  EXPECT_EQ(cv::norm(desc_fresh, desc_reused, cv::NORM_HAMMING), 0.0);
}

TEST(OrbExtractorTest, ColourImageIsConvertedToGrey) {
  const cv::Mat& gray = corridorImage();
  cv::Mat bgr;
  cv::cvtColor(gray, bgr, cv::COLOR_GRAY2BGR);
  OrbExtractor orb;
  std::vector<cv::KeyPoint> kps_gray, kps_bgr;
  cv::Mat desc_gray, desc_bgr;
  orb.detectAndCompute(gray, &kps_gray, &desc_gray);
  orb.detectAndCompute(bgr, &kps_bgr, &desc_bgr);
  ASSERT_EQ(kps_gray.size(), kps_bgr.size());
  EXPECT_EQ(cv::norm(desc_gray, desc_bgr, cv::NORM_HAMMING), 0.0);
}

// cv::rotate by 90 degrees clockwise maps (x, y) to (rows - 1 - y, x) and
// turns every direction by +90 degrees (image axes, y down).
TEST(OrbExtractorTest, AnglesTurnWithTheImage) {
  const cv::Mat& image = corridorImage();
  cv::Mat rotated;
  cv::rotate(image, rotated, cv::ROTATE_90_CLOCKWISE);
  OrbExtractor orb;
  std::vector<cv::KeyPoint> kps, kps_rot;
  cv::Mat desc, desc_rot;
  orb.detectAndCompute(image, &kps, &desc);
  orb.detectAndCompute(rotated, &kps_rot, &desc_rot);
  int matched = 0, agree = 0, same_descriptor = 0;
  for (const auto& kp : kps) {
    const cv::Point2f expected(image.rows - 1 - kp.pt.y, kp.pt.x);
    const float tolerance = 1.0f * orb.scaleFactors()[kp.octave];
    for (size_t j = 0; j < kps_rot.size(); ++j) {
      const auto& kr = kps_rot[j];
      if (kr.octave != kp.octave || cv::norm(kr.pt - expected) > tolerance) continue;
      ++matched;
      float diff = std::fmod(kr.angle - kp.angle - 90.0f + 720.0f, 360.0f);
      if (diff > 180.0f) diff -= 360.0f;
      if (std::fabs(diff) < 10.0f) ++agree;
      if (descriptorDistance(desc, static_cast<int>(&kp - kps.data()), desc_rot,
                             static_cast<int>(j)) < 50) {
        ++same_descriptor;
      }
      break;
    }
  }
  EXPECT_GE(matched, 200);
  EXPECT_GE(agree, 0.9 * matched) << matched << " matched";
  // rBRIEF is steered by the angle: the rotated patch gives about the same bits.
  EXPECT_GE(same_descriptor, 0.8 * matched) << matched << " matched";
}

// A keypoint found on a coarse pyramid level must lie where the same corner
// is in the full image, without a bias: a constant offset that grows with the
// level (half a level pixel when the level-to-image mapping ignores pixel
// centres) makes a point seen at changing scales drift, which a walk turns
// into scale drift of the whole map. Truth: the same high-resolution picture
// area-downsampled straight to a level's size, whose level-0 corners have no
// scaling error.
TEST(OrbExtractorTest, CoarseLevelKeypointsHaveNoPositionBias) {
  const cv::Size size(640, 480);
  const int k = 6;  // high-resolution oversampling
  cv::Mat high(size.height * k, size.width * k, CV_8UC1, cv::Scalar(128));
  std::mt19937 rng(5);
  std::uniform_int_distribution<int> x(0, high.cols), y(0, high.rows), side(60, 400), grey(0, 255);
  for (int i = 0; i < 1500; ++i) {
    const cv::Point p(x(rng), y(rng));
    cv::rectangle(high, cv::Rect(p, cv::Size(side(rng), side(rng))), cv::Scalar(grey(rng)),
                  cv::FILLED);
  }
  cv::Mat image;
  cv::resize(high, image, size, 0, 0, cv::INTER_AREA);
  OrbConfig config;
  config.num_features = 3000;
  OrbExtractor orb(config);
  std::vector<cv::KeyPoint> kps;
  cv::Mat desc;
  orb.detectAndCompute(image, &kps, &desc);

  OrbConfig single = config;
  single.num_levels = 1;
  OrbExtractor level0(single);
  for (int level : {3, 5}) {
    const float s = orb.scaleFactors()[level];
    const cv::Size level_size(cvRound(size.width / s), cvRound(size.height / s));
    cv::Mat truth_image;
    cv::resize(high, truth_image, level_size, 0, 0, cv::INTER_AREA);
    std::vector<cv::KeyPoint> truth;
    level0.detectAndCompute(truth_image, &truth, nullptr);
    const double sx = static_cast<double>(size.width) / level_size.width;
    const double sy = static_cast<double>(size.height) / level_size.height;
    double sum_dx = 0, sum_dy = 0;
    int n = 0;
    for (const auto& kp : kps) {
      if (kp.octave != level) continue;
      // The nearest true corner, in full-image pixels.
      double best = 1.5 * s * 1.5 * s, dx = 0, dy = 0;
      for (const auto& t : truth) {
        const double tx = (t.pt.x + 0.5) * sx - 0.5, ty = (t.pt.y + 0.5) * sy - 0.5;
        const double d2 = (kp.pt.x - tx) * (kp.pt.x - tx) + (kp.pt.y - ty) * (kp.pt.y - ty);
        if (d2 < best) best = d2, dx = kp.pt.x - tx, dy = kp.pt.y - ty;
      }
      if (best < 1.5 * s * 1.5 * s) sum_dx += dx, sum_dy += dy, ++n;
    }
    ASSERT_GE(n, 30) << "level " << level;
    EXPECT_LT(std::abs(sum_dx / n), 0.2) << "level " << level << ", " << n << " keypoints";
    EXPECT_LT(std::abs(sum_dy / n), 0.2) << "level " << level << ", " << n << " keypoints";
  }
}

TEST(OrbExtractorTest, ComputeAtReproducesDescriptors) {
  for (const bool real : {false, true}) {
    const cv::Mat image = real ? kittiImage() : corridorImage();
    if (image.empty()) continue;
    OrbExtractor orb;
    std::vector<cv::KeyPoint> kps;
    cv::Mat desc;
    orb.detectAndCompute(image, &kps, &desc);
    ASSERT_GT(kps.size(), 500u);

    cv::Mat again;
    std::vector<uint8_t> valid;
    orb.computeAt(image, kps, &again, &valid);
    ASSERT_EQ(again.rows, static_cast<int>(kps.size()));
    ASSERT_EQ(valid.size(), kps.size());
    int identical = 0;
    for (size_t i = 0; i < kps.size(); ++i) {
      EXPECT_TRUE(valid[i]);
      if (descriptorDistance(desc, static_cast<int>(i), again, static_cast<int>(i)) == 0) {
        ++identical;
      }
    }
    EXPECT_GE(identical, 0.99 * kps.size()) << (real ? "KITTI" : "synthetic");

    // The same image after JPEG compression (quality 70): close descriptors.
    std::vector<uchar> jpeg;
    cv::imencode(".jpg", image, jpeg, {cv::IMWRITE_JPEG_QUALITY, 70});
    const cv::Mat decoded = cv::imdecode(jpeg, cv::IMREAD_GRAYSCALE);
    cv::Mat from_jpeg;
    orb.computeAt(decoded, kps, &from_jpeg, &valid);
    int close = 0;
    for (size_t i = 0; i < kps.size(); ++i) {
      if (valid[i] &&
          descriptorDistance(desc, static_cast<int>(i), from_jpeg, static_cast<int>(i)) <= 50) {
        ++close;
      }
    }
    EXPECT_GE(close, 0.9 * kps.size()) << (real ? "KITTI" : "synthetic");
  }
}

TEST(OrbExtractorTest, ComputeAtRejectsKeypointsItCannotDescribe) {
  const cv::Mat& image = corridorImage();
  OrbExtractor orb;
  const float nan = std::numeric_limits<float>::quiet_NaN();
  std::vector<cv::KeyPoint> kps = {
      cv::KeyPoint(320.0f, 240.0f, 31.0f, 45.0f, 0.0f, 0),         // fine
      cv::KeyPoint(320.0f, 240.0f, 31.0f, 45.0f, 0.0f, 99),        // no such level
      cv::KeyPoint(320.0f, 240.0f, 31.0f, 45.0f, 0.0f, -1),        // no such level
      cv::KeyPoint(-50.0f, 240.0f, 31.0f, 45.0f, 0.0f, 0),         // outside
      cv::KeyPoint(700.0f, 900.0f, 31.0f, 45.0f, 0.0f, 0),         // outside
      cv::KeyPoint(5.0f, 240.0f, 31.0f, 45.0f, 0.0f, 0),           // at the border
      cv::KeyPoint(630.0f, 240.0f, 31.0f, 45.0f, 0.0f, 0),         // at the border
      cv::KeyPoint(320.0f, 30.0f, 31.0f * 3.58f, 45.0f, 0.0f, 7),  // border at level 7
      cv::KeyPoint(nan, 240.0f, 31.0f, 45.0f, 0.0f, 0),
      cv::KeyPoint(320.0f, 240.0f, 31.0f, nan, 0.0f, 0),
      cv::KeyPoint(1e30f, 1e30f, 31.0f, 45.0f, 0.0f, 0),
      cv::KeyPoint(320.0f, 240.0f, 31.0f * 3.58f, 45.0f, 0.0f, 7),  // fine
  };
  cv::Mat desc;
  std::vector<uint8_t> valid;
  orb.computeAt(image, kps, &desc, &valid);
  ASSERT_EQ(desc.rows, static_cast<int>(kps.size()));
  ASSERT_EQ(valid.size(), kps.size());
  const std::vector<uint8_t> expected = {1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1};
  for (size_t i = 0; i < kps.size(); ++i) {
    EXPECT_EQ(valid[i], expected[i]) << "keypoint " << i;
    if (!valid[i]) {
      EXPECT_EQ(cv::countNonZero(desc.row(static_cast<int>(i))), 0);
    }
  }
  EXPECT_GT(cv::countNonZero(desc.row(0)), 0);

  // The angle steers the descriptor.
  std::vector<cv::KeyPoint> turned = {kps[0]};
  turned[0].angle += 90.0f;
  cv::Mat desc_turned;
  orb.computeAt(image, turned, &desc_turned, &valid);
  EXPECT_GT(descriptorDistance(desc, 0, desc_turned, 0), 20);

  // Nothing to describe on a bad image; no keypoints, no rows.
  orb.computeAt(cv::Mat(), kps, &desc, &valid);
  EXPECT_EQ(desc.rows, static_cast<int>(kps.size()));
  EXPECT_EQ(std::count(valid.begin(), valid.end(), 1), 0);
  orb.computeAt(image, {}, &desc, &valid);
  EXPECT_EQ(desc.rows, 0);
  EXPECT_TRUE(valid.empty());
}

TEST(OrbExtractorTest, BadImagesGiveNoKeypoints) {
  OrbExtractor orb;
  std::vector<cv::KeyPoint> kps;
  cv::Mat desc;
  cv::Mat image16;
  corridorImage().convertTo(image16, CV_16U, 256.0);
  const cv::Mat bad[] = {cv::Mat(),
                         image16,
                         cv::Mat(10, 10, CV_8UC1, cv::Scalar(128)),
                         cv::Mat(63, 640, CV_8UC1, cv::Scalar(128)),
                         cv::Mat(480, 640, CV_32FC1, cv::Scalar(0.5)),
                         cv::Mat(480, 640, CV_8UC2, cv::Scalar(1, 2))};
  for (const cv::Mat& image : bad) {
    kps.assign(3, cv::KeyPoint());
    orb.detectAndCompute(image, &kps, &desc);
    EXPECT_TRUE(kps.empty()) << image.size() << " type " << image.type();
    EXPECT_EQ(desc.rows, 0);
  }
  // A flat image has no corners; a 64 x 64 one is small but fine.
  orb.detectAndCompute(cv::Mat(480, 640, CV_8UC1, cv::Scalar(90)), &kps, &desc);
  EXPECT_TRUE(kps.empty());
  orb.detectAndCompute(corridorImage()(cv::Rect(200, 200, 64, 64)), &kps, &desc);
  expectWellFormed(orb, cv::Size(64, 64), kps, desc);
  // Without a descriptor matrix: keypoints only.
  orb.detectAndCompute(corridorImage(), &kps, nullptr);
  EXPECT_GT(kps.size(), 900u);
}

TEST(OrbExtractorTest, InvalidConfigIsAnErrorNamingTheKey) {
  auto expectError = [](OrbConfig c, const std::string& key) {
    try {
      OrbExtractor orb(c);
      ADD_FAILURE() << key << " accepted";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(key), std::string::npos) << e.what();
    }
  };
  OrbConfig c;
  c.num_features = 0;
  expectError(c, "num_features");
  c = OrbConfig();
  c.scale_factor = 1.0f;
  expectError(c, "scale_factor");
  c = OrbConfig();
  c.num_levels = 0;
  expectError(c, "num_levels");
  c = OrbConfig();
  c.min_fast_threshold = 30;
  expectError(c, "min_fast_threshold");
  c = OrbConfig();
  c.cell_size = 0;
  expectError(c, "cell_size");
}

TEST(OrbExtractorTest, DescriptorDistanceCountsDifferentBits) {
  std::mt19937 rng(5);
  std::uniform_int_distribution<int> byte(0, 255);
  cv::Mat a(50, 32, CV_8U), b(50, 32, CV_8U);
  for (int r = 0; r < 50; ++r) {
    for (int c = 0; c < 32; ++c) {
      a.at<uint8_t>(r, c) = static_cast<uint8_t>(byte(rng));
      b.at<uint8_t>(r, c) = static_cast<uint8_t>(byte(rng));
    }
  }
  b.row(1).setTo(0);
  a.row(1).setTo(255);
  a.row(2).copyTo(b.row(2));
  for (int r = 0; r < 50; ++r) {
    int reference = 0;
    for (int c = 0; c < 32; ++c) {
      reference +=
          static_cast<int>(std::bitset<8>(a.at<uint8_t>(r, c) ^ b.at<uint8_t>(r, c)).count());
    }
    EXPECT_EQ(descriptorDistance(a, r, b, r), reference) << "row " << r;
    EXPECT_EQ(descriptorDistance(a.ptr<uint8_t>(r), b.ptr<uint8_t>(r)), reference);
  }
  EXPECT_EQ(descriptorDistance(a, 1, b, 1), 256);
  EXPECT_EQ(descriptorDistance(a, 2, b, 2), 0);
}

}  // namespace
}  // namespace ecar
