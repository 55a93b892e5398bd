// Trajectory evaluation against ground truth: absolute trajectory error (ATE)
// after a least-squares alignment, and relative pose error (RPE), as in the
// TUM RGB-D benchmark (Sturm et al., IROS 2012).
//
// Frames: gt holds T_w_c (ground-truth world), est holds T_v_c (the estimator's
// own world v). The alignment found here is S_w_v, mapping est's world into gt's.
#pragma once

#include <string>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>

#include "ecar_core/common/geometry.h"
#include "ecar_core/io/trajectory.h"

namespace ecar {

/// The similarity (with_scale) or rigid transform S minimising
/// sum_i |dst_i - S * src_i|^2, in closed form (Umeyama, PAMI 1991).
/// Throws ecar::Error when the sizes differ, there are fewer than 3 points, a
/// point is not finite, or the points are degenerate (all coincident or all
/// collinear, so the rotation is not unique).
/// Angles (degrees) of each rotation from their chordal mean (the SVD
/// projection of their sum onto SO(3)): how far a set of map-to-world
/// rotations spreads, i.e. how much a map bends. Empty for no rotations.
std::vector<double> rotationSpreadDeg(const std::vector<Eigen::Matrix3d>& rotations);

Sim3 umeyama(const std::vector<Eigen::Vector3d>& src, const std::vector<Eigen::Vector3d>& dst,
             bool with_scale);

/// How the estimate is aligned onto the ground truth before computing errors.
enum class Alignment {
  kNone,  ///< Compare in the given frames (est already expressed in gt's world).
  kSE3,   ///< Rigid alignment (rotation + translation): metric estimators (stereo, RGB-D, VIO).
  kSim3,  ///< Similarity alignment (also scale): monocular estimators with unknown scale.
};

struct EvalOptions {
  /// Alignment of est onto gt, fitted on all associated positions.
  Alignment alignment = Alignment::kSE3;
  /// Largest timestamp difference (seconds, >= 0) for a gt and an est pose to be associated.
  double max_dt = 0.02;
  /// RPE interval length, in rpe_unit (> 0; a whole number when in frames).
  double rpe_delta = 1.0;
  /// Unit of rpe_delta: kFrames counts associated poses, kSeconds uses gt timestamps,
  /// kMeters uses the distance travelled along gt. The second pose of each RPE pair is the
  /// first associated pose at least rpe_delta past the first one (1 us slack on seconds).
  enum RpeUnit { kFrames, kSeconds, kMeters } rpe_unit = kSeconds;
};

/// Throws ecar::Error naming the field when an option is out of range.
void validate(const EvalOptions& options);

/// Summary statistics of a set of non-negative errors. std is the population
/// standard deviation (numpy.std); median averages the two middle values for
/// an even count.
struct ErrorStats {
  size_t n = 0;
  double rmse = 0.0, mean = 0.0, median = 0.0, std = 0.0, min = 0.0, max = 0.0;
};

/// Statistics of `errors`; for an empty set n == 0 and every statistic is NaN.
ErrorStats computeStats(const std::vector<double>& errors);

/// The p-quantile (p in [0, 1]) of `values` by nearest rank; 0 for an empty set.
/// Used by the benchmark tools for median / p95 timings.
double percentile(std::vector<double> values, double p);

struct AteResult {
  ErrorStats translation;  ///< |p_gt - S_w_v * p_est| over matched poses, metres.
  Sim3 alignment;          ///< S_w_v (identity for Alignment::kNone).
  std::vector<std::pair<size_t, size_t>> matches;  ///< (index in gt, index in est), by gt index.
  std::vector<double> errors;                      ///< Per match, same order as matches.
};

/// Associates est with gt by timestamp (within options.max_dt), aligns est onto
/// gt and returns the translational error of every matched pose. Throws
/// ecar::Error on invalid options or too few matches (3 to align, 1 without).
AteResult computeAte(const Trajectory& gt, const Trajectory& est, const EvalOptions& options);

struct RpeResult {
  ErrorStats translation;   ///< |t(E)|, metres, E = (G_i^-1 G_j)^-1 (P_i^-1 P_j).
  ErrorStats rotation_deg;  ///< angle(R(E)), degrees.
};

/// Relative pose error over intervals of options.rpe_delta between associated
/// pose pairs (i, j). With Alignment::kSim3 the est translations are first
/// multiplied by the Sim(3) scale fitted as in computeAte; kSE3 and kNone need
/// no alignment (RPE is invariant to a rigid change of world). When no pair is
/// rpe_delta apart the stats have n == 0. Throws ecar::Error on invalid options
/// or too few matches.
RpeResult computeRpe(const Trajectory& gt, const Trajectory& est, const EvalOptions& options);

/// Maps every pose of traj by S (rotation composes, position maps); stamps kept.
Trajectory applyAlignment(const Trajectory& traj, const Sim3& S);

/// Lower-case names used on the command line and in JSON: "none", "se3",
/// "sim3"; "frames", "seconds", "meters".
std::string toString(Alignment alignment);
std::string toString(EvalOptions::RpeUnit unit);

/// JSON views of the results. NaN statistics (n == 0) become null.
nlohmann::json toJson(const ErrorStats& stats);
nlohmann::json toJson(const Sim3& S);  ///< {scale, rotation (row-major 3x3), translation}
nlohmann::json toJson(const EvalOptions& options);
/// {matched, translation, alignment}; per-pose errors only when with_errors.
nlohmann::json toJson(const AteResult& ate, bool with_errors = false);
nlohmann::json toJson(const RpeResult& rpe);

}  // namespace ecar
