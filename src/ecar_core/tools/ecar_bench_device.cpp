// Benchmark of the device side (DeviceTracker) on one thread, without ROS: a
// scene's device walk is rendered first (with the scene's image noise); the
// server's SLAM aligns every 4th frame (JPEG quality 70, gravity, odometry),
// the local graph composer answers each aligned upload in eCAR mode, and the
// graph reaches the device --delay frames later, as a round trip would; the
// device tracks every frame on its own uncompressed image.
//   ecar_bench_device [--scene FILE] [--device NAME] [--frames N] [--delay D]
//                     [--orb-features N]
// (defaults: config/scenes/corridor.yaml, device_0, 300 frames, delay 2)
// Prints the median and p95 wall-clock ms of DeviceTracker::track per frame
// (and of its ORB and tracking parts), of addLocalGraph per graph, the median
// thread CPU time per frame, and the frames tracked. Under
// `valgrind --tool=callgrind` the inclusive cost of DeviceTracker::track over
// the frames is the device's instruction count per frame.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <deque>
#include <iostream>
#include <string>
#include <vector>

#include <opencv2/imgcodecs.hpp>

#include "ecar_core/common/error.h"
#include "ecar_core/device/device_tracker.h"
#include "ecar_core/eval/trajectory_eval.h"
#include "ecar_core/sim/motion.h"
#include "ecar_core/sim/renderer.h"
#include "ecar_core/sim/scene.h"
#include "ecar_core/slam/slam_system.h"
#include "ecar_core/sync/local_graph_composer.h"

namespace {

using ecar::percentile;

struct Args {
  std::string scene = "config/scenes/corridor.yaml";  // from the repository's root
  std::string device = "device_0";
  int frames = 300;
  int delay = 2;
  int orb_features = 0;  // 0: DeviceTrackerConfig's default
};

void usage() {
  std::cerr << "usage: ecar_bench_device [--scene FILE] [--device NAME] [--frames N] "
               "[--delay D] [--orb-features N]\n";
}

Args parse(int argc, char** argv) {
  Args a;
  for (int i = 1; i < argc; ++i) {
    const std::string k = argv[i];
    if (k == "--help" || k == "-h") {
      usage();
      std::exit(0);
    }
    if (i + 1 >= argc) throw ecar::Error("option " + k + " needs a value");
    const std::string v = argv[++i];
    const auto integer = [&](int lo, int hi) {
      char* end = nullptr;
      const long x = std::strtol(v.c_str(), &end, 10);
      if (end == v.c_str() || *end != '\0' || x < lo || x > hi) {
        throw ecar::Error(k + " must be an integer in [" + std::to_string(lo) + ", " +
                          std::to_string(hi) + "] (got '" + v + "')");
      }
      return static_cast<int>(x);
    };
    if (k == "--scene") {
      a.scene = v;
    } else if (k == "--device") {
      a.device = v;
    } else if (k == "--frames") {
      a.frames = integer(8, 100000);
    } else if (k == "--delay") {
      a.delay = integer(0, 1000);
    } else if (k == "--orb-features") {
      a.orb_features = integer(100, 20000);
    } else {
      throw ecar::Error("unknown option " + k);
    }
  }
  return a;
}

struct Upload {
  int deliver_at = 0;
  int frame = 0;
  ecar::LocalGraph graph;
};

int run(const Args& args) {
  const ecar::Scene scene = ecar::loadScene(args.scene);
  const ecar::Renderer renderer(scene);
  const auto motion =
      ecar::generateMotion(scene, scene.device(args.device), scene.camera.fps, args.frames);
  ecar::RenderOptions opt;
  opt.noise_sigma = static_cast<float>(scene.noise_sigma);
  opt.depth = opt.labels = false;
  std::vector<cv::Mat> images;
  images.reserve(motion.size());
  ecar::RenderOutput out;
  for (size_t i = 0; i < motion.size(); ++i) {
    opt.noise_seed = static_cast<uint32_t>(i);
    renderer.render(motion[i].T_w_c, opt, &out);
    images.push_back(out.image.clone());
  }

  ecar::SlamSystem slam(renderer.camera());
  ecar::DeviceTrackerConfig config;
  if (args.orb_features > 0) config.orb.num_features = args.orb_features;
  ecar::DeviceTracker device(renderer.camera(), config);
  const ecar::LocalGraphComposer composer;
  ecar::DeviceSyncState sync(device.config().keyframe_queue);
  const ecar::ComposerLookups lookups;
  std::deque<Upload> in_flight;
  std::vector<double> total_ms, orb_ms, track_ms, cpu_ms, graph_ms;
  int tracked = 0, after_graph = 0;
  bool graph_seen = false;
  std::vector<uint8_t> jpeg;
  for (int i = 0; i < static_cast<int>(images.size()); ++i) {
    while (!in_flight.empty() && in_flight.front().deliver_at <= i) {
      const Upload& u = in_flight.front();
      graph_ms.push_back(device.addLocalGraph(images[u.frame], u.graph).ms);
      graph_seen = true;
      in_flight.pop_front();
    }
    if (i % 4 == 0) {
      cv::imencode(".jpg", images[i], jpeg, {cv::IMWRITE_JPEG_QUALITY, 70});
      const ecar::TrackResult r = slam.track(
          ecar::DeviceId(1), cv::imdecode(jpeg, cv::IMREAD_GRAYSCALE), motion[i].timestamp,
          static_cast<uint32_t>(i), motion[i].gravity_c, motion[i].T_o_c);
      if (r.state == ecar::TrackingState::kOk) {
        ecar::ComposerInput in;
        in.device = args.device;
        in.frame_index = static_cast<uint32_t>(i);
        in.map_epoch = r.map_epoch;
        in.frame = &r;
        in.mode = ecar::SyncMode::kEcar;
        if (auto graph = composer.compose(slam.map(), in, lookups, &sync)) {
          in_flight.push_back({i + args.delay, i, std::move(*graph)});
        }
      }
    }
    const ecar::DeviceTrackResult& t =
        device.track(images[i], motion[i].timestamp, static_cast<uint32_t>(i));
    if (!graph_seen) continue;
    ++after_graph;
    if (t.state == ecar::TrackingState::kOk) ++tracked;
    total_ms.push_back(t.total_ms);
    orb_ms.push_back(t.orb_ms);
    track_ms.push_back(t.track_ms);
    cpu_ms.push_back(t.cpu_ms);
  }
  if (total_ms.empty()) {
    std::fprintf(stderr, "ecar_bench_device: no local graph reached the device in %d frames\n",
                 args.frames);
    return 1;
  }
  std::printf(
      "%s/%s, %d frames, %d features: tracked %d of %d frames after the first graph\n"
      "track() ms: median %.2f p95 %.2f (ORB median %.2f, tracking median %.2f); thread CPU "
      "median %.2f ms\n"
      "addLocalGraph() ms: median %.2f p95 %.2f over %zu graphs\n",
      scene.name.c_str(), args.device.c_str(), args.frames, device.config().orb.num_features,
      tracked, after_graph, percentile(total_ms, 0.5), percentile(total_ms, 0.95),
      percentile(orb_ms, 0.5), percentile(track_ms, 0.5), percentile(cpu_ms, 0.5),
      percentile(graph_ms, 0.5), percentile(graph_ms, 0.95), graph_ms.size());
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  try {
    return run(parse(argc, argv));
  } catch (const ecar::Error& e) {
    std::cerr << "ecar_bench_device: " << e.what() << "\n";
    usage();
    return 2;
  }
}
