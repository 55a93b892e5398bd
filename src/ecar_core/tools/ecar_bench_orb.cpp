// Benchmark of OrbExtractor (1000 features, 8 levels, factor 1.2) on one
// thread: detectAndCompute, computeAt at its keypoints, and OpenCV's own ORB
// with the same settings for reference.
//   ecar_bench_orb [--image PATH] [--scene FILE] [--runs N]
// --image times N calls on one image (e.g. a KITTI frame); --scene renders 50
// frames along the scene's first device (with the scene's image noise) and
// times N calls on them in turn. Prints the median and p95 wall-clock ms per
// call, the median of the thread's CPU time (less inflated than wall clock on
// a busy machine) and the keypoints per call.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <string>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/features2d.hpp>
#include <opencv2/imgcodecs.hpp>

#include "ecar_core/common/error.h"
#include "ecar_core/common/timing.h"
#include "ecar_core/eval/trajectory_eval.h"
#include "ecar_core/sim/motion.h"
#include "ecar_core/sim/renderer.h"
#include "ecar_core/sim/scene.h"
#include "ecar_core/slam/features.h"

namespace {

using ecar::threadCpuMs;

using ecar::percentile;

struct Args {
  std::string image, scene;
  int runs = 200;
};

void usage() {
  std::cerr << "usage: ecar_bench_orb [--image PATH] [--scene FILE] [--runs N]\n"
               "  (at least one of --image and --scene)\n";
}

// Times `extract(frame)` over `runs` calls cycling through `frames` (after one
// warm-up call) and prints one line.
template <typename Extract>
void bench(const std::string& label, const std::vector<cv::Mat>& frames, int runs,
           Extract extract) {
  extract(frames[0]);
  std::vector<double> ms, cpu_ms;
  double keypoints = 0.0;
  for (int i = 0; i < runs; ++i) {
    const cv::Mat& frame = frames[static_cast<size_t>(i) % frames.size()];
    const double cpu0 = threadCpuMs();
    const auto t0 = std::chrono::steady_clock::now();
    const size_t n = extract(frame);
    ms.push_back(
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
    cpu_ms.push_back(threadCpuMs() - cpu0);
    keypoints += static_cast<double>(n);
  }
  std::printf("  %-24s median %6.2f ms  p95 %6.2f ms  (cpu median %6.2f ms)  keypoints %.0f\n",
              label.c_str(), percentile(ms, 0.5), percentile(ms, 0.95), percentile(cpu_ms, 0.5),
              keypoints / runs);
}

void benchFrames(const std::string& title, const std::vector<cv::Mat>& frames, int runs) {
  std::printf("%s: %dx%d, %zu frame(s), %d runs, 1 thread\n", title.c_str(), frames[0].cols,
              frames[0].rows, frames.size(), runs);
  ecar::OrbExtractor extractor;  // defaults: 1000 features, 8 levels, 1.2
  std::vector<cv::KeyPoint> kps;
  cv::Mat desc;
  bench("OrbExtractor", frames, runs, [&](const cv::Mat& f) {
    extractor.detectAndCompute(f, &kps, &desc);
    return kps.size();
  });
  std::vector<uint8_t> valid;
  extractor.detectAndCompute(frames[0], &kps, &desc);
  const std::vector<cv::KeyPoint> at = kps;
  bench("OrbExtractor::computeAt", frames, runs, [&](const cv::Mat& f) {
    extractor.computeAt(f, at, &desc, &valid);
    return at.size();
  });
  auto orb = cv::ORB::create(1000, 1.2f, 8);
  bench("cv::ORB (reference)", frames, runs, [&](const cv::Mat& f) {
    orb->detectAndCompute(f, cv::noArray(), kps, desc);
    return kps.size();
  });
}

}  // namespace

int main(int argc, char** argv) {
  Args a;
  for (int i = 1; i < argc; ++i) {
    const std::string k = argv[i];
    if (i + 1 >= argc) {
      usage();
      return 2;
    }
    if (k == "--image") {
      a.image = argv[++i];
    } else if (k == "--scene") {
      a.scene = argv[++i];
    } else if (k == "--runs") {
      a.runs = std::max(1, std::atoi(argv[++i]));
    } else {
      usage();
      return 2;
    }
  }
  if (a.image.empty() && a.scene.empty()) {
    usage();
    return 2;
  }
  try {
    cv::setNumThreads(1);
    if (!a.scene.empty()) {
      const ecar::Scene scene = ecar::loadScene(a.scene);
      if (scene.devices.empty()) throw ecar::Error(a.scene + ": scene has no devices");
      const ecar::Renderer renderer(scene);
      const auto motion = ecar::generateMotion(scene, scene.devices.front(), scene.camera.fps);
      ecar::RenderOptions options;
      options.noise_sigma = static_cast<float>(scene.noise_sigma);
      ecar::RenderOutput out;
      std::vector<cv::Mat> frames;
      const size_t count = std::min<size_t>(50, motion.size());
      for (size_t k = 0; k < count; ++k) {
        const size_t i = k * motion.size() / count;
        options.noise_seed = static_cast<uint32_t>(i);
        renderer.render(motion[i].T_w_c, options, &out);
        frames.push_back(out.image.clone());
      }
      if (frames.empty()) throw ecar::Error(a.scene + ": the first device has no motion");
      benchFrames("scene " + scene.name, frames, a.runs);
    }
    if (!a.image.empty()) {
      const cv::Mat image = cv::imread(a.image, cv::IMREAD_GRAYSCALE);
      if (image.empty()) throw ecar::Error(a.image + ": cannot read the image");
      benchFrames(a.image, {image}, a.runs);
    }
  } catch (const std::exception& e) {
    std::cerr << "ecar_bench_orb: " << e.what() << "\n";
    return 1;
  }
  return 0;
}
