// Dataset: format names and detection, open() (the loaders are in
// dataset_formats.cpp), touches.txt, and frame and image access.
#include "ecar_core/io/dataset.h"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <string>
#include <system_error>
#include <utility>
#include <vector>

#include <opencv2/imgcodecs.hpp>

#include "ecar_core/common/error.h"
#include "ecar_core/io/dataset_formats.h"
#include "ecar_core/io/dataset_parsing.h"

namespace ecar {

namespace fs = std::filesystem;
using dataset_internal::at;
using dataset_internal::Contents;
using dataset_internal::expectFields;
using dataset_internal::isDirectory;
using dataset_internal::isFile;
using dataset_internal::loadCameraOrThrow;
using dataset_internal::loadEuroc;
using dataset_internal::loadKitti;
using dataset_internal::loadSim;
using dataset_internal::loadTum;
using dataset_internal::parseNumber;
using dataset_internal::readTextLines;
using dataset_internal::TextLine;

namespace {

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
