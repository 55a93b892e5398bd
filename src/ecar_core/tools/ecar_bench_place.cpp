// Benchmark of the place recognition index on a synthetic trajectory, on one
// core:
//   ecar_bench_place [--keyframes N] [--features M] [--queries Q]
//                    [--tables T] [--bits B] [--seed S]
// Keyframe k observes M landmarks starting at landmark k * M / 5 (consecutive
// keyframes share 80% of their landmarks), each landmark's descriptor with
// 0-15 bit flips. A query re-observes a random keyframe: 60% of its landmarks
// with 10-25 bit flips plus 40% unrelated descriptors. Prints the index memory,
// the add time per keyframe, the median / p95 query time and how often the
// best candidate is within 2 keyframes of the true one. Then the same for the
// KeypointIndex (relocalisation / joining by keypoint matches) with the first
// --keypoint-rows descriptors of each keyframe indexed (those with map
// points): query time and the share of re-observed landmarks whose true
// keypoint is among the hits.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <numeric>
#include <random>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "ecar_core/common/error.h"
#include "ecar_core/common/timing.h"
#include "ecar_core/eval/trajectory_eval.h"
#include "ecar_core/slam/matcher.h"
#include "ecar_core/slam/place_recognition.h"

namespace {

using ecar::threadCpuMs;

using ecar::percentile;

struct Args {
  int keyframes = 5000, features = 1000, queries = 200, keypoint_rows = 500;
  ecar::PlaceIndexConfig index;
  ecar::KeypointIndexConfig keypoints;
};

void usage() {
  std::cerr << "usage: ecar_bench_place [--keyframes N] [--features M] [--queries Q] "
               "[--tables T] [--bits B] [--seed S] [--keypoint-rows R] [--keypoint-tables T] "
               "[--keypoint-bits B]\n";
}

double msSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

// CPU time of this thread (ms): on a loaded machine, wall time overstates.
void randomDescriptor(std::mt19937_64* rng, uint8_t* out) {
  for (int i = 0; i < 4; ++i) {
    const uint64_t v = (*rng)();
    for (int b = 0; b < 8; ++b) out[8 * i + b] = static_cast<uint8_t>(v >> (8 * b));
  }
}

void flipBits(std::mt19937_64* rng, int flips, uint8_t* descriptor) {
  for (int i = 0; i < flips; ++i) {  // may flip a bit twice: at most `flips`
    const unsigned bit = (*rng)() % 256;
    descriptor[bit >> 3] ^= static_cast<uint8_t>(1u << (bit & 7));
  }
}

}  // namespace

int main(int argc, char** argv) {
  Args a;
  for (int i = 1; i < argc; ++i) {
    const std::string k = argv[i];
    auto next = [&]() -> int {
      if (i + 1 >= argc) {
        usage();
        std::exit(2);
      }
      return std::stoi(argv[++i]);
    };
    if (k == "--keyframes")
      a.keyframes = std::max(1, next());
    else if (k == "--features")
      a.features = std::max(5, next());
    else if (k == "--queries")
      a.queries = std::max(1, next());
    else if (k == "--tables")
      a.index.tables = next();
    else if (k == "--bits")
      a.index.bits = next();
    else if (k == "--seed")
      a.index.seed = static_cast<uint32_t>(next());
    else if (k == "--keypoint-rows")
      a.keypoint_rows = std::max(1, next());
    else if (k == "--keypoint-tables")
      a.keypoints.tables = next();
    else if (k == "--keypoint-bits")
      a.keypoints.bits = next();
    else {
      usage();
      return 2;
    }
  }
  try {
    std::mt19937_64 rng(42);
    const int step = a.features / 5;
    const int landmarks_total = step * (a.keyframes - 1) + a.features;
    cv::Mat landmarks(landmarks_total, 32, CV_8U);
    for (int l = 0; l < landmarks_total; ++l) randomDescriptor(&rng, landmarks.ptr<uint8_t>(l));

    ecar::PlaceIndex index(a.index);
    ecar::KeypointIndex keypoint_index(a.keypoints);
    std::vector<int> indexed_rows(static_cast<size_t>(std::min(a.keypoint_rows, a.features)));
    std::iota(indexed_rows.begin(), indexed_rows.end(), 0);
    std::vector<double> add_ms, add_cpu_ms;
    cv::Mat d(a.features, 32, CV_8U);
    for (int k = 0; k < a.keyframes; ++k) {
      for (int f = 0; f < a.features; ++f) {
        landmarks.row(k * step + f).copyTo(d.row(f));
        flipBits(&rng, static_cast<int>(rng() % 16), d.ptr<uint8_t>(f));
      }
      const auto t0 = std::chrono::steady_clock::now();
      const double cpu0 = threadCpuMs();
      index.add(ecar::KeyFrameId(k + 1), d);
      add_cpu_ms.push_back(threadCpuMs() - cpu0);
      add_ms.push_back(msSince(t0));
      keypoint_index.add(ecar::KeyFrameId(k + 1), d, indexed_rows);
    }
    const double memory_mb = static_cast<double>(index.memoryBytes()) / (1024.0 * 1024.0);

    std::vector<double> query_ms, query_cpu_ms, keypoint_cpu_ms;
    int keypoint_indexed = 0, keypoint_found = 0;
    int near = 0;
    std::vector<int> order(a.features);
    for (int q = 0; q < a.queries; ++q) {
      const int k = static_cast<int>(rng() % a.keyframes);
      std::iota(order.begin(), order.end(), 0);
      std::shuffle(order.begin(), order.end(), rng);
      const int seen = a.features * 6 / 10;
      for (int f = 0; f < a.features; ++f) {
        if (f < seen) {
          landmarks.row(k * step + order[f]).copyTo(d.row(f));
          flipBits(&rng, 10 + static_cast<int>(rng() % 16), d.ptr<uint8_t>(f));
        } else {
          randomDescriptor(&rng, d.ptr<uint8_t>(f));
        }
      }
      const auto t0 = std::chrono::steady_clock::now();
      const double cpu0 = threadCpuMs();
      const auto candidates = index.query(d);
      query_cpu_ms.push_back(threadCpuMs() - cpu0);
      query_ms.push_back(msSince(t0));
      if (!candidates.empty() &&
          std::abs(static_cast<int>(candidates[0].keyframe.value) - 1 - k) <= 2)
        ++near;

      // Keypoint index: a hit is right when it is the landmark's own keypoint
      // in one of the keyframes that indexed it.
      const double kcpu0 = threadCpuMs();
      const auto hits = keypoint_index.query(d, ecar::kDescriptorThresholdLow, 4);
      keypoint_cpu_ms.push_back(threadCpuMs() - kcpu0);
      std::vector<bool> found(static_cast<size_t>(seen), false);
      for (const auto& h : hits) {
        if (h.query_row >= seen) continue;
        const int landmark = k * step + order[h.query_row];
        if (landmark - static_cast<int>(h.keyframe.value - 1) * step == h.row) {
          found[h.query_row] = true;
        }
      }
      for (int f = 0; f < seen; ++f) {
        const int landmark = k * step + order[f];
        // Indexed somewhere: by keyframe k' at row landmark - k' * step < rows.
        bool indexed = false;
        for (int kk = std::max(0, landmark / step - 5); kk <= landmark / step && !indexed; ++kk) {
          const int row = landmark - kk * step;
          indexed = kk < a.keyframes && row >= 0 && row < static_cast<int>(indexed_rows.size());
        }
        if (!indexed) continue;
        ++keypoint_indexed;
        keypoint_found += found[f] ? 1 : 0;
      }
    }

    auto mean = [](const std::vector<double>& v) {
      return std::accumulate(v.begin(), v.end(), 0.0) / static_cast<double>(v.size());
    };
    const std::vector<double> last_adds(add_ms.end() - std::max<size_t>(1, add_ms.size() / 10),
                                        add_ms.end());
    std::printf("index: %d keyframes x %d descriptors, %d tables x %d bits\n", a.keyframes,
                a.features, a.index.tables, a.index.bits);
    std::printf("memory estimate: %.1f MB (%.1f bytes per descriptor)\n", memory_mb,
                memory_mb * 1024.0 * 1024.0 / (static_cast<double>(a.keyframes) * a.features));
    std::printf(
        "add ms/keyframe: mean %.3f  median %.3f  p95 %.3f  max %.3f  last 10%% mean %.3f"
        "  (cpu mean %.3f)\n",
        mean(add_ms), percentile(add_ms, 0.5), percentile(add_ms, 0.95), percentile(add_ms, 1.0),
        mean(last_adds), mean(add_cpu_ms));
    std::printf(
        "query ms (%d descriptors): median %.3f  p95 %.3f  max %.3f  (cpu median %.3f  p95 "
        "%.3f)\n",
        a.features, percentile(query_ms, 0.5), percentile(query_ms, 0.95),
        percentile(query_ms, 1.0), percentile(query_cpu_ms, 0.5), percentile(query_cpu_ms, 0.95));
    std::printf("best candidate within 2 keyframes: %d of %d queries\n", near, a.queries);
    std::printf(
        "keypoint index: %zu entries (%d tables x %d bits); query cpu ms (%d descriptors): "
        "median %.3f  p95 %.3f; true keypoint among the hits for %.1f%% of re-observed "
        "landmarks\n",
        keypoint_index.entries(), a.keypoints.tables, a.keypoints.bits, a.features,
        percentile(keypoint_cpu_ms, 0.5), percentile(keypoint_cpu_ms, 0.95),
        100.0 * keypoint_found / std::max(1, keypoint_indexed));
  } catch (const std::exception& e) {
    std::cerr << "ecar_bench_place: " << e.what() << "\n";
    return 1;
  }
  return 0;
}
