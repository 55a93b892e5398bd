// Benchmark of the synthetic world renderer (and of how many ORB keypoints its
// images give), on one core:
//   ecar_bench_render --scene config/scenes/corridor.yaml [--device NAME]
//                     [--frames N] [--every K] [--color] [--orb]
// Prints the median / mean / p95 render time per frame and, with --orb, the
// ORB keypoints per frame split by surface label.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <iostream>
#include <numeric>
#include <string>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/features2d.hpp>

#include "ecar_core/common/error.h"
#include "ecar_core/eval/trajectory_eval.h"
#include "ecar_core/sim/motion.h"
#include "ecar_core/sim/renderer.h"
#include "ecar_core/sim/scene.h"

namespace {

using ecar::percentile;

struct Args {
  std::string scene, device;
  int frames = 200, every = 1;
  bool color = false, orb = false;
};

void usage() {
  std::cerr << "usage: ecar_bench_render --scene FILE [--device NAME] [--frames N] [--every K] "
               "[--color] [--orb]\n";
}

}  // namespace

int main(int argc, char** argv) {
  Args a;
  for (int i = 1; i < argc; ++i) {
    const std::string k = argv[i];
    auto next = [&]() -> std::string {
      if (i + 1 >= argc) {
        usage();
        std::exit(2);
      }
      return argv[++i];
    };
    if (k == "--scene")
      a.scene = next();
    else if (k == "--device")
      a.device = next();
    else if (k == "--frames")
      a.frames = std::stoi(next());
    else if (k == "--every")
      a.every = std::max(1, std::stoi(next()));
    else if (k == "--color")
      a.color = true;
    else if (k == "--orb")
      a.orb = true;
    else {
      usage();
      return 2;
    }
  }
  if (a.scene.empty()) {
    usage();
    return 2;
  }
  try {
    cv::setNumThreads(1);
    const auto t_load = std::chrono::steady_clock::now();
    const ecar::Scene scene = ecar::loadScene(a.scene);
    if (scene.devices.empty()) throw ecar::Error(a.scene + ": scene has no devices");
    const ecar::DeviceSpec& dev = a.device.empty() ? scene.devices.front() : scene.device(a.device);
    const ecar::Renderer renderer(scene);
    const double setup_s =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t_load).count();
    const auto motion = ecar::generateMotion(scene, dev, scene.camera.fps);
    ecar::RenderOptions opt;
    opt.color = a.color;
    opt.noise_sigma = static_cast<float>(scene.noise_sigma);
    ecar::RenderOutput out;
    std::vector<double> ms;
    std::vector<double> kp_total, kp_label[5];
    auto orb = cv::ORB::create(1000, 1.2f, 8);
    int rendered = 0;
    for (size_t i = 0; i < motion.size() && rendered < a.frames; i += a.every, ++rendered) {
      opt.noise_seed = static_cast<uint32_t>(i);
      const auto t0 = std::chrono::steady_clock::now();
      renderer.render(motion[i].T_w_c, opt, &out);
      ms.push_back(
          std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
      if (a.orb) {
        std::vector<cv::KeyPoint> kps;
        orb->detect(out.image, kps);
        kp_total.push_back(static_cast<double>(kps.size()));
        int per[5] = {0, 0, 0, 0, 0};
        for (const auto& kp : kps) {
          ++per[out.labels.at<uint8_t>(cvRound(kp.pt.y), cvRound(kp.pt.x))];
        }
        for (int l = 0; l < 5; ++l) kp_label[l].push_back(per[l]);
      }
    }
    const double mean = std::accumulate(ms.begin(), ms.end(), 0.0) / std::max<size_t>(1, ms.size());
    std::printf("scene %s, device %s, %dx%d %s, %zu frames (every %d of %zu)\n", scene.name.c_str(),
                dev.name.c_str(), renderer.camera().width(), renderer.camera().height(),
                a.color ? "colour" : "grey", ms.size(), a.every, motion.size());
    std::printf("setup (textures): %.2f s\n", setup_s);
    std::printf("render ms/frame: median %.2f  mean %.2f  p95 %.2f  max %.2f\n",
                percentile(ms, 0.5), mean, percentile(ms, 0.95), percentile(ms, 1.0));
    if (a.orb) {
      auto avg = [](const std::vector<double>& v) {
        return std::accumulate(v.begin(), v.end(), 0.0) / std::max<size_t>(1, v.size());
      };
      std::printf(
          "ORB (1000, 1.2, 8) keypoints/frame: mean %.0f  min %.0f  | floor %.0f  wall %.0f"
          "  ceiling %.0f  object %.0f\n",
          avg(kp_total), percentile(kp_total, 0.0), avg(kp_label[1]), avg(kp_label[2]),
          avg(kp_label[3]), avg(kp_label[4]));
    }
  } catch (const std::exception& e) {
    std::cerr << "ecar_bench_render: " << e.what() << "\n";
    return 1;
  }
  return 0;
}
