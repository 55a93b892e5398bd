#include "ecar_core/io/dataset_writer.h"

#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <vector>

#include <Eigen/Geometry>
#include <opencv2/imgcodecs.hpp>

#include "ecar_core/common/error.h"

namespace ecar {

namespace fs = std::filesystem;

namespace {

constexpr char kGroundTruthHeader[] =
    "# ground truth trajectory\n"
    "# file: ecar simulation (T_w_c: camera pose in the world)\n"
    "# timestamp tx ty tz qx qy qz qw\n";
constexpr char kOdometryHeader[] =
    "# odometry trajectory\n"
    "# file: ecar simulation (T_o_c: camera pose in the odometry frame)\n"
    "# timestamp tx ty tz qx qy qz qw\n";
constexpr char kRgbHeader[] =
    "# color images\n"
    "# file: ecar simulation\n"
    "# timestamp filename\n";
constexpr char kImuHeader[] =
    "# imu: camera optical frame (x right, y down, z forward); specific force in m/s^2\n"
    "# (reads +g up at rest), angular rate in rad/s\n"
    "# timestamp ax ay az wx wy wz\n";
constexpr char kTouchesHeader[] =
    "# scripted touches: the frame's stamp and 0-based index in rgb.txt, the pixel\n"
    "# (column, row, origin top-left), phase begin|move|end, colour 0-255, width in metres\n"
    "# timestamp frame_index u v phase r g b width\n";
constexpr char kGravityHeader[] =
    "# gravity: accelerometer at rest in the camera optical frame, m/s^2, points up\n"
    "# timestamp gx gy gz\n";

std::string stampText(double t) {
  char buf[64];
  std::snprintf(buf, sizeof(buf), "%.6f", t);
  return buf;
}

std::string poseLine(const std::string& stamp, const SE3& T) {
  Eigen::Quaterniond q(T.linear());
  q.normalize();
  const Eigen::Vector3d& t = T.translation();
  char buf[512];
  std::snprintf(buf, sizeof(buf), "%s %.17g %.17g %.17g %.17g %.17g %.17g %.17g\n", stamp.c_str(),
                t.x(), t.y(), t.z(), q.x(), q.y(), q.z(), q.w());
  return buf;
}

// The shortest text that reads back as exactly `v` (locale independent).
std::string shortest(double v) {
  char buf[64];
  const auto [end, ec] = std::to_chars(buf, buf + sizeof(buf), v);
  return ec == std::errc() ? std::string(buf, end) : std::string("nan");
}

void writeOrThrow(std::ofstream& stream, const std::string& text, const fs::path& file) {
  stream << text;
  if (!stream) throw Error(file.string() + ": write failed");
}

}  // namespace

DatasetWriter::DatasetWriter(const std::string& dir, const PinholeCamera& camera)
    : dir_(dir), camera_(camera) {
  std::error_code ec;
  fs::create_directories(fs::path(dir) / "rgb", ec);
  if (ec) throw Error(dir + ": cannot create dataset folder (" + ec.message() + ")");
  const auto start = [&](std::ofstream& stream, const char* name, const char* header) {
    const fs::path file = fs::path(dir) / name;
    stream.open(file, std::ios::out | std::ios::trunc);
    if (!stream) throw Error(file.string() + ": cannot write file");
    writeOrThrow(stream, header, file);
  };
  start(rgb_, "rgb.txt", kRgbHeader);
  start(groundtruth_, "groundtruth.txt", kGroundTruthHeader);
  start(imu_, "imu.txt", kImuHeader);
  // Optional files of an earlier run in the same folder would be read back
  // with this run's frames: remove them.
  fs::remove(fs::path(dir) / "gravity.txt", ec);
  fs::remove(fs::path(dir) / "odometry.txt", ec);
  fs::remove(fs::path(dir) / "touches.txt", ec);
}

DatasetWriter::~DatasetWriter() {
  try {
    finish();
  } catch (const std::exception&) {
    // Destructors must not throw; finish() reports errors to callers that ask.
  }
}

void DatasetWriter::checkOpen() const {
  if (finished_) throw Error(dir_ + ": DatasetWriter used after finish()");
}

std::ofstream& DatasetWriter::openLazily(std::ofstream& stream, const std::string& name,
                                         const std::string& header) {
  if (!stream.is_open()) {
    const fs::path file = fs::path(dir_) / name;
    stream.open(file, std::ios::out | std::ios::trunc);
    if (!stream) throw Error(file.string() + ": cannot write file");
    writeOrThrow(stream, header, file);
  }
  return stream;
}

void DatasetWriter::addFrame(double timestamp, const cv::Mat& image, const SE3& T_w_c_gt,
                             const std::optional<Eigen::Vector3d>& gravity_c,
                             const std::optional<SE3>& T_o_c_odom) {
  checkOpen();
  if (!std::isfinite(timestamp)) throw Error(dir_ + ": frame timestamp is not finite");
  const long long us = std::llround(timestamp * 1e6);
  if (frame_count_ > 0 && us <= last_frame_us_) {
    throw Error(dir_ + ": frame timestamp " + stampText(timestamp) +
                " is not after the previous frame's (microsecond resolution)");
  }
  const std::string stamp = stampText(timestamp);
  if (image.empty()) throw Error(dir_ + ": empty image for frame " + stamp);
  if (image.cols != camera_.width() || image.rows != camera_.height()) {
    throw Error(dir_ + ": image of frame " + stamp + " is " + std::to_string(image.cols) + "x" +
                std::to_string(image.rows) + " but the camera is " +
                std::to_string(camera_.width()) + "x" + std::to_string(camera_.height()));
  }
  if (!isFinite(T_w_c_gt))
    throw Error(dir_ + ": ground-truth pose of frame " + stamp + " is not finite");
  if (gravity_c && !gravity_c->allFinite()) {
    throw Error(dir_ + ": gravity of frame " + stamp + " is not finite");
  }
  if (T_o_c_odom && !isFinite(*T_o_c_odom)) {
    throw Error(dir_ + ": odometry pose of frame " + stamp + " is not finite");
  }

  const std::string name = "rgb/" + stamp + ".png";
  const fs::path image_file = fs::path(dir_) / name;
  bool written = false;
  try {
    written = cv::imwrite(image_file.string(), image, {cv::IMWRITE_PNG_COMPRESSION, 1});
  } catch (const cv::Exception& e) {
    throw Error(image_file.string() + ": cannot write image (" + e.what() + ")");
  }
  if (!written) throw Error(image_file.string() + ": cannot write image");

  writeOrThrow(rgb_, stamp + " " + name + "\n", fs::path(dir_) / "rgb.txt");
  writeOrThrow(groundtruth_, poseLine(stamp, T_w_c_gt), fs::path(dir_) / "groundtruth.txt");
  if (gravity_c) {
    char buf[256];
    std::snprintf(buf, sizeof(buf), "%s %.17g %.17g %.17g\n", stamp.c_str(), gravity_c->x(),
                  gravity_c->y(), gravity_c->z());
    writeOrThrow(openLazily(gravity_, "gravity.txt", kGravityHeader), buf,
                 fs::path(dir_) / "gravity.txt");
  }
  if (T_o_c_odom) {
    writeOrThrow(openLazily(odometry_, "odometry.txt", kOdometryHeader),
                 poseLine(stamp, *T_o_c_odom), fs::path(dir_) / "odometry.txt");
  }
  frame_stamps_.emplace_back(us, stamp);
  last_frame_us_ = us;
  ++frame_count_;
}

void DatasetWriter::addTouch(const TouchEvent& e) {
  checkOpen();
  const std::string what = dir_ + ": touch on frame " + std::to_string(e.frame);
  if (e.frame >= frame_count_) {
    throw Error(what + ": no such frame yet (" + std::to_string(frame_count_) + " added)");
  }
  if (last_touch_ && e.frame < last_touch_->frame) {
    throw Error(what + ": before the previous touch's frame " + std::to_string(last_touch_->frame));
  }
  const auto& [frame_us, stamp] = frame_stamps_[e.frame];
  if (!std::isfinite(e.timestamp) || std::llabs(std::llround(e.timestamp * 1e6) - frame_us) > 1) {
    throw Error(what + ": timestamp " + stampText(e.timestamp) + " is not the frame's (" + stamp +
                ")");
  }
  if (!e.uv.allFinite() || !camera_.inImage(e.uv)) {
    throw Error(what + ": pixel is not finite or outside the image");
  }
  if (!std::isfinite(e.width) || !(e.width > 0)) throw Error(what + ": width must be > 0");
  const bool open = last_touch_ && last_touch_->phase != TouchPhase::kEnd;
  if ((e.phase == TouchPhase::kBegin) == open) {
    throw Error(what + ": phase " + toString(e.phase) +
                (open ? " inside a stroke" : " without a begin before"));
  }
  const std::string line = stamp + " " + std::to_string(e.frame) + " " + shortest(e.uv.x()) + " " +
                           shortest(e.uv.y()) + " " + toString(e.phase) + " " +
                           std::to_string(e.r) + " " + std::to_string(e.g) + " " +
                           std::to_string(e.b) + " " + shortest(e.width) + "\n";
  writeOrThrow(openLazily(touches_, "touches.txt", kTouchesHeader), line,
               fs::path(dir_) / "touches.txt");
  last_touch_ = e;
  ++touch_count_;
}

void DatasetWriter::addImu(const ImuSample& s) {
  checkOpen();
  if (!std::isfinite(s.timestamp) || !s.acc_c.allFinite() || !s.gyro_c.allFinite()) {
    throw Error(dir_ + ": IMU sample with a non-finite value");
  }
  const long long ns = std::llround(s.timestamp * 1e9);
  if (imu_count_ > 0 && ns <= last_imu_ns_) {
    throw Error(dir_ + ": IMU timestamp " + std::to_string(s.timestamp) +
                " is not after the previous sample's");
  }
  char buf[512];
  std::snprintf(buf, sizeof(buf), "%.9f %.17g %.17g %.17g %.17g %.17g %.17g\n", s.timestamp,
                s.acc_c.x(), s.acc_c.y(), s.acc_c.z(), s.gyro_c.x(), s.gyro_c.y(), s.gyro_c.z());
  writeOrThrow(imu_, buf, fs::path(dir_) / "imu.txt");
  last_imu_ns_ = ns;
  ++imu_count_;
}

void DatasetWriter::finish() {
  if (finished_) return;
  finished_ = true;
  std::string failed;
  if (last_touch_ && last_touch_->phase != TouchPhase::kEnd) {
    failed = "touches.txt (the last stroke has no end)";
  }
  camera_.saveYaml((fs::path(dir_) / "camera.yaml").string());
  const std::vector<std::pair<std::ofstream*, const char*>> files = {
      {&rgb_, "rgb.txt"},         {&groundtruth_, "groundtruth.txt"}, {&imu_, "imu.txt"},
      {&gravity_, "gravity.txt"}, {&odometry_, "odometry.txt"},       {&touches_, "touches.txt"}};
  for (const auto& [stream, name] : files) {
    if (!stream->is_open()) continue;
    stream->close();
    if (!*stream) failed += std::string(failed.empty() ? "" : ", ") + name;
  }
  if (!failed.empty()) throw Error(dir_ + ": could not finish writing " + failed);
}

}  // namespace ecar
