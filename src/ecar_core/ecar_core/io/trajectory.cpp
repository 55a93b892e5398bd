#include "ecar_core/io/trajectory.h"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <fstream>
#include <sstream>
#include <system_error>
#include <tuple>

#include "ecar_core/common/error.h"
#include "ecar_core/common/text.h"

namespace ecar {

namespace {

constexpr int kTumFields = 8;  // timestamp tx ty tz qx qy qz qw
const char* const kTumFieldNames[kTumFields] = {"timestamp", "tx", "ty", "tz",
                                                "qx",        "qy", "qz", "qw"};

// "<path>:<line>: <message>", the location format editors and compilers use.
Error lineError(const std::string& path, size_t line_number, const std::string& message) {
  return Error(path + ":" + std::to_string(line_number) + ": " + message);
}

StampedPose parseTumLine(const std::string& path, size_t line_number,
                         const std::vector<std::string>& fields) {
  if (fields.size() != kTumFields) {
    throw lineError(
        path, line_number,
        "expected 8 fields (timestamp tx ty tz qx qy qz qw), got " + std::to_string(fields.size()));
  }
  double v[kTumFields];
  for (int k = 0; k < kTumFields; ++k) {
    if (!parseDouble(fields[k], &v[k])) {
      throw lineError(
          path, line_number,
          std::string("field ") + kTumFieldNames[k] + " is not a number: '" + fields[k] + "'");
    }
    if (!std::isfinite(v[k])) {
      throw lineError(
          path, line_number,
          std::string("field ") + kTumFieldNames[k] + " is not finite: '" + fields[k] + "'");
    }
  }
  const Eigen::Quaterniond q(v[7], v[4], v[5], v[6]);  // Eigen order: w, x, y, z
  if (!(q.norm() > 1e-12)) {
    throw lineError(path, line_number, "quaternion (qx qy qz qw) has zero norm");
  }
  StampedPose pose;
  pose.timestamp = v[0];
  pose.T_w_c = makeSE3(q, Eigen::Vector3d(v[1], v[2], v[3]));
  return pose;
}

// Shortest text that reads back to exactly the same double.
std::string formatDouble(double value) {
  char buffer[64];
  const auto [ptr, ec] = std::to_chars(buffer, buffer + sizeof(buffer), value);
  if (ec != std::errc()) throw Error("cannot format number " + std::to_string(value));
  return std::string(buffer, ptr);
}

}  // namespace

Trajectory readTum(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw Error("cannot open trajectory file '" + path + "'");
  Trajectory traj;
  std::string line;
  size_t line_number = 0;
  while (std::getline(in, line)) {
    ++line_number;
    const size_t first = line.find_first_not_of(" \t\r\n");
    if (first == std::string::npos || line[first] == '#') continue;
    traj.push_back(parseTumLine(path, line_number, splitWhitespace(line)));
  }
  if (in.bad()) throw Error("error while reading trajectory file '" + path + "'");
  return traj;
}

void writeTum(const std::string& path, const Trajectory& traj, const std::string& comment) {
  std::ofstream out(path);
  if (!out) throw Error("cannot open '" + path + "' for writing");
  if (!comment.empty()) {
    std::istringstream comment_lines(comment);
    std::string comment_line;
    while (std::getline(comment_lines, comment_line)) out << "# " << comment_line << "\n";
  }
  out << "# timestamp tx ty tz qx qy qz qw\n";
  for (size_t i = 0; i < traj.size(); ++i) {
    const StampedPose& pose = traj[i];
    if (!std::isfinite(pose.timestamp) || !isFinite(pose.T_w_c)) {
      throw Error("cannot write '" + path + "': pose " + std::to_string(i) + " is not finite");
    }
    const Eigen::Vector3d t = pose.T_w_c.translation();
    const Eigen::Quaterniond q = Eigen::Quaterniond(pose.T_w_c.linear()).normalized();
    out << formatDouble(pose.timestamp) << ' ' << formatDouble(t.x()) << ' ' << formatDouble(t.y())
        << ' ' << formatDouble(t.z()) << ' ' << formatDouble(q.x()) << ' ' << formatDouble(q.y())
        << ' ' << formatDouble(q.z()) << ' ' << formatDouble(q.w()) << '\n';
  }
  out.flush();
  if (!out) throw Error("error while writing '" + path + "'");
}

std::vector<std::pair<size_t, size_t>> associate(const std::vector<double>& a,
                                                 const std::vector<double>& b, double max_dt,
                                                 double offset_b) {
  if (!(max_dt >= 0.0) || !std::isfinite(max_dt)) {
    throw Error("associate: max_dt must be finite and >= 0, got " + std::to_string(max_dt));
  }
  if (!std::isfinite(offset_b)) throw Error("associate: offset_b must be finite");

  // b's shifted stamps in increasing order, so each a only scans its window.
  std::vector<std::pair<double, size_t>> b_sorted;
  b_sorted.reserve(b.size());
  for (size_t j = 0; j < b.size(); ++j) b_sorted.emplace_back(b[j] + offset_b, j);
  std::sort(b_sorted.begin(), b_sorted.end());

  // Every candidate pair within max_dt, as (|dt|, i, j).
  std::vector<std::tuple<double, size_t, size_t>> candidates;
  for (size_t i = 0; i < a.size(); ++i) {
    auto it = std::lower_bound(b_sorted.begin(), b_sorted.end(),
                               std::make_pair(a[i] - max_dt, size_t{0}));
    for (; it != b_sorted.end() && it->first <= a[i] + max_dt; ++it) {
      const double dt = std::abs(a[i] - it->first);
      if (dt <= max_dt) candidates.emplace_back(dt, i, it->second);
    }
  }
  // Greedy by smallest |dt| (ties broken by index, so the result is deterministic).
  std::sort(candidates.begin(), candidates.end());
  std::vector<bool> a_used(a.size(), false), b_used(b.size(), false);
  std::vector<std::pair<size_t, size_t>> matches;
  for (const auto& [dt, i, j] : candidates) {
    if (a_used[i] || b_used[j]) continue;
    a_used[i] = b_used[j] = true;
    matches.emplace_back(i, j);
  }
  std::sort(matches.begin(), matches.end());
  return matches;
}

std::vector<double> timestamps(const Trajectory& traj) {
  std::vector<double> stamps;
  stamps.reserve(traj.size());
  for (const StampedPose& pose : traj) stamps.push_back(pose.timestamp);
  return stamps;
}

}  // namespace ecar
