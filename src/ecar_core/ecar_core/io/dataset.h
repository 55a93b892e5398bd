// One reader for the image sequences eCAR runs on: our simulator's output, TUM
// RGB-D, KITTI odometry and EuRoC MAV folders.
//
// Every format is turned into the same thing: a PinholeCamera, a list of
// frames (timestamp in seconds, absolute image path, optional ground-truth
// pose T_w_c, optional gravity direction and odometry), and an IMU stream in
// the camera optical frame (x right, y down, z forward).
//
// Layouts (dir is the folder passed to Dataset::open):
//
//   sim    dir/camera.yaml     PinholeCamera::loadYaml format
//          dir/rgb.txt         `timestamp rgb/<file>.png` (TUM style)
//          dir/groundtruth.txt TUM, one pose per frame at the frame's stamp
//          dir/imu.txt         optional; `timestamp ax ay az wx wy wz`, camera frame
//          dir/gravity.txt     optional; `timestamp gx gy gz`, accelerometer at
//                              rest in the camera frame (m/s^2, points up)
//          dir/odometry.txt    optional; TUM, T_o_c at frame stamps
//          dir/touches.txt     optional (read for any format); scripted touches,
//                              `timestamp frame_index u v phase r g b width`:
//                              the frame's stamp, its 0-based index in the
//                              frame list, the pixel (inside the image),
//                              begin|move|end, colour 0-255, width in metres
//                              (> 0); lines in frame order, phases forming
//                              whole strokes (begin, move..., end)
//          (written by DatasetWriter, see dataset_writer.h)
//   tum    dir/rgb.txt + dir/rgb/, no camera.yaml. Intrinsics: the override
//          file, else the published fr1/fr2/fr3 calibration when the folder
//          name says "fr1"/"freiburg1" etc. dir/groundtruth.txt is optional and
//          associated to frames by nearest stamp within 20 ms.
//   kitti  dir/image_0/ + dir/calib.txt (P0: fx fy cx cy; size from the first
//          image) + dir/rgb.txt (`timestamp image_0/NNNNNN.png`) or
//          dir/times.txt (one stamp per line, image_0/%06d.png). Ground truth:
//          optional dir/groundtruth.txt (TUM, within 20 ms) or dir/poses.txt
//          (KITTI: 12 numbers per line, row-major 3x4 T_w_c, one per frame).
//   euroc  dir/cam0/ or dir/mav0/cam0/: data.csv (`t_ns,filename`, images in
//          cam0/data/) and sensor.yaml (intrinsics, radial-tangential
//          distortion, resolution, rate_hz, T_BS = camera pose in the body
//          frame). Optional imu0/data.csv (`t_ns,wx,wy,wz,ax,ay,az`, body frame)
//          and state_groundtruth_estimate0/data.csv (`t_ns,px,py,pz,qw,qx,qy,qz,
//          ...`, body pose in the world; interpolated to the image stamps,
//          T_w_c = T_w_b * T_BS).
//
// Errors (missing folder or file, malformed line, non-finite number, listed
// image that does not exist, empty dataset, unreadable or mis-sized image)
// are ecar::Error exceptions naming the file and, where there is one, the line.
#pragma once

#include <cstddef>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "ecar_core/common/camera.h"
#include "ecar_core/common/geometry.h"
#include "ecar_core/common/touch.h"
#include "ecar_core/io/trajectory.h"

namespace ecar {

enum class DatasetFormat { kAuto, kSim, kTum, kKitti, kEuroc };

/// "auto", "sim", "tum", "kitti" or "euroc" (lower case). Throws ecar::Error
/// listing the accepted names otherwise.
DatasetFormat parseDatasetFormat(const std::string& name);
/// The inverse of parseDatasetFormat.
std::string toString(DatasetFormat format);

/// One inertial measurement, expressed in the camera optical frame.
struct ImuSample {
  double timestamp = 0.0;  ///< seconds
  /// Specific force in m/s^2: reads +g pointing up when at rest.
  Eigen::Vector3d acc_c = Eigen::Vector3d::Zero();
  /// Angular rate in rad/s.
  Eigen::Vector3d gyro_c = Eigen::Vector3d::Zero();
};

struct DatasetFrame {
  double timestamp = 0.0;  ///< seconds
  std::string image_path;  ///< absolute
  /// Ground-truth camera pose in the world, when the dataset has one for this frame.
  std::optional<SE3> T_w_c_gt;
  /// Accelerometer reading at rest in the camera frame (m/s^2, points up):
  /// EuRoC: mean of the accelerometer within +-25 ms of the image; sim: gravity.txt.
  std::optional<Eigen::Vector3d> gravity_c;
  /// Camera pose in an odometry frame (sim only).
  std::optional<SE3> T_o_c_odom;
};

/// An opened dataset: everything but the images is read and validated by open().
/// Immutable afterwards; const methods are safe to call from several threads.
class Dataset {
 public:
  /// Opens `dir`. kAuto detects the format (euroc, kitti, sim, tum in that
  /// order of checks). A non-empty `camera_yaml_override` (PinholeCamera::loadYaml
  /// format) replaces the intrinsics of any format. Throws ecar::Error.
  static Dataset open(const std::string& dir, DatasetFormat format = DatasetFormat::kAuto,
                      const std::string& camera_yaml_override = "");

  /// Which format open() would pick for `dir`; throws ecar::Error when none fits.
  static DatasetFormat detectFormat(const std::string& dir);

  const std::string& dir() const { return dir_; }
  DatasetFormat format() const { return format_; }
  const PinholeCamera& camera() const { return camera_; }

  size_t size() const { return frames_.size(); }
  /// Throws ecar::Error when i >= size().
  const DatasetFrame& frame(size_t i) const;
  const std::vector<DatasetFrame>& frames() const { return frames_; }

  /// Reads frame i's image with cv::imread. Throws ecar::Error naming the file
  /// when it is missing, corrupt or empty, or when its size differs from the camera's.
  cv::Mat loadImage(size_t i, int imread_flags = cv::IMREAD_UNCHANGED) const;

  /// IMU samples in time order (empty when the dataset has none).
  const std::vector<ImuSample>& imu() const { return imu_; }

  /// The scripted touches of dir/touches.txt in frame order (empty when the
  /// file is absent); each event's frame indexes frames().
  const std::vector<TouchEvent>& touches() const { return touches_; }

  /// True when at least one frame has a ground-truth pose.
  bool hasGroundTruth() const;
  /// The ground-truth poses of the frames that have one, in frame order.
  Trajectory groundTruth() const;

 private:
  Dataset() = default;

  std::string dir_;
  DatasetFormat format_ = DatasetFormat::kAuto;
  PinholeCamera camera_;
  std::vector<DatasetFrame> frames_;
  std::vector<std::string> sources_;  ///< "<list file>:<line>" of each frame, for errors
  std::vector<ImuSample> imu_;
  std::vector<TouchEvent> touches_;
};

}  // namespace ecar
