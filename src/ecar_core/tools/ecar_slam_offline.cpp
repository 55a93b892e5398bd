// Runs the SLAM on datasets as the edge server would see them:
//
//   ecar_slam_offline --dataset DIR [--format auto|sim|tum|kitti|euroc] [--every N]
//                     [--jpeg-quality Q] [--frames N] [--out TRAJ.txt] [--summary FILE.json]
//                     [--devices DIR2 ...] [--no-odometry] [--threads] [--orb-features N]
//                     [--gravity-sigma DEG] [--odometry-sigma F] [--odometry-walk W]
//                     [--ba-whole-map N] [--no-loops] [--atlas]
//
// Every Nth frame of each dataset is (optionally) JPEG-compressed at quality Q,
// decoded, and tracked; several datasets run interleaved by time into one map,
// each device with its own camera (its dataset's camera.yaml).
// Prints and writes (JSON): uploads tracked / total, initialisation upload,
// relocalisations, keyframes, map points, ATE against the ground truth (Sim(3)
// without metric odometry, SE(3) with it; one transform for all devices), the
// rotation and tilt errors after that transform (how far the map bends), and
// median / p95 times of ORB extraction, tracking and local BA.
//
// For a device that joins a map another device started: `joined_upload` (its
// first tracked upload) and `first_overlap_upload`, the first upload whose
// ground-truth view shares mapped ground with the other devices' keyframes
// by then: at least kOverlapPoints points of the final map (aligned onto the
// ground truth by the ATE transform) lie in its image at a distance within
// 20% (about one ORB pyramid level) of the distance from which an earlier
// keyframe of another device observed them, and no farther than the range the
// SLAM maps at (the 90th percentile of the final map's observation distances;
// about 6 m in the corridor): points at 10 m on grazing walls and floor are in
// view but not matchable from the other side. Occlusion is not modelled (fine
// for the simulated box-shaped scenes). `join_delay_uploads` is the difference.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <map>
#include <string>
#include <tuple>
#include <vector>

#include <Eigen/Geometry>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "ecar_core/common/error.h"
#include "ecar_core/eval/trajectory_eval.h"
#include "ecar_core/io/dataset.h"
#include "ecar_core/io/trajectory.h"
#include "ecar_core/slam/atlas.h"
#include "ecar_core/slam/slam_system.h"
#include "offline_atlas_events.h"
#include "offline_options.h"
#include "offline_runs.h"

namespace {

using ecar::percentile;
using offline::Args;
using offline::DeviceRun;
using offline::deviceTrajectoryPath;
using offline::firstOverlapUploads;

nlohmann::json gapsJson(const DeviceRun& r) {
  nlohmann::json out = nlohmann::json::array();
  for (const offline::Gap& g :
       offline::trackingGaps(r.upload_tracked, r.upload_blank, r.upload_initialised)) {
    out.push_back({{"lost_upload", g.lost_upload},
                   {"blank_uploads", g.blank_uploads},
                   {"textured_upload", g.textured_upload},
                   {"tracked_upload", g.tracked_upload},
                   {"delay_uploads", g.delay()},
                   {"new_map", g.new_map}});
  }
  return out;
}

int run(const Args& args) {
  std::vector<DeviceRun> runs;
  for (size_t d = 0; d < args.datasets.size(); ++d) {
    DeviceRun r(ecar::Dataset::open(args.datasets[d], ecar::parseDatasetFormat(args.format)));
    r.name = "device_" + std::to_string(d);
    const size_t n =
        args.frames > 0 ? std::min<size_t>(args.frames, r.dataset.size()) : r.dataset.size();
    for (size_t i = 0; i < n; i += args.every) r.uploads.push_back(i);
    runs.push_back(std::move(r));
  }
  ecar::SlamConfig config;
  config.synchronous_mapping = !args.threads;
  if (args.orb_features > 0) config.orb.num_features = args.orb_features;
  if (args.gravity_sigma_deg >= 0.0) config.ba.gravity_sigma_deg = args.gravity_sigma_deg;
  if (args.odometry_sigma >= 0.0) config.odometry_sigma_fraction = args.odometry_sigma;
  if (args.odometry_walk >= 0.0) config.odometry_sigma_walk = args.odometry_walk;
  if (args.ba_whole_map >= 0) config.ba_whole_map_keyframes = args.ba_whole_map;
  config.loops.enabled = args.loops;
  // An atlas of maps; each device with its own camera (its dataset's camera.yaml).
  ecar::AtlasConfig atlas_config;
  if (!args.atlas) {
    atlas_config.several_maps = false;
    atlas_config.merge = false;
  }
  ecar::Atlas atlas(runs.front().dataset.camera(), config, atlas_config);
  for (size_t d = 0; d < runs.size(); ++d) {
    atlas.setCamera(ecar::DeviceId(static_cast<uint32_t>(d + 1)), runs[d].dataset.camera());
  }
  // Which upload of which device found each merge and each loop.
  offline::AtlasLog log;
  bool metric = args.use_odometry;
  for (const auto& r : runs) {
    if (r.dataset.size() == 0 || !r.dataset.frame(0).T_o_c_odom) metric = false;
  }

  std::vector<double> orb_ms, track_ms;
  std::vector<double> jpeg_bytes;  // size of each upload's JPEG (--jpeg-quality)
  std::vector<uint8_t> jpeg;
  std::vector<int> order;  // interleave: the device whose next upload is earliest
  size_t total_uploads = 0;
  for (const auto& r : runs) total_uploads += r.uploads.size();
  const auto t_start = std::chrono::steady_clock::now();
  for (size_t step = 0; step < total_uploads; ++step) {
    size_t d = runs.size();
    for (size_t k = 0; k < runs.size(); ++k) {
      if (runs[k].next >= runs[k].uploads.size()) continue;
      const double t = runs[k].dataset.frame(runs[k].uploads[runs[k].next]).timestamp -
                       runs[k].dataset.frame(0).timestamp;
      if (args.sequential) {
        d = k;
        break;
      }
      if (d == runs.size() || t < runs[d].dataset.frame(runs[d].uploads[runs[d].next]).timestamp -
                                      runs[d].dataset.frame(0).timestamp) {
        d = k;
      }
    }
    DeviceRun& r = runs[d];
    const size_t index = r.uploads[r.next];
    const int upload = static_cast<int>(r.next++);
    const ecar::DatasetFrame& f = r.dataset.frame(index);
    cv::Mat image;
    try {
      image = r.dataset.loadImage(index, cv::IMREAD_GRAYSCALE);
    } catch (const ecar::Error& e) {
      std::cerr << "ecar_slam_offline: " << e.what() << " (tracked as a bad image)\n";
    }
    if (args.jpeg_quality > 0 && !image.empty()) {
      cv::imencode(".jpg", image, jpeg, {cv::IMWRITE_JPEG_QUALITY, args.jpeg_quality});
      jpeg_bytes.push_back(static_cast<double>(jpeg.size()));
      image = cv::imdecode(jpeg, cv::IMREAD_GRAYSCALE);
    }
    const std::optional<ecar::SE3> odom = metric ? f.T_o_c_odom : std::optional<ecar::SE3>();
    ecar::MapId map_id;
    const size_t merges_before = atlas.merges().size();
    const size_t loops_before = atlas.loopClosures().size();
    const auto call_start = std::chrono::steady_clock::now();
    const ecar::TrackResult res =
        atlas.track(ecar::DeviceId(static_cast<uint32_t>(d + 1)), image, f.timestamp,
                    static_cast<uint32_t>(index), f.gravity_c, odom, &map_id);
    const double call_ms =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - call_start)
            .count();
    for (size_t m = merges_before; m < atlas.merges().size(); ++m) {
      log.merge_found_by.emplace_back(d, upload);
      log.merge_steps.push_back(step);
    }
    for (size_t l = loops_before; l < atlas.loopClosures().size(); ++l) {
      log.loop_found_by.emplace_back(d, upload);
      log.loop_steps.push_back(step);
    }
    if (args.verbose) {
      std::fprintf(stderr, "[slam] %s upload %d frame %zu: %s, %zu points%s%s\n", r.name.c_str(),
                   upload, index, ecar::toString(res.state), res.tracked.size(),
                   res.message.empty() ? "" : ": ", res.message.c_str());
    }
    orb_ms.push_back(res.orb_ms);
    track_ms.push_back(res.track_ms);
    const bool ok = res.state == ecar::TrackingState::kOk;
    log.steps.push_back({d, upload, ok, ok ? map_id : ecar::MapId(), call_ms});
    r.upload_tracked.push_back(ok);
    r.upload_blank.push_back(offline::blankImage(image));
    r.upload_initialised.push_back(res.initialised);
    if (res.initialised) {
      ++r.maps_started;
      if (r.init_upload < 0) r.init_upload = upload;
    }
    if (res.relocalised) {
      if (r.joined_upload < 0 && r.init_upload < 0) r.joined_upload = upload;
      ++r.relocalisations;
    }
    if (res.state == ecar::TrackingState::kOk) {
      ++r.tracked;
      if (r.first_tracked_upload < 0) r.first_tracked_upload = upload;
      r.all_estimates.push_back({f.timestamp, res.T_w_c});
      if (f.T_w_c_gt) {
        r.estimate.push_back({f.timestamp, res.T_w_c});
        r.estimate_map.push_back(map_id);
        r.estimate_step.push_back(step);
        r.truth.push_back({f.timestamp, *f.T_w_c_gt});
      }
    }
    if (step % 20 == 0 || step + 1 == total_uploads) {
      std::fprintf(stderr, "\r[slam] upload %zu/%zu  %s  maps %zu   ", step + 1, total_uploads,
                   ecar::toString(res.state), atlas.mapIds().size());
    }
  }
  std::fprintf(stderr, "\n");
  atlas.finish();
  const double wall_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t_start).count();
  // The map the evaluation is in: the first device's at the end (the largest
  // when it has none); estimates made in maps merged into it are moved into
  // its frame with the merges' similarities, those of other maps left out.
  ecar::MapId main_map = atlas.finalFrameOf(atlas.mapOf(ecar::DeviceId(1))).first;
  if (!atlas.map(main_map)) {
    size_t best = 0;
    for (const ecar::MapId id : atlas.mapIds()) {
      const auto m = atlas.map(id);
      auto lock = m->map().readLock();
      if (m->map().numKeyFrames() >= best) {
        best = m->map().numKeyFrames();
        main_map = id;
      }
    }
  }
  const std::shared_ptr<ecar::SlamSystem> main_slam = atlas.map(main_map);
  if (!main_slam) throw ecar::Error("no map was made");
  ecar::SlamSystem& slam = *main_slam;
  size_t outside_main = 0;
  for (DeviceRun& r : runs) {
    ecar::Trajectory estimate, truth;
    std::vector<size_t> estimate_step;
    for (size_t i = 0; i < r.estimate.size(); ++i) {
      const auto [final_map, S] = atlas.finalFrameOf(r.estimate_map[i]);
      if (final_map != main_map) {
        ++outside_main;
        continue;
      }
      ecar::StampedPose p = r.estimate[i];
      p.T_w_c = S.transformPose(p.T_w_c);
      estimate.push_back(p);
      truth.push_back(r.truth[i]);
      estimate_step.push_back(r.estimate_step[i]);
    }
    r.estimate = std::move(estimate);
    r.truth = std::move(truth);
    r.estimate_step = std::move(estimate_step);
  }
  if (outside_main > 0) {
    std::printf("%zu tracked uploads are in maps never merged into the first device's (left out)\n",
                outside_main);
  }
  // ATE: one transform for every device (they share the map).
  std::vector<Eigen::Vector3d> est_all, gt_all;
  for (const auto& r : runs) {
    for (size_t i = 0; i < r.estimate.size(); ++i) {
      est_all.push_back(r.estimate[i].T_w_c.translation());
      gt_all.push_back(r.truth[i].T_w_c.translation());
    }
  }
  nlohmann::json summary;
  summary["alignment"] = metric ? "se3" : "sim3";
  summary["every"] = args.every;
  summary["jpeg_quality"] = args.jpeg_quality;
  // Median upload JPEG size, bytes (null without --jpeg-quality).
  summary["jpeg_bytes_median"] =
      jpeg_bytes.empty() ? nlohmann::json() : nlohmann::json(percentile(jpeg_bytes, 0.5));
  ecar::Sim3 S;
  bool have_ate = est_all.size() >= 3;
  if (have_ate) {
    try {
      S = ecar::umeyama(est_all, gt_all, !metric);
    } catch (const ecar::Error& e) {
      have_ate = false;
      std::cerr << "ecar_slam_offline: no ATE: " << e.what() << "\n";
    }
  }
  if (have_ate) firstOverlapUploads(slam, S, &runs, atlas_config.id_range);
  std::printf("map: %zu keyframes, %zu map points (%.1f s wall)\n", slam.map().numKeyFrames(),
              slam.map().numPoints(), wall_s);
  std::vector<double> all_errors, all_tilt;
  std::vector<Eigen::Matrix3d> map_to_world;
  for (size_t d = 0; d < runs.size(); ++d) {
    const DeviceRun& r = runs[d];
    std::vector<double> errors;
    for (size_t i = 0; i < r.estimate.size() && have_ate; ++i) {
      errors.push_back(
          (S * r.estimate[i].T_w_c.translation() - r.truth[i].T_w_c.translation()).norm());
      // Map-to-world rotation seen at this upload (its spread is how far the
      // map bends), and the map's up axis against the true up in the camera
      // (the map is initialised with its z axis up when there is gravity).
      const Eigen::Matrix3d& R_est = r.estimate[i].T_w_c.linear();
      const Eigen::Matrix3d& R_gt = r.truth[i].T_w_c.linear();
      map_to_world.push_back(R_gt * R_est.transpose());
      const Eigen::Vector3d up_est = R_est.transpose() * Eigen::Vector3d::UnitZ();
      const Eigen::Vector3d up_gt = R_gt.transpose() * Eigen::Vector3d::UnitZ();
      all_tilt.push_back(std::atan2(up_est.cross(up_gt).norm(), up_est.dot(up_gt)) * 180.0 / M_PI);
    }
    all_errors.insert(all_errors.end(), errors.begin(), errors.end());
    const ecar::ErrorStats st = ecar::computeStats(errors);
    // Uploads from the one that initialised the map, or joined it, on.
    const int start = r.init_upload >= 0 ? r.init_upload : std::max(0, r.joined_upload);
    const int after_init = static_cast<int>(r.uploads.size()) - start;
    // How the device entered the map: it initialised it, or joined it.
    char entry[160];
    if (r.init_upload >= 0) {
      std::snprintf(entry, sizeof(entry), "initialised at upload %d (frame %d)", r.init_upload,
                    static_cast<int>(r.uploads[r.init_upload]));
    } else if (r.joined_upload < 0 && r.overlap_range_m > 0.0) {
      std::snprintf(entry, sizeof(entry), "never joined (first overlap upload %d, within %.1f m)",
                    r.first_overlap_upload, r.overlap_range_m);
    } else if (r.joined_upload < 0) {
      std::snprintf(entry, sizeof(entry), "never initialised a map or joined one");
    } else {
      std::snprintf(entry, sizeof(entry),
                    "joined at upload %d (first overlap upload %d, within %.1f m)", r.joined_upload,
                    r.first_overlap_upload, r.overlap_range_m);
    }
    std::printf(
        "%s (%s): tracked %d/%zu uploads (%.1f%%; %.1f%% from initialisation or joining on), %s,"
        " relocalisations %d, ATE rmse %.4f m (n %zu)\n",
        r.name.c_str(), r.dataset.dir().c_str(), r.tracked, r.uploads.size(),
        100.0 * r.tracked / std::max<size_t>(1, r.uploads.size()),
        100.0 * r.tracked / std::max(1, after_init), entry, r.relocalisations, st.rmse, st.n);
    summary["devices"].push_back(
        {{"dataset", r.dataset.dir()},
         {"uploads", r.uploads.size()},
         {"tracked", r.tracked},
         {"init_upload", r.init_upload},
         {"first_tracked_upload", r.first_tracked_upload},
         {"init_frame", r.init_upload >= 0 ? static_cast<int>(r.uploads[r.init_upload]) : -1},
         {"joined_upload", r.joined_upload},
         {"first_overlap_upload", r.first_overlap_upload},
         {"overlap_range_m", r.overlap_range_m},
         {"join_delay_uploads", r.joined_upload >= 0 && r.first_overlap_upload >= 0
                                    ? r.joined_upload - r.first_overlap_upload
                                    : -1},
         {"relocalisations", r.relocalisations},
         {"maps_started", r.maps_started},
         {"gaps", gapsJson(r)},
         {"ate", ecar::toJson(st)}});
    for (const offline::Gap& g :
         offline::trackingGaps(r.upload_tracked, r.upload_blank, r.upload_initialised)) {
      if (g.tracked_upload >= 0 && g.tracked_upload - g.lost_upload < 3) continue;
      std::printf("  %s lost at upload %d (%d blank uploads): %s\n", r.name.c_str(), g.lost_upload,
                  g.blank_uploads,
                  g.tracked_upload < 0
                      ? "never tracked again"
                      : ("tracked again at upload " + std::to_string(g.tracked_upload) + ", " +
                         std::to_string(g.delay()) + " after the first textured one" +
                         (g.new_map ? ", in a new map" : ""))
                            .c_str());
    }
    if (!args.out.empty()) {
      ecar::writeTum(deviceTrajectoryPath(args.out, d, runs.size()), r.all_estimates,
                     "ecar_slam_offline estimate (T_w_c per tracked upload)");
    }
  }
  const ecar::ErrorStats overall = ecar::computeStats(all_errors);
  const auto ba = slam.mapper().baTimes();
  std::printf(
      "ATE (%s, one transform for all devices): rmse %.4f m, median %.4f m, max %.4f m, scale "
      "%.4f\n",
      metric ? "SE(3)" : "Sim(3)", overall.rmse, overall.median, overall.max, S.scale);
  // Beside a metric ATE, the similarity fit: its scale is the map's scale
  // error (ground-truth metres per map metre).
  ecar::ErrorStats overall_sim3 = overall;
  ecar::Sim3 S_sim3 = S;
  if (have_ate && metric) {
    S_sim3 = ecar::umeyama(est_all, gt_all, true);
    std::vector<double> e;
    for (size_t i = 0; i < est_all.size(); ++i)
      e.push_back((S_sim3 * est_all[i] - gt_all[i]).norm());
    overall_sim3 = ecar::computeStats(e);
    std::printf("ATE (Sim(3)): rmse %.4f m; map scale error %+.2f%% (ground truth / map)\n",
                overall_sim3.rmse, 100.0 * (S_sim3.scale - 1.0));
  }
  summary["ate_sim3"] = ecar::toJson(overall_sim3);
  // The map at the end: its keyframes (after every loop correction and global
  // BA) against the ground truth of their frames, one transform.
  {
    std::vector<Eigen::Vector3d> est, gt;
    {
      auto lock = slam.map().readLock();
      for (const ecar::KeyFrameId id : slam.map().keyframeIds()) {
        const ecar::KeyFrame* kf = slam.map().keyframe(id);
        const size_t d = kf->device.value - 1;
        if (d >= runs.size() || kf->frame_index >= runs[d].dataset.size()) continue;
        const auto& truth = runs[d].dataset.frame(kf->frame_index).T_w_c_gt;
        if (!truth) continue;
        est.push_back(kf->center());
        gt.push_back(truth->translation());
      }
    }
    if (est.size() >= 3) {
      const ecar::Sim3 K = ecar::umeyama(est, gt, !metric);
      std::vector<double> e;
      for (size_t i = 0; i < est.size(); ++i) e.push_back((K * est[i] - gt[i]).norm());
      const ecar::ErrorStats st = ecar::computeStats(e);
      std::printf("keyframes at the end (%zu): ATE (%s) rmse %.4f m, max %.4f m\n", est.size(),
                  metric ? "SE(3)" : "Sim(3)", st.rmse, st.max);
      summary["ate_keyframes"] = ecar::toJson(st);
      if (metric) {
        const ecar::Sim3 K3 = ecar::umeyama(est, gt, true);
        std::vector<double> e3;
        for (size_t i = 0; i < est.size(); ++i) e3.push_back((K3 * est[i] - gt[i]).norm());
        const ecar::ErrorStats st3 = ecar::computeStats(e3);
        std::printf(
            "keyframes at the end: ATE (Sim(3)) rmse %.4f m, max %.4f m; scale error %+.2f%%\n",
            st3.rmse, st3.max, 100.0 * (K3.scale - 1.0));
        summary["ate_keyframes_sim3"] = ecar::toJson(st3);
        summary["scale_keyframes_sim3"] = K3.scale;
      }
    }
  }
  summary["scale_sim3"] = S_sim3.scale;
  summary["odometry_sigma_fraction"] = config.odometry_sigma_fraction;
  summary["odometry_sigma_walk"] = config.odometry_sigma_walk;
  summary["ba_whole_map_keyframes"] = config.ba_whole_map_keyframes;
  const ecar::ErrorStats rotation = ecar::computeStats(ecar::rotationSpreadDeg(map_to_world));
  const ecar::ErrorStats tilt = ecar::computeStats(all_tilt);
  std::printf(
      "map bending: map-to-world rotation off its mean by median %.3f deg, max %.3f deg | map "
      "up axis off gravity: median %.3f deg, max %.3f deg\n",
      rotation.median, rotation.max, tilt.median, tilt.max);
  {
    std::vector<double> calls;
    for (const offline::Step& st : log.steps) calls.push_back(st.call_ms);
    std::printf("track() calls ms: median %.1f p95 %.1f\n", percentile(calls, 0.5),
                percentile(calls, 0.95));
    summary["call_median_ms"] = percentile(calls, 0.5);
    summary["call_p95_ms"] = percentile(calls, 0.95);
  }
  std::printf(
      "times ms: ORB median %.1f p95 %.1f | tracking median %.1f p95 %.1f | local BA "
      "median %.1f p95 %.1f (%zu runs)\n",
      percentile(orb_ms, 0.5), percentile(orb_ms, 0.95), percentile(track_ms, 0.5),
      percentile(track_ms, 0.95), percentile(ba, 0.5), percentile(ba, 0.95), ba.size());
  summary["keyframes"] = slam.map().numKeyFrames();
  summary["map_points"] = slam.map().numPoints();
  summary["ate"] = ecar::toJson(overall);
  summary["scale"] = S.scale;
  summary["rotation_spread_deg"] = ecar::toJson(rotation);
  summary["map_tilt_deg"] = ecar::toJson(tilt);
  summary["gravity_sigma_deg"] = config.ba.gravity_sigma_deg;
  summary["times_ms"] = {
      {"orb_median", percentile(orb_ms, 0.5)},        {"orb_p95", percentile(orb_ms, 0.95)},
      {"tracking_median", percentile(track_ms, 0.5)}, {"tracking_p95", percentile(track_ms, 0.95)},
      {"local_ba_median", percentile(ba, 0.5)},       {"local_ba_p95", percentile(ba, 0.95)}};
  summary["wall_s"] = wall_s;
  offline::reportAtlasEvents(atlas, have_ate ? &slam : nullptr, S, runs, log, metric,
                             atlas_config.id_range, &summary);
  if (!args.summary.empty()) {
    std::ofstream out(args.summary);
    out << summary.dump(2) << "\n";
    if (!out) throw ecar::Error(args.summary + ": cannot write summary");
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  cv::setNumThreads(1);
  try {
    return run(offline::parse(argc, argv));
  } catch (const ecar::Error& e) {
    std::cerr << "ecar_slam_offline: " << e.what() << "\n";
    const std::string what = e.what();
    if (what.find("option") != std::string::npos || what.find("required") != std::string::npos) {
      offline::usage(std::cerr);
      return 2;
    }
    return 1;
  } catch (const std::exception& e) {
    std::cerr << "ecar_slam_offline: " << e.what() << "\n";
    return 1;
  }
}
