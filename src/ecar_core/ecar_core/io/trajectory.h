// Trajectories in the TUM text format: one pose per line,
// `timestamp tx ty tz qx qy qz qw` (T_w_c: camera pose in the world),
// '#' starts a comment line.
#pragma once

#include <string>
#include <utility>
#include <vector>

#include "ecar_core/common/geometry.h"

namespace ecar {

struct StampedPose {
  double timestamp = 0.0;  ///< seconds
  SE3 T_w_c = SE3::Identity();
};

using Trajectory = std::vector<StampedPose>;

/// Reads a TUM trajectory. Throws ecar::Error naming the file and line number
/// on a malformed line (wrong field count, non-numeric or non-finite value,
/// zero quaternion). Blank lines and '#' comments are skipped.
Trajectory readTum(const std::string& path);

/// Writes a TUM trajectory (full double precision, quaternion normalised).
/// Throws ecar::Error when the file cannot be written.
void writeTum(const std::string& path, const Trajectory& traj, const std::string& comment = "");

/// Pairs of indices (i into a, j into b) whose timestamps differ by at most
/// max_dt (plus an optional constant offset added to b's stamps), each index
/// used at most once, matched greedily by smallest difference as TUM's
/// associate.py does. Returned in increasing order of i.
std::vector<std::pair<size_t, size_t>> associate(const std::vector<double>& a,
                                                 const std::vector<double>& b, double max_dt = 0.02,
                                                 double offset_b = 0.0);

/// Convenience: the timestamps of a trajectory.
std::vector<double> timestamps(const Trajectory& traj);

}  // namespace ecar
