#include "ecar_core/io/dataset.h"

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <regex>
#include <set>
#include <sstream>
#include <utility>

#include <yaml-cpp/yaml.h>
#include <Eigen/Geometry>
#include <Eigen/SVD>
#include <opencv2/imgcodecs.hpp>

#include "ecar_core/common/error.h"
#include "ecar_core/common/text.h"

namespace ecar {

namespace fs = std::filesystem;

namespace {

// ---------------------------------------------------------------------------
// Text parsing helpers. Every error names "<file>:<line>".

// One data line of a text file: its 1-based number and its fields.
struct TextLine {
  int number = 0;
  std::vector<std::string> fields;
};

std::string at(const fs::path& file, int line) {
  return file.string() + ":" + std::to_string(line);
}

std::string trim(const std::string& s) {
  const size_t b = s.find_first_not_of(" \t");
  if (b == std::string::npos) return "";
  const size_t e = s.find_last_not_of(" \t");
  return s.substr(b, e - b + 1);
}

bool isFile(const fs::path& p) {
  std::error_code ec;
  return fs::is_regular_file(p, ec);
}

bool isDirectory(const fs::path& p) {
  std::error_code ec;
  return fs::is_directory(p, ec);
}

// Reads a text file, skipping blank lines and '#' comments. Fields are split on
// whitespace, or on commas (each trimmed) when `csv` is true.
std::vector<TextLine> readTextLines(const fs::path& file, bool csv) {
  if (!isFile(file)) throw Error(file.string() + ": file is missing");
  std::ifstream in(file);
  if (!in) throw Error(file.string() + ": cannot open file");
  std::vector<TextLine> lines;
  std::string text;
  int number = 0;
  while (std::getline(in, text)) {
    ++number;
    if (!text.empty() && text.back() == '\r') text.pop_back();
    const std::string content = trim(text);
    if (content.empty() || content[0] == '#') continue;
    TextLine line;
    line.number = number;
    if (csv) {
      std::stringstream ss(content);
      std::string field;
      while (std::getline(ss, field, ',')) line.fields.push_back(trim(field));
    } else {
      std::istringstream ss(content);
      std::string field;
      while (ss >> field) line.fields.push_back(field);
    }
    lines.push_back(std::move(line));
  }
  if (in.bad()) throw Error(file.string() + ": read error");
  return lines;
}

void expectFields(const TextLine& line, size_t count, const fs::path& file,
                  const std::string& layout) {
  if (line.fields.size() != count) {
    throw Error(at(file, line.number) + ": expected " + std::to_string(count) + " fields (" +
                layout + "), found " + std::to_string(line.fields.size()));
  }
}

void expectAtLeastFields(const TextLine& line, size_t count, const fs::path& file,
                         const std::string& layout) {
  if (line.fields.size() < count) {
    throw Error(at(file, line.number) + ": expected at least " + std::to_string(count) +
                " fields (" + layout + "), found " + std::to_string(line.fields.size()));
  }
}

// Parses the whole of `s` as a finite double, independently of the C locale.
double parseNumber(const std::string& s, const fs::path& file, int line, const std::string& what) {
  double v = 0.0;
  if (!parseDouble(s, &v)) {
    throw Error(at(file, line) + ": " + what + " '" + s + "' is not a number");
  }
  if (!std::isfinite(v)) {
    throw Error(at(file, line) + ": " + what + " '" + s + "' is not finite");
  }
  return v;
}

Eigen::Vector3d parseVector3(const TextLine& line, size_t first, const fs::path& file,
                             const std::string& what) {
  Eigen::Vector3d v;
  for (int k = 0; k < 3; ++k) {
    v[k] = parseNumber(line.fields[first + k], file, line.number, what);
  }
  return v;
}

int64_t parseNanoseconds(const std::string& s, const fs::path& file, int line) {
  int64_t v = 0;
  const char* end = s.data() + s.size();
  const auto [ptr, ec] = std::from_chars(s.data(), end, v);
  if (s.empty() || ec != std::errc() || ptr != end || v < 0) {
    throw Error(at(file, line) + ": timestamp '" + s +
                "' is not a non-negative integer number of nanoseconds");
  }
  return v;
}

double nsToSeconds(int64_t ns) {
  return static_cast<double>(ns / 1000000000) + static_cast<double>(ns % 1000000000) * 1e-9;
}

// Nearest rotation (in the Frobenius sense) to a 3x3 matrix that should be one.
// Throws when it is far from a rotation.
Eigen::Matrix3d orthonormalize(const Eigen::Matrix3d& M, const std::string& where) {
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(M, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d R = svd.matrixU() * svd.matrixV().transpose();
  if (R.determinant() < 0 || (R - M).norm() > 1e-3) {
    throw Error(where + ": rotation part is not a rotation matrix");
  }
  return R;
}

// ---------------------------------------------------------------------------
// What a format loader produces.

struct Contents {
  std::optional<PinholeCamera> camera;
  std::vector<DatasetFrame> frames;
  std::vector<std::string> sources;  // "<list file>:<line>" of each frame
  std::vector<ImuSample> imu;
};

void addFrame(Contents* c, const fs::path& list, int line, double timestamp,
              const fs::path& image) {
  if (!c->frames.empty() && !(timestamp > c->frames.back().timestamp)) {
    throw Error(at(list, line) + ": timestamp " + std::to_string(timestamp) +
                " is not after the previous frame's (" + c->sources.back() + ")");
  }
  if (!isFile(image)) {
    throw Error(at(list, line) + ": listed image " + image.string() + " does not exist");
  }
  DatasetFrame f;
  f.timestamp = timestamp;
  f.image_path = image.string();
  c->frames.push_back(std::move(f));
  c->sources.push_back(at(list, line));
}

void requireFrames(const Contents& c, const fs::path& list) {
  if (c.frames.empty()) throw Error(list.string() + ": empty dataset (no frames listed)");
}

// `timestamp filename` lists (TUM rgb.txt, our sim rgb.txt, KITTI rgb.txt);
// filenames are relative to `dir`.
void readImageList(const fs::path& dir, const fs::path& list, Contents* c) {
  for (const TextLine& line : readTextLines(list, false)) {
    expectFields(line, 2, list, "timestamp filename");
    const double t = parseNumber(line.fields[0], list, line.number, "timestamp");
    addFrame(c, list, line.number, t, (dir / line.fields[1]).lexically_normal());
  }
  requireFrames(*c, list);
}

std::vector<double> frameStamps(const Contents& c) {
  std::vector<double> stamps;
  stamps.reserve(c.frames.size());
  for (const DatasetFrame& f : c.frames) stamps.push_back(f.timestamp);
  return stamps;
}

// Gives each frame the pose of `traj` nearest in time within max_dt (each pose
// used once, as TUM's associate.py does).
void attachGroundTruth(const Trajectory& traj, double max_dt, Contents* c) {
  for (const auto& [i, j] : associate(frameStamps(*c), timestamps(traj), max_dt)) {
    c->frames[i].T_w_c_gt = traj[j].T_w_c;
  }
}

PinholeCamera loadCameraOrThrow(const fs::path& path) {
  if (!isFile(path)) throw Error(path.string() + ": camera file is missing");
  return PinholeCamera::loadYaml(path.string());
}

// ---------------------------------------------------------------------------
// sim: our DatasetWriter's output.

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

// ---------------------------------------------------------------------------
// touches.txt (any format): `timestamp frame_index u v phase r g b width`.

// Parses the whole of `s` as an integer in [lo, hi].
long parseInteger(const std::string& s, long lo, long hi, const fs::path& file, int line,
                  const std::string& what) {
  long v = 0;
  const char* end = s.data() + s.size();
  const auto [ptr, ec] = std::from_chars(s.data(), end, v);
  if (s.empty() || ec != std::errc() || ptr != end || v < lo || v > hi) {
    throw Error(at(file, line) + ": " + what + " '" + s + "' is not an integer in [" +
                std::to_string(lo) + ", " + std::to_string(hi) + "]");
  }
  return v;
}

// Reads touches.txt: frame indices into `frames`, stamps equal to the frame's
// (to 1 us), pixels inside the image, events in frame order forming whole strokes.
std::vector<TouchEvent> readTouches(const fs::path& file, const std::vector<DatasetFrame>& frames,
                                    const PinholeCamera& camera) {
  constexpr double kStampTolerance = 1e-6;  // stamps are written with 6 decimals
  const std::string layout = "timestamp frame_index u v phase r g b width";
  std::vector<TouchEvent> events;
  std::vector<int> numbers;
  for (const TextLine& line : readTextLines(file, false)) {
    expectFields(line, 9, file, layout);
    const std::string where = at(file, line.number);
    TouchEvent e;
    e.timestamp = parseNumber(line.fields[0], file, line.number, "timestamp");
    e.frame = static_cast<size_t>(parseInteger(
        line.fields[1], 0, static_cast<long>(frames.size()) - 1, file, line.number, "frame_index"));
    if (std::abs(e.timestamp - frames[e.frame].timestamp) > kStampTolerance) {
      throw Error(where + ": timestamp " + line.fields[0] + " is not the stamp of frame " +
                  line.fields[1] + " (" + std::to_string(frames[e.frame].timestamp) + ")");
    }
    if (!events.empty() && e.frame < events.back().frame) {
      throw Error(where + ": frame_index " + line.fields[1] + " is before the previous line's (" +
                  std::to_string(events.back().frame) + ")");
    }
    e.uv = Eigen::Vector2d(parseNumber(line.fields[2], file, line.number, "u"),
                           parseNumber(line.fields[3], file, line.number, "v"));
    if (!camera.inImage(e.uv)) {
      throw Error(where + ": pixel (" + line.fields[2] + ", " + line.fields[3] +
                  ") is outside the " + std::to_string(camera.width()) + "x" +
                  std::to_string(camera.height()) + " image");
    }
    const auto phase = parseTouchPhase(line.fields[4]);
    if (!phase) {
      throw Error(where + ": phase '" + line.fields[4] + "' is not begin, move or end");
    }
    e.phase = *phase;
    e.r = static_cast<uint8_t>(parseInteger(line.fields[5], 0, 255, file, line.number, "r"));
    e.g = static_cast<uint8_t>(parseInteger(line.fields[6], 0, 255, file, line.number, "g"));
    e.b = static_cast<uint8_t>(parseInteger(line.fields[7], 0, 255, file, line.number, "b"));
    e.width = parseNumber(line.fields[8], file, line.number, "width");
    if (!(e.width > 0)) throw Error(where + ": width " + line.fields[8] + " must be > 0");
    events.push_back(e);
    numbers.push_back(line.number);
  }
  const auto bad = firstIllFormedTouch(events, [](const TouchEvent& e) { return e.phase; });
  if (bad && *bad < events.size()) {
    throw Error(at(file, numbers[*bad]) + ": phase '" + toString(events[*bad].phase) + "' " +
                (events[*bad].phase == TouchPhase::kBegin ? "inside a stroke (no 'end' before)"
                                                          : "without a 'begin' before"));
  }
  if (bad) throw Error(file.string() + ": the last stroke has no 'end'");
  return events;
}

}  // namespace

// ---------------------------------------------------------------------------

DatasetFormat parseDatasetFormat(const std::string& name) {
  if (name == "auto") return DatasetFormat::kAuto;
  if (name == "sim") return DatasetFormat::kSim;
  if (name == "tum") return DatasetFormat::kTum;
  if (name == "kitti") return DatasetFormat::kKitti;
  if (name == "euroc") return DatasetFormat::kEuroc;
  throw Error("unknown dataset format '" + name + "' (expected auto, sim, tum, kitti or euroc)");
}

std::string toString(DatasetFormat format) {
  switch (format) {
    case DatasetFormat::kAuto:
      return "auto";
    case DatasetFormat::kSim:
      return "sim";
    case DatasetFormat::kTum:
      return "tum";
    case DatasetFormat::kKitti:
      return "kitti";
    case DatasetFormat::kEuroc:
      return "euroc";
  }
  return "unknown";
}

DatasetFormat Dataset::detectFormat(const std::string& dir_str) {
  const fs::path dir(dir_str);
  if (!isDirectory(dir)) throw Error(dir_str + ": dataset folder does not exist");
  if (isFile(dir / "cam0" / "data.csv") || isFile(dir / "mav0" / "cam0" / "data.csv")) {
    return DatasetFormat::kEuroc;
  }
  if (isFile(dir / "calib.txt") && isDirectory(dir / "image_0")) return DatasetFormat::kKitti;
  if (isFile(dir / "rgb.txt")) {
    return isFile(dir / "camera.yaml") ? DatasetFormat::kSim : DatasetFormat::kTum;
  }
  throw Error(dir_str +
              ": cannot tell the dataset format: found none of cam0/data.csv (EuRoC), "
              "calib.txt + image_0/ (KITTI), rgb.txt (TUM; with camera.yaml: sim)");
}

Dataset Dataset::open(const std::string& dir_str, DatasetFormat format,
                      const std::string& camera_yaml_override) {
  std::error_code ec;
  // Resolve symlinks first: "pkg/../../x" must follow a symlinked package.
  fs::path dir = fs::weakly_canonical(fs::absolute(fs::path(dir_str), ec), ec);
  if (ec) dir = fs::absolute(fs::path(dir_str)).lexically_normal();
  if (!isDirectory(dir)) throw Error(dir_str + ": dataset folder does not exist");
  // "a/b/" normalises to "a/b/" whose filename() is empty: drop the slash.
  const fs::path clean = dir.has_filename() ? dir : dir.parent_path();
  if (format == DatasetFormat::kAuto) format = detectFormat(clean.string());

  const bool need_camera = camera_yaml_override.empty();
  Contents c;
  switch (format) {
    case DatasetFormat::kSim:
      c = loadSim(clean, need_camera);
      break;
    case DatasetFormat::kTum:
      c = loadTum(clean, need_camera);
      break;
    case DatasetFormat::kKitti:
      c = loadKitti(clean, need_camera);
      break;
    case DatasetFormat::kEuroc:
      c = loadEuroc(clean, need_camera);
      break;
    case DatasetFormat::kAuto:
      break;
  }
  if (c.frames.empty()) {
    throw Error(clean.string() + ": empty dataset (no frames listed, " + toString(format) +
                " format)");
  }
  if (!need_camera) c.camera = loadCameraOrThrow(camera_yaml_override);

  Dataset d;
  d.dir_ = clean.string();
  d.format_ = format;
  d.camera_ = *c.camera;
  d.frames_ = std::move(c.frames);
  d.sources_ = std::move(c.sources);
  d.imu_ = std::move(c.imu);
  const fs::path touches = clean / "touches.txt";
  if (isFile(touches)) d.touches_ = readTouches(touches, d.frames_, d.camera_);
  return d;
}

const DatasetFrame& Dataset::frame(size_t i) const {
  if (i >= frames_.size()) {
    throw Error(dir_ + ": frame index " + std::to_string(i) + " out of range (" +
                std::to_string(frames_.size()) + " frames)");
  }
  return frames_[i];
}

cv::Mat Dataset::loadImage(size_t i, int imread_flags) const {
  const DatasetFrame& f = frame(i);
  const std::string where = f.image_path + " (listed at " + sources_[i] + ")";
  if (!isFile(f.image_path)) throw Error(where + ": image file is missing");
  cv::Mat image;
  try {
    image = cv::imread(f.image_path, imread_flags);
  } catch (const cv::Exception& e) {
    throw Error(where + ": cannot decode image (" + e.what() + ")");
  }
  if (image.empty()) throw Error(where + ": cannot read image (empty, corrupt or not an image)");
  if (image.cols != camera_.width() || image.rows != camera_.height()) {
    throw Error(where + ": image is " + std::to_string(image.cols) + "x" +
                std::to_string(image.rows) + " but the camera is " +
                std::to_string(camera_.width()) + "x" + std::to_string(camera_.height()));
  }
  return image;
}

bool Dataset::hasGroundTruth() const {
  return std::any_of(frames_.begin(), frames_.end(),
                     [](const DatasetFrame& f) { return f.T_w_c_gt.has_value(); });
}

Trajectory Dataset::groundTruth() const {
  Trajectory traj;
  for (const DatasetFrame& f : frames_) {
    if (f.T_w_c_gt) traj.push_back({f.timestamp, *f.T_w_c_gt});
  }
  return traj;
}

}  // namespace ecar
