// The format loaders of the dataset reader: sim, TUM, KITTI and EuRoC (see
// dataset_formats.h; the layouts are described in dataset.h).
#include "ecar_core/io/dataset_formats.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <fstream>
#include <optional>
#include <regex>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include <yaml-cpp/yaml.h>
#include <Eigen/Geometry>
#include <opencv2/imgcodecs.hpp>

#include "ecar_core/common/error.h"
#include "ecar_core/common/geometry.h"
#include "ecar_core/io/trajectory.h"

namespace ecar::dataset_internal {

// ---------------------------------------------------------------------------
// sim: our DatasetWriter's output.

namespace {

// Sim files write every stamp with 6 decimals: records of one frame share it.
constexpr double kSameStamp = 5e-7;

// Index of the frame whose stamp is `t` (stamps sorted), if any.
std::optional<size_t> frameAtStamp(const std::vector<double>& stamps, double t) {
  const auto it = std::lower_bound(stamps.begin(), stamps.end(), t - kSameStamp);
  if (it == stamps.end() || std::abs(*it - t) > kSameStamp) return std::nullopt;
  return static_cast<size_t>(it - stamps.begin());
}

// Calls parse(line, frame index) for each line of `file`; a line whose stamp
// matches no frame is an error.
template <typename Parse>
void attachByStamp(const fs::path& file, const std::vector<double>& stamps, Parse parse) {
  for (const TextLine& line : readTextLines(file, false)) {
    const double t = parseNumber(line.fields[0], file, line.number, "timestamp");
    const auto i = frameAtStamp(stamps, t);
    if (!i) {
      throw Error(at(file, line.number) + ": timestamp " + line.fields[0] +
                  " matches no frame of rgb.txt");
    }
    parse(line, *i);
  }
}

}  // namespace

Contents loadSim(const fs::path& dir, bool need_camera) {
  Contents c;
  if (need_camera) c.camera = loadCameraOrThrow(dir / "camera.yaml");
  readImageList(dir, dir / "rgb.txt", &c);
  const std::vector<double> stamps = frameStamps(c);

  const fs::path gt_file = dir / "groundtruth.txt";
  if (!isFile(gt_file)) throw Error(gt_file.string() + ": file is missing (sim format)");
  attachGroundTruth(readTum(gt_file.string()), kSameStamp, &c);
  for (size_t i = 0; i < c.frames.size(); ++i) {
    if (!c.frames[i].T_w_c_gt) {
      throw Error(gt_file.string() + ": no pose at the stamp of frame " + std::to_string(i) + " (" +
                  c.sources[i] + ")");
    }
  }

  const fs::path odom_file = dir / "odometry.txt";
  if (isFile(odom_file)) {
    // readTum does the parsing (and its errors); the poses are T_o_c here.
    for (const StampedPose& p : readTum(odom_file.string())) {
      const auto i = frameAtStamp(stamps, p.timestamp);
      if (!i) {
        throw Error(odom_file.string() + ": pose at timestamp " + std::to_string(p.timestamp) +
                    " matches no frame of rgb.txt");
      }
      c.frames[*i].T_o_c_odom = p.T_w_c;
    }
  }

  const fs::path gravity_file = dir / "gravity.txt";
  if (isFile(gravity_file)) {
    attachByStamp(gravity_file, stamps, [&](const TextLine& line, size_t i) {
      expectFields(line, 4, gravity_file, "timestamp gx gy gz");
      c.frames[i].gravity_c = parseVector3(line, 1, gravity_file, "gravity");
    });
  }

  const fs::path imu_file = dir / "imu.txt";
  if (isFile(imu_file)) {
    for (const TextLine& line : readTextLines(imu_file, false)) {
      expectFields(line, 7, imu_file, "timestamp ax ay az wx wy wz");
      ImuSample s;
      s.timestamp = parseNumber(line.fields[0], imu_file, line.number, "timestamp");
      s.acc_c = parseVector3(line, 1, imu_file, "acceleration");
      s.gyro_c = parseVector3(line, 4, imu_file, "angular rate");
      if (!c.imu.empty() && !(s.timestamp > c.imu.back().timestamp)) {
        throw Error(at(imu_file, line.number) + ": timestamp is not after the previous line's");
      }
      c.imu.push_back(s);
    }
  }
  return c;
}

// ---------------------------------------------------------------------------
// tum: TUM RGB-D benchmark folders.

namespace {

// Published calibration of the TUM RGB-D color cameras (vision.in.tum.de,
// "file formats" page). fr3 images are already undistorted.
std::optional<CameraParams> tumCameraFromName(const std::string& folder_name) {
  std::string name = folder_name;
  std::transform(name.begin(), name.end(), name.begin(),
                 [](unsigned char ch) { return static_cast<char>(std::tolower(ch)); });
  static const std::regex kPattern("(freiburg|fr)([123])(?![0-9])");
  std::set<char> ids;
  for (auto it = std::sregex_iterator(name.begin(), name.end(), kPattern);
       it != std::sregex_iterator(); ++it) {
    ids.insert((*it)[2].str()[0]);
  }
  if (ids.size() != 1) return std::nullopt;
  CameraParams p;
  p.width = 640;
  p.height = 480;
  p.fps = 30.0;
  switch (*ids.begin()) {
    case '1':
      p.fx = 517.3, p.fy = 516.5, p.cx = 318.6, p.cy = 255.3;
      p.dist = {0.2624, -0.9531, -0.0054, 0.0026, 1.1633};
      break;
    case '2':
      p.fx = 520.9, p.fy = 521.0, p.cx = 325.1, p.cy = 249.7;
      p.dist = {0.2312, -0.7849, -0.0033, -0.0001, 0.9172};
      break;
    default:
      p.fx = 535.4, p.fy = 539.2, p.cx = 320.1, p.cy = 247.6;
      p.dist = {0, 0, 0, 0, 0};
      break;
  }
  return p;
}

}  // namespace

Contents loadTum(const fs::path& dir, bool need_camera) {
  Contents c;
  const fs::path list = dir / "rgb.txt";
  if (!isFile(list)) throw Error(list.string() + ": file is missing (TUM list of images)");
  if (need_camera) {
    const auto params = tumCameraFromName(dir.filename().string());
    if (!params) {
      throw Error(dir.string() +
                  ": TUM folder without camera.yaml, and its name does not say fr1, fr2 or fr3 "
                  "(freiburg1/2/3): pass a camera file (camera_yaml_override) with the "
                  "intrinsics");
    }
    c.camera = PinholeCamera(*params);
  }
  readImageList(dir, list, &c);
  const fs::path gt_file = dir / "groundtruth.txt";
  if (isFile(gt_file)) attachGroundTruth(readTum(gt_file.string()), 0.02, &c);
  return c;
}

// ---------------------------------------------------------------------------
// kitti: KITTI odometry sequences (left gray camera, image_0).

namespace {

CameraParams readKittiCalib(const fs::path& calib) {
  for (const TextLine& line : readTextLines(calib, false)) {
    if (line.fields[0] != "P0:") continue;
    expectFields(line, 13, calib, "P0: followed by the 12 values of the 3x4 projection matrix");
    double P[12];
    for (int k = 0; k < 12; ++k) P[k] = parseNumber(line.fields[1 + k], calib, line.number, "P0");
    CameraParams p;
    p.fx = P[0];
    p.cx = P[2];
    p.fy = P[5];
    p.cy = P[6];
    p.fps = 10.0;  // KITTI cameras run at 10 Hz
    return p;
  }
  throw Error(calib.string() + ": no 'P0:' line (projection matrix of the left gray camera)");
}

void readKittiPoses(const fs::path& file, Contents* c) {
  const std::vector<TextLine> lines = readTextLines(file, false);
  if (lines.size() != c->frames.size()) {
    throw Error(file.string() + ": " + std::to_string(lines.size()) + " poses for " +
                std::to_string(c->frames.size()) + " frames (KITTI poses are one per image)");
  }
  for (size_t i = 0; i < lines.size(); ++i) {
    const TextLine& line = lines[i];
    expectFields(line, 12, file, "3x4 matrix T_w_c, row-major");
    Eigen::Matrix<double, 3, 4> M;
    for (int k = 0; k < 12; ++k) {
      M(k / 4, k % 4) = parseNumber(line.fields[k], file, line.number, "pose value");
    }
    SE3 T = SE3::Identity();
    T.linear() = orthonormalize(M.leftCols<3>(), at(file, line.number));
    T.translation() = M.col(3);
    c->frames[i].T_w_c_gt = T;
  }
}

}  // namespace

Contents loadKitti(const fs::path& dir, bool need_camera) {
  Contents c;
  const fs::path calib = dir / "calib.txt";
  if (!isFile(calib)) throw Error(calib.string() + ": file is missing (KITTI calibration)");
  CameraParams params = readKittiCalib(calib);

  const fs::path rgb_list = dir / "rgb.txt";
  const fs::path times = dir / "times.txt";
  if (isFile(rgb_list)) {
    readImageList(dir, rgb_list, &c);
  } else if (isFile(times)) {
    for (const TextLine& line : readTextLines(times, false)) {
      expectFields(line, 1, times, "timestamp");
      const double t = parseNumber(line.fields[0], times, line.number, "timestamp");
      char name[32];
      std::snprintf(name, sizeof(name), "%06zu.png", c.frames.size());
      addFrame(&c, times, line.number, t, dir / "image_0" / name);
    }
    requireFrames(c, times);
  } else {
    throw Error(dir.string() + ": KITTI folder has neither rgb.txt nor times.txt");
  }

  if (need_camera) {
    // calib.txt has no image size: take it from the first image.
    const std::string& first = c.frames.front().image_path;
    cv::Mat image;
    try {
      image = cv::imread(first, cv::IMREAD_UNCHANGED);
    } catch (const cv::Exception& e) {
      throw Error(first + ": cannot read image (" + e.what() + ")");
    }
    if (image.empty()) throw Error(first + ": cannot read image (corrupt or not an image)");
    params.width = image.cols;
    params.height = image.rows;
    try {
      c.camera = PinholeCamera(params);
    } catch (const Error& e) {
      throw Error(calib.string() + ": " + e.what());
    }
  }

  const fs::path gt_file = dir / "groundtruth.txt";
  const fs::path poses_file = dir / "poses.txt";
  if (isFile(gt_file)) {
    attachGroundTruth(readTum(gt_file.string()), 0.02, &c);
  } else if (isFile(poses_file)) {
    readKittiPoses(poses_file, &c);
  }
  return c;
}

// ---------------------------------------------------------------------------
// euroc: EuRoC MAV (ASL folder layout).

namespace {

// Reads a sensor.yaml written by OpenCV (first line `%YAML:1.0`, which yaml-cpp
// does not accept).
YAML::Node loadOpenCvYaml(const fs::path& path) {
  if (!isFile(path)) throw Error(path.string() + ": file is missing");
  std::ifstream in(path);
  if (!in) throw Error(path.string() + ": cannot open file");
  std::stringstream ss;
  ss << in.rdbuf();
  std::string text = ss.str();
  if (text.rfind("%YAML:", 0) == 0) text.erase(0, text.find('\n'));
  try {
    YAML::Node root = YAML::Load(text);
    if (!root.IsMap()) throw Error(path.string() + ": expected a YAML map");
    return root;
  } catch (const YAML::Exception& e) {
    throw Error(path.string() + ": not valid YAML (" + e.msg + ")");
  }
}

template <typename T>
T yamlKey(const YAML::Node& root, const std::string& key, const fs::path& path) {
  if (!root[key]) throw Error(path.string() + ": missing key '" + key + "'");
  try {
    return root[key].as<T>();
  } catch (const YAML::Exception& e) {
    throw Error(path.string() + ": key '" + key + "' has an invalid value (" + e.msg + ")");
  }
}

std::vector<double> yamlNumbers(const YAML::Node& root, const std::string& key,
                                const fs::path& path, size_t min_count, size_t max_count) {
  const auto v = yamlKey<std::vector<double>>(root, key, path);
  if (v.size() < min_count || v.size() > max_count) {
    throw Error(path.string() + ": key '" + key + "' has " + std::to_string(v.size()) +
                " values, expected " + std::to_string(min_count) +
                (max_count != min_count ? " to " + std::to_string(max_count) : ""));
  }
  for (double x : v) {
    if (!std::isfinite(x)) throw Error(path.string() + ": key '" + key + "' is not finite");
  }
  return v;
}

struct EurocSensor {
  CameraParams params;
  SE3 T_b_c = SE3::Identity();  // T_BS: camera (sensor) pose in the body frame
};

EurocSensor readEurocSensor(const fs::path& path) {
  const YAML::Node root = loadOpenCvYaml(path);
  EurocSensor s;
  if (root["camera_model"] && yamlKey<std::string>(root, "camera_model", path) != "pinhole") {
    throw Error(path.string() + ": key 'camera_model' must be 'pinhole'");
  }
  if (root["distortion_model"]) {
    const auto model = yamlKey<std::string>(root, "distortion_model", path);
    if (model != "radial-tangential" && model != "radtan") {
      throw Error(path.string() + ": key 'distortion_model' is '" + model +
                  "', only radial-tangential is supported");
    }
  }
  const auto intr = yamlNumbers(root, "intrinsics", path, 4, 4);
  const auto res = yamlNumbers(root, "resolution", path, 2, 2);
  const auto dist = yamlNumbers(root, "distortion_coefficients", path, 4, 5);
  s.params.fx = intr[0];
  s.params.fy = intr[1];
  s.params.cx = intr[2];
  s.params.cy = intr[3];
  for (double r : res) {
    if (!(r >= 1 && r <= 100000) || r != std::floor(r)) {
      throw Error(path.string() + ": key 'resolution' must be two positive whole numbers");
    }
  }
  s.params.width = static_cast<int>(res[0]);
  s.params.height = static_cast<int>(res[1]);
  s.params.dist = {0, 0, 0, 0, 0};
  std::copy(dist.begin(), dist.end(), s.params.dist.begin());
  if (root["rate_hz"]) s.params.fps = yamlKey<double>(root, "rate_hz", path);

  if (!root["T_BS"] || !root["T_BS"].IsMap()) {
    throw Error(path.string() + ": missing key 'T_BS' (map with rows, cols, data)");
  }
  const auto data = yamlNumbers(root["T_BS"], "data", path, 16, 16);
  Eigen::Matrix4d M;
  for (int k = 0; k < 16; ++k) M(k / 4, k % 4) = data[k];
  s.T_b_c.linear() = orthonormalize(M.topLeftCorner<3, 3>(), path.string() + ": key 'T_BS'");
  s.T_b_c.translation() = M.topRightCorner<3, 1>();
  return s;
}

}  // namespace

Contents loadEuroc(const fs::path& dir, bool need_camera) {
  const fs::path root = isFile(dir / "cam0" / "data.csv") ? dir : dir / "mav0";
  const fs::path cam_dir = root / "cam0";
  const fs::path list = cam_dir / "data.csv";
  if (!isFile(list)) {
    throw Error(dir.string() + ": EuRoC folder has neither cam0/data.csv nor mav0/cam0/data.csv");
  }
  const EurocSensor sensor = readEurocSensor(cam_dir / "sensor.yaml");
  Contents c;
  if (need_camera) {
    try {
      c.camera = PinholeCamera(sensor.params);
    } catch (const Error& e) {
      throw Error((cam_dir / "sensor.yaml").string() + ": " + e.what());
    }
  }

  std::vector<int64_t> frame_ns;
  for (const TextLine& line : readTextLines(list, true)) {
    expectFields(line, 2, list, "timestamp [ns],filename");
    const int64_t ns = parseNanoseconds(line.fields[0], list, line.number);
    addFrame(&c, list, line.number, nsToSeconds(ns), cam_dir / "data" / line.fields[1]);
    frame_ns.push_back(ns);
  }
  requireFrames(c, list);

  const Eigen::Matrix3d R_c_b = sensor.T_b_c.linear().transpose();
  const fs::path imu_file = root / "imu0" / "data.csv";
  std::vector<int64_t> imu_ns;
  if (isFile(imu_file)) {
    for (const TextLine& line : readTextLines(imu_file, true)) {
      expectFields(line, 7, imu_file, "timestamp [ns],wx,wy,wz,ax,ay,az");
      const int64_t ns = parseNanoseconds(line.fields[0], imu_file, line.number);
      if (!imu_ns.empty() && ns <= imu_ns.back()) {
        throw Error(at(imu_file, line.number) + ": timestamp is not after the previous line's");
      }
      ImuSample s;
      s.timestamp = nsToSeconds(ns);
      // Rotating the specific force ignores the lever arm between IMU and
      // camera (its centripetal and tangential terms are small at walking speed).
      s.gyro_c = R_c_b * parseVector3(line, 1, imu_file, "angular rate");
      s.acc_c = R_c_b * parseVector3(line, 4, imu_file, "acceleration");
      c.imu.push_back(s);
      imu_ns.push_back(ns);
    }
    constexpr int64_t kGravityWindowNs = 25000000;  // +-25 ms around the image
    for (size_t i = 0; i < c.frames.size(); ++i) {
      auto it = std::lower_bound(imu_ns.begin(), imu_ns.end(), frame_ns[i] - kGravityWindowNs);
      Eigen::Vector3d sum = Eigen::Vector3d::Zero();
      int count = 0;
      for (; it != imu_ns.end() && *it <= frame_ns[i] + kGravityWindowNs; ++it, ++count) {
        sum += c.imu[it - imu_ns.begin()].acc_c;
      }
      if (count > 0) c.frames[i].gravity_c = sum / count;
    }
  }

  const fs::path gt_file = root / "state_groundtruth_estimate0" / "data.csv";
  if (isFile(gt_file)) {
    std::vector<int64_t> gt_ns;
    std::vector<SE3> T_w_b;
    for (const TextLine& line : readTextLines(gt_file, true)) {
      expectAtLeastFields(line, 8, gt_file, "timestamp [ns],px,py,pz,qw,qx,qy,qz,...");
      const int64_t ns = parseNanoseconds(line.fields[0], gt_file, line.number);
      if (!gt_ns.empty() && ns <= gt_ns.back()) {
        throw Error(at(gt_file, line.number) + ": timestamp is not after the previous line's");
      }
      const Eigen::Vector3d p = parseVector3(line, 1, gt_file, "position");
      const double qw = parseNumber(line.fields[4], gt_file, line.number, "qw");
      const Eigen::Vector3d qv = parseVector3(line, 5, gt_file, "quaternion");
      const Eigen::Quaterniond q(qw, qv.x(), qv.y(), qv.z());
      if (q.norm() < 1e-6) throw Error(at(gt_file, line.number) + ": zero quaternion");
      gt_ns.push_back(ns);
      T_w_b.push_back(makeSE3(q, p));
    }
    // The estimate runs at 200 Hz: interpolate between the two samples around
    // each image when they are at most 50 ms apart.
    constexpr int64_t kMaxGapNs = 50000000;
    for (size_t i = 0; i < c.frames.size(); ++i) {
      const auto it = std::lower_bound(gt_ns.begin(), gt_ns.end(), frame_ns[i]);
      if (it == gt_ns.end()) continue;
      const size_t j = it - gt_ns.begin();
      SE3 T;
      if (*it == frame_ns[i]) {
        T = T_w_b[j];
      } else if (j > 0 && gt_ns[j] - gt_ns[j - 1] <= kMaxGapNs) {
        const double alpha = static_cast<double>(frame_ns[i] - gt_ns[j - 1]) /
                             static_cast<double>(gt_ns[j] - gt_ns[j - 1]);
        T = interpolate(T_w_b[j - 1], T_w_b[j], alpha);
      } else {
        continue;
      }
      c.frames[i].T_w_c_gt = T * sensor.T_b_c;
    }
  }
  return c;
}

}  // namespace ecar::dataset_internal
