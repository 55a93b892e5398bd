// Writes a sequence (typically from the simulator) as a "sim" dataset folder
// that Dataset::open reads back (auto-detected by camera.yaml + rgb.txt).
//
// Layout of dir/ (all text files TUM-style: '#' comment lines, then one record
// per line, fields separated by spaces; timestamps in seconds):
//
//   camera.yaml      PinholeCamera::saveYaml (written by finish())
//   rgb/<t>.png      one image per frame, <t> = timestamp with 6 decimals
//   rgb.txt          `timestamp rgb/<t>.png`
//   groundtruth.txt  `timestamp tx ty tz qx qy qz qw`: T_w_c of every frame,
//                    at the frame's stamp
//   imu.txt          `timestamp ax ay az wx wy wz`: camera optical frame
//                    (x right, y down, z forward), specific force in m/s^2
//                    (reads +g up at rest) and angular rate in rad/s
//   gravity.txt      `timestamp gx gy gz`: accelerometer at rest in the camera
//                    frame (m/s^2, points up); only frames given one
//   odometry.txt     `timestamp tx ty tz qx qy qz qw`: T_o_c, only frames given one
//   touches.txt      `timestamp frame_index u v phase r g b width`: scripted
//                    touches (see dataset.h), phase begin|move|end
//
// rgb.txt, groundtruth.txt and imu.txt always exist (possibly with no records);
// gravity.txt, odometry.txt and touches.txt only when some frame had the value. Poses and IMU
// values are written with 17 significant digits, so they read back exactly.
#pragma once

#include <fstream>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "ecar_core/common/camera.h"
#include "ecar_core/common/geometry.h"
#include "ecar_core/common/touch.h"
#include "ecar_core/io/dataset.h"

namespace ecar {

/// Not thread-safe: call from one thread.
class DatasetWriter {
 public:
  /// Creates `dir` (and dir/rgb) if needed and starts the list files,
  /// replacing those of an earlier run. Throws ecar::Error when it cannot.
  DatasetWriter(const std::string& dir, const PinholeCamera& camera);
  /// Finishes if finish() was not called; errors are swallowed here, so call
  /// finish() to see them.
  ~DatasetWriter();

  DatasetWriter(const DatasetWriter&) = delete;
  DatasetWriter& operator=(const DatasetWriter&) = delete;

  /// Writes rgb/<timestamp>.png and the frame's records. Throws ecar::Error
  /// when the image is empty or not the camera's size, a value is not finite,
  /// the timestamp is not after the previous frame's (at microsecond
  /// resolution), a file cannot be written, or after finish().
  void addFrame(double timestamp, const cv::Mat& image, const SE3& T_w_c_gt,
                const std::optional<Eigen::Vector3d>& gravity_c = std::nullopt,
                const std::optional<SE3>& T_o_c_odom = std::nullopt);

  /// Appends to imu.txt. Stamps must increase (at nanosecond resolution).
  void addImu(const ImuSample& sample);

  /// Appends to touches.txt a touch on an already added frame; the line
  /// carries that frame's stamp. Throws ecar::Error when touch.frame is not an
  /// added frame or is before the previous touch's, touch.timestamp is not
  /// that frame's stamp (to 1 us), the pixel is outside the image or not
  /// finite, width is not > 0, or the phase breaks the begin, move..., end
  /// pattern (finish() also fails when the last stroke has no end).
  void addTouch(const TouchEvent& touch);

  /// Writes camera.yaml and closes the files. Further calls do nothing.
  void finish();

  const std::string& dir() const { return dir_; }
  size_t frameCount() const { return frame_count_; }
  size_t touchCount() const { return touch_count_; }

 private:
  void checkOpen() const;
  std::ofstream& openLazily(std::ofstream& stream, const std::string& name,
                            const std::string& header);

  std::string dir_;
  PinholeCamera camera_;
  std::ofstream rgb_;
  std::ofstream groundtruth_;
  std::ofstream imu_;
  std::ofstream gravity_;   // opened on the first frame with gravity
  std::ofstream odometry_;  // opened on the first frame with odometry
  std::ofstream touches_;   // opened on the first touch
  /// Stamp of every added frame: microseconds and its rgb.txt text.
  std::vector<std::pair<long long, std::string>> frame_stamps_;
  std::optional<TouchEvent> last_touch_;
  long long last_frame_us_ = 0;
  long long last_imu_ns_ = 0;
  size_t frame_count_ = 0;
  size_t imu_count_ = 0;
  size_t touch_count_ = 0;
  bool finished_ = false;
};

}  // namespace ecar
