// ecar_slam_offline's bookkeeping of each device's run, and when a device
// that did not start the map first saw ground the others had mapped (see the
// tool's file comment). Included by that tool only.
#pragma once

#include <cmath>
#include <optional>
#include <string>
#include <tuple>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "ecar_core/eval/trajectory_eval.h"
#include "ecar_core/io/dataset.h"
#include "ecar_core/io/trajectory.h"
#include "ecar_core/slam/slam_system.h"

namespace offline {

// Map points another device's keyframes had observed from about the same
// distance: the count an upload needs to "see mapped ground".
constexpr int kOverlapPoints = 20;

struct DeviceRun {
  explicit DeviceRun(ecar::Dataset d) : dataset(std::move(d)) {}
  ecar::Dataset dataset;
  std::string name;
  std::vector<size_t> uploads;  // frame indices sent
  size_t next = 0;
  int tracked = 0, init_upload = -1, joined_upload = -1, relocalisations = 0;
  int first_overlap_upload = -1;
  double overlap_range_m = 0.0;           ///< the distance limit of first_overlap_upload
  ecar::Trajectory estimate, truth;       // tracked uploads with ground truth
  std::vector<ecar::MapId> estimate_map;  // the map each estimate is in
  std::vector<size_t> estimate_step;      // the atlas step of each estimate
  ecar::Trajectory all_estimates;
  int first_tracked_upload = -1;
  int maps_started = 0;  // maps this device initialised
  std::vector<bool> upload_tracked, upload_blank, upload_initialised;
};

inline std::string deviceTrajectoryPath(const std::string& out, size_t device, size_t count) {
  if (count == 1) return out;
  const auto dot = out.rfind('.');
  const std::string stem = dot == std::string::npos ? out : out.substr(0, dot);
  const std::string ext = dot == std::string::npos ? "" : out.substr(dot);
  return stem + "_device" + std::to_string(device) + ext;
}

// A map point (in the ground-truth frame, through S) with the keyframes that
// observed it: their device, time since the device's first frame, centre (the
// ground truth's) and the atlas map each was made in (from its id range).
struct ObservedPoint {
  struct View {
    size_t device;
    double time;
    Eigen::Vector3d centre;
    ecar::MapId origin;
  };
  Eigen::Vector3d p;
  std::vector<View> views;
};

// Every point of the map with ground truth views; `distances` receives every
// observation's distance (for the range the SLAM maps at).
inline std::vector<ObservedPoint> observedPoints(const ecar::SlamSystem& slam, const ecar::Sim3& S,
                                                 const std::vector<DeviceRun>& runs,
                                                 uint32_t id_range,
                                                 std::vector<double>* distances) {
  std::vector<ObservedPoint> points;
  auto lock = slam.map().readLock();
  for (const auto& pid : slam.map().pointIds()) {
    const ecar::MapPoint* p = slam.map().point(pid);
    if (!p) continue;
    ObservedPoint o;
    o.p = S * p->p_w;
    for (const auto& obs : p->observations) {
      const ecar::KeyFrame* kf = slam.map().keyframe(obs.first);
      if (!kf) continue;
      distances->push_back(S.scale * (p->p_w - kf->center()).norm());
      const size_t d = kf->device.value - 1;
      if (kf->device.value < 1 || d >= runs.size()) continue;
      const DeviceRun& r = runs[d];
      if (kf->frame_index >= r.dataset.size()) continue;
      const auto& f = r.dataset.frame(kf->frame_index);
      if (!f.T_w_c_gt) continue;
      o.views.push_back({d, f.timestamp - r.dataset.frame(0).timestamp, f.T_w_c_gt->translation(),
                         ecar::MapId((kf->id.value - 1) / id_range + 1)});
    }
    if (!o.views.empty()) points.push_back(std::move(o));
  }
  return points;
}

// Sets first_overlap_upload of every device that did not start the map (see
// the file comment).
inline void firstOverlapUploads(const ecar::SlamSystem& slam, const ecar::Sim3& S,
                                std::vector<DeviceRun>* runs, uint32_t id_range) {
  std::vector<double> observation_distances;
  const std::vector<ObservedPoint> points =
      observedPoints(slam, S, *runs, id_range, &observation_distances);
  // The range the SLAM itself maps at: 90% of the map's observations are closer.
  const double range = ecar::percentile(observation_distances, 0.9);
  for (size_t d = 0; d < runs->size(); ++d) {
    DeviceRun& r = (*runs)[d];
    const ecar::PinholeCamera& camera = r.dataset.camera();
    if (r.init_upload >= 0) continue;  // it started the map
    r.overlap_range_m = range;
    for (size_t u = 0; u < r.uploads.size(); ++u) {
      const auto& f = r.dataset.frame(r.uploads[u]);
      if (!f.T_w_c_gt) continue;
      const double t = f.timestamp - r.dataset.frame(0).timestamp;
      const ecar::SE3 T_c_w = f.T_w_c_gt->inverse();
      const Eigen::Vector3d c = f.T_w_c_gt->translation();
      int shared = 0;
      for (const auto& o : points) {
        const Eigen::Vector3d pc = T_c_w * o.p;
        if (pc.z() < 0.1) continue;
        const std::optional<Eigen::Vector2d> uv = camera.project(pc);
        if (!uv || !camera.inImage(*uv)) continue;
        const double dist = (o.p - c).norm();
        if (dist > range) continue;
        for (const ObservedPoint::View& v : o.views) {
          if (v.device == d || v.time > t) continue;
          if (std::abs((o.p - v.centre).norm() / dist - 1.0) <= 0.2) {
            ++shared;
            break;
          }
        }
      }
      if (shared >= kOverlapPoints) {
        r.first_overlap_upload = static_cast<int>(u);
        break;
      }
    }
  }
}

}  // namespace offline
