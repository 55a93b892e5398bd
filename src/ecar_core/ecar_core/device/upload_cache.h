// The uploads of a dataset, made ahead of time: the JPEG of every frame a
// device uploads, encoded once and kept on disk, with the odometry and gravity
// that go with it. Light devices (the paper's device simulators) play these
// instead of a camera: no image decoding or encoding while they run.
//
// Layout: <dir>/<frame index, 6 digits>.jpg for every frame whose index is a
// multiple of `every`; dir defaults to <dataset>/jpeg_q<quality>. Entries are
// written atomically (temporary file, then rename); an entry that is not a
// whole JPEG (no SOI/EOI marker, e.g. a crash while writing by hand) is encoded
// again from the dataset's image.
#pragma once

#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "ecar_core/common/geometry.h"
#include "ecar_core/io/dataset.h"

namespace ecar {

/// One upload: the frame's JPEG (grayscale) and what is uploaded with it.
struct CachedUpload {
  size_t index = 0;        ///< the frame's index in the dataset
  double timestamp = 0.0;  ///< the dataset's stamp, seconds
  std::vector<uint8_t> jpeg;
  std::optional<SE3> T_o_c;                  ///< odometry, when the dataset has it
  std::optional<Eigen::Vector3d> gravity_c;  ///< accelerometer at rest, camera frame
};

struct UploadCacheConfig {
  int every = 4;          ///< frames 0, every, 2 every, ... (>= 1)
  int jpeg_quality = 70;  ///< 1..100
  size_t max_frames = 0;  ///< frames of the dataset considered (0 = all)
  std::string dir;        ///< "" = <dataset>/jpeg_q<jpeg_quality>
};

class UploadCache {
 public:
  /// Encodes the missing or damaged entries from the dataset's images, then
  /// holds every entry in memory. Throws ecar::Error naming the folder or file
  /// (bad config, unwritable folder, unreadable image).
  static UploadCache build(const Dataset& dataset, const UploadCacheConfig& config);

  const std::vector<CachedUpload>& uploads() const { return uploads_; }
  const std::string& dir() const { return dir_; }
  size_t bytes() const { return bytes_; }
  /// Entries this build() encoded (0 when the cache was complete).
  size_t encoded() const { return encoded_; }

  /// Whether `bytes` hold a whole JPEG (SOI at the start, EOI at the end).
  static bool wholeJpeg(const std::vector<uint8_t>& bytes);

 private:
  std::vector<CachedUpload> uploads_;
  std::string dir_;
  size_t bytes_ = 0;
  size_t encoded_ = 0;
};

}  // namespace ecar
