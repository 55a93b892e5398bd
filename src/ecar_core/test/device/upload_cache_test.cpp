// The uploads of a dataset encoded once: what is cached, reused and repaired.
#include "ecar_core/device/upload_cache.h"

#include <filesystem>
#include <fstream>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "../test_support.h"
#include "ecar_core/common/error.h"
#include "ecar_core/io/dataset_writer.h"

namespace ecar {
namespace {

namespace fs = std::filesystem;
using testing::TempDir;

std::string writeDataset(const TempDir& tmp, int frames) {
  CameraParams p;
  p.width = 64;
  p.height = 48;
  p.fx = p.fy = 50.0;
  p.cx = 31.5;
  p.cy = 23.5;
  const std::string dir = tmp.file("sim");
  DatasetWriter writer(dir, PinholeCamera(p));
  cv::RNG rng(7);
  for (int i = 0; i < frames; ++i) {
    cv::Mat image(48, 64, CV_8UC3);
    rng.fill(image, cv::RNG::UNIFORM, 0, 255);
    SE3 T_w_c = SE3::Identity();
    T_w_c.translation() = Eigen::Vector3d(0.1 * i, 0.0, 0.0);
    SE3 T_o_c = SE3::Identity();
    T_o_c.translation() = Eigen::Vector3d(0.2 * i, 0.0, 0.0);
    writer.addFrame(0.1 * i, image, T_w_c, Eigen::Vector3d(0.0, -9.81, 0.0), T_o_c);
  }
  writer.finish();
  return dir;
}

TEST(UploadCache, EncodesEveryNthFrameOnceWithItsOdometryAndGravity) {
  TempDir tmp("upload_cache");
  const Dataset dataset = Dataset::open(writeDataset(tmp, 9));
  UploadCacheConfig config;
  config.every = 4;
  config.jpeg_quality = 80;
  const UploadCache cache = UploadCache::build(dataset, config);
  EXPECT_EQ(cache.dir(), (fs::path(dataset.dir()) / "jpeg_q80").string());
  ASSERT_EQ(cache.uploads().size(), 3u);
  EXPECT_EQ(cache.encoded(), 3u);
  size_t bytes = 0;
  for (size_t k = 0; k < 3; ++k) {
    const CachedUpload& u = cache.uploads()[k];
    EXPECT_EQ(u.index, 4 * k);
    EXPECT_DOUBLE_EQ(u.timestamp, dataset.frame(4 * k).timestamp);
    ASSERT_TRUE(u.T_o_c);
    EXPECT_NEAR(u.T_o_c->translation().x(), 0.2 * 4 * k, 1e-6);
    ASSERT_TRUE(u.gravity_c);
    EXPECT_NEAR(u.gravity_c->y(), -9.81, 1e-6);
    // A grayscale JPEG of the frame, the same bytes as on disk.
    const cv::Mat decoded = cv::imdecode(u.jpeg, cv::IMREAD_UNCHANGED);
    EXPECT_EQ(decoded.type(), CV_8UC1);
    EXPECT_EQ(decoded.cols, 64);
    char name[16];
    std::snprintf(name, sizeof(name), "%06zu.jpg", 4 * k);
    EXPECT_EQ(fs::file_size(fs::path(cache.dir()) / name), u.jpeg.size());
    bytes += u.jpeg.size();
  }
  EXPECT_EQ(cache.bytes(), bytes);

  // Built again: everything read back, nothing encoded.
  const UploadCache again = UploadCache::build(dataset, config);
  EXPECT_EQ(again.encoded(), 0u);
  EXPECT_EQ(again.uploads()[2].jpeg, cache.uploads()[2].jpeg);
}

TEST(UploadCache, ADamagedEntryIsEncodedAgain) {
  TempDir tmp("upload_cache");
  const Dataset dataset = Dataset::open(writeDataset(tmp, 5));
  UploadCacheConfig config;
  config.dir = tmp.file("cache");
  const UploadCache cache = UploadCache::build(dataset, config);
  ASSERT_EQ(cache.uploads().size(), 2u);
  // Cut short, as a crash while writing by hand would leave it.
  const fs::path entry = fs::path(config.dir) / "000004.jpg";
  fs::resize_file(entry, fs::file_size(entry) / 2);
  const UploadCache repaired = UploadCache::build(dataset, config);
  EXPECT_EQ(repaired.encoded(), 1u);
  EXPECT_EQ(repaired.uploads()[1].jpeg, cache.uploads()[1].jpeg);
  EXPECT_TRUE(UploadCache::wholeJpeg(repaired.uploads()[1].jpeg));
}

TEST(UploadCache, MaxFramesAndBadSettings) {
  TempDir tmp("upload_cache");
  const Dataset dataset = Dataset::open(writeDataset(tmp, 9));
  UploadCacheConfig config;
  config.max_frames = 5;
  EXPECT_EQ(UploadCache::build(dataset, config).uploads().size(), 2u);  // frames 0 and 4
  config.every = 0;
  EXPECT_THROW(UploadCache::build(dataset, config), Error);
  config.every = 4;
  config.jpeg_quality = 101;
  EXPECT_THROW(UploadCache::build(dataset, config), Error);
  config.jpeg_quality = 70;
  // A folder that cannot be made: the error names it.
  std::ofstream(tmp.file("a_file")) << "x";
  config.dir = tmp.file("a_file") + "/cache";
  try {
    UploadCache::build(dataset, config);
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find(config.dir), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace ecar
