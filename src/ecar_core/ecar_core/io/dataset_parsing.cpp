// The dataset reader's text parsing helpers and Contents helpers (see
// dataset_parsing.h).
#include "ecar_core/io/dataset_parsing.h"

#include <charconv>
#include <cmath>
#include <fstream>
#include <sstream>
#include <system_error>
#include <utility>

#include <Eigen/SVD>

#include "ecar_core/common/error.h"
#include "ecar_core/common/text.h"

namespace ecar::dataset_internal {

std::string at(const fs::path& file, int line) {
  return file.string() + ":" + std::to_string(line);
}

namespace {

std::string trim(const std::string& s) {
  const size_t b = s.find_first_not_of(" \t");
  if (b == std::string::npos) return "";
  const size_t e = s.find_last_not_of(" \t");
  return s.substr(b, e - b + 1);
}

}  // namespace

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

}  // namespace ecar::dataset_internal
