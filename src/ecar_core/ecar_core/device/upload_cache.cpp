#include "ecar_core/device/upload_cache.h"

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>

#include <opencv2/imgcodecs.hpp>

#include "ecar_core/common/error.h"
#include "ecar_core/io/atomic_file.h"

namespace ecar {
namespace {

namespace fs = std::filesystem;

std::vector<uint8_t> readFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return {};
  return std::vector<uint8_t>(std::istreambuf_iterator<char>(in), {});
}

/// The gravity uploaded with frame i: the dataset's, else the last IMU sample
/// at or before the frame.
std::optional<Eigen::Vector3d> gravityOf(const Dataset& dataset, size_t i) {
  const DatasetFrame& frame = dataset.frame(i);
  if (frame.gravity_c) return frame.gravity_c;
  std::optional<Eigen::Vector3d> g;
  for (const ImuSample& s : dataset.imu()) {
    if (s.timestamp > frame.timestamp) break;
    g = s.acc_c;
  }
  return g;
}

}  // namespace

bool UploadCache::wholeJpeg(const std::vector<uint8_t>& b) {
  return b.size() >= 4 && b[0] == 0xFF && b[1] == 0xD8 && b[b.size() - 2] == 0xFF &&
         b[b.size() - 1] == 0xD9;
}

UploadCache UploadCache::build(const Dataset& dataset, const UploadCacheConfig& config) {
  if (config.every < 1) throw Error("upload cache: every must be >= 1");
  if (config.jpeg_quality < 1 || config.jpeg_quality > 100) {
    throw Error("upload cache: jpeg_quality must be in 1..100");
  }
  UploadCache cache;
  cache.dir_ =
      config.dir.empty()
          ? (fs::path(dataset.dir()) / ("jpeg_q" + std::to_string(config.jpeg_quality))).string()
          : config.dir;
  std::error_code ec;
  fs::create_directories(cache.dir_, ec);
  if (ec || !fs::is_directory(cache.dir_)) {
    throw Error("upload cache: cannot create " + cache.dir_ + ": " + ec.message());
  }
  const size_t frames =
      config.max_frames > 0 ? std::min(config.max_frames, dataset.size()) : dataset.size();
  const std::vector<int> params = {cv::IMWRITE_JPEG_QUALITY, config.jpeg_quality};
  for (size_t i = 0; i < frames; i += static_cast<size_t>(config.every)) {
    char name[32];
    std::snprintf(name, sizeof(name), "%06zu.jpg", i);
    const std::string path = (fs::path(cache.dir_) / name).string();
    CachedUpload u;
    u.index = i;
    u.timestamp = dataset.frame(i).timestamp;
    u.T_o_c = dataset.frame(i).T_o_c_odom;
    u.gravity_c = gravityOf(dataset, i);
    u.jpeg = readFile(path);
    if (!wholeJpeg(u.jpeg)) {
      const cv::Mat gray = dataset.loadImage(i, cv::IMREAD_GRAYSCALE);
      if (!cv::imencode(".jpg", gray, u.jpeg, params)) {
        throw Error("upload cache: cannot encode " + dataset.frame(i).image_path);
      }
      writeFileAtomically(path, u.jpeg, "upload cache entry " + path);
      ++cache.encoded_;
    }
    cache.bytes_ += u.jpeg.size();
    cache.uploads_.push_back(std::move(u));
  }
  return cache;
}

}  // namespace ecar
