// Benchmark of the grid connection and the plane segmentation, on one core:
//   ecar_bench_grid [--window W] [--runs N] [--points P]
// Grid: a 30 x 2.4 x 2.7 m corridor (floor, ceiling, two side walls, two end
// walls: 6 planes), a 640 x 480 camera (fx = 525), poses every 2 m along it
// looking down the corridor with some pitch and yaw. Prints the median / p95 /
// max thread CPU time of visibleCells() per call, the samples and cells per
// call, and the time of isVisible() and of building GridPlanes.
// Planes: P map points on a 6 m corridor section with 1 cm noise and 10%
// outliers; prints the time of PlaneSegmenter::segment and PlaneMap::integrate.
#include <algorithm>
#include <cstdlib>
#include <iostream>
#include <random>
#include <string>
#include <vector>

#include "ecar_core/common/error.h"
#include "ecar_core/common/timing.h"
#include "ecar_core/structure/grid_caster.h"
#include "ecar_core/structure/grid_map.h"
#include "ecar_core/structure/plane_map.h"

namespace {

using ecar::threadCpuMs;

// CPU time of this thread (ms): on a loaded machine, wall time overstates.
double percentileOf(std::vector<double> v, double q) {
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, static_cast<size_t>(q * static_cast<double>(v.size())))];
}

ecar::Plane box(uint32_t id, const Eigen::Vector3d& n, double d,
                const std::vector<Eigen::Vector3d>& corners) {
  ecar::Plane p;
  p.id = ecar::PlaneId(id);
  p.normal = n;
  p.offset = d;
  p.boundary = ecar::planeHull(corners, n, d);
  p.version = 1;
  return p;
}

std::vector<ecar::Plane> corridorPlanes() {
  using V = Eigen::Vector3d;
  const double L = 30.0, W = 2.4, H = 2.7;
  return {
      box(1, V::UnitZ(), 0.0, {{0, 0, 0}, {L, 0, 0}, {L, W, 0}, {0, W, 0}}),
      box(2, -V::UnitZ(), H, {{0, 0, H}, {L, 0, H}, {L, W, H}, {0, W, H}}),
      box(3, V::UnitY(), 0.0, {{0, 0, 0}, {L, 0, 0}, {L, 0, H}, {0, 0, H}}),
      box(4, -V::UnitY(), W, {{0, W, 0}, {L, W, 0}, {L, W, H}, {0, W, H}}),
      box(5, V::UnitX(), 0.0, {{0, 0, 0}, {0, W, 0}, {0, W, H}, {0, 0, H}}),
      box(6, -V::UnitX(), L, {{L, 0, 0}, {L, W, 0}, {L, W, H}, {L, 0, H}}),
  };
}

int run(int argc, char** argv) {
  int window = 5, runs = 200, points = 2000;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (i + 1 >= argc) throw ecar::Error("missing value after " + a);
    const int v = std::atoi(argv[++i]);
    if (a == "--window") {
      window = v;
    } else if (a == "--runs") {
      runs = std::max(1, v);
    } else if (a == "--points") {
      points = std::max(10, v);
    } else {
      throw ecar::Error("unknown option " + a +
                        " (usage: ecar_bench_grid [--window W] [--runs N] [--points P])");
    }
  }

  ecar::CameraParams cp;  // 640 x 480, fx = fy = 525
  const ecar::PinholeCamera camera(cp);
  ecar::GridConfig config;
  config.window = window;
  const ecar::GridCaster grid(config, camera);
  const std::vector<ecar::Plane> planes = corridorPlanes();

  double t0 = threadCpuMs();
  const int prepare_runs = 1000;
  size_t kept = 0;
  for (int i = 0; i < prepare_runs; ++i) kept += ecar::GridPlanes(planes, 0.1).size();
  const double prepare_ms = (threadCpuMs() - t0) / prepare_runs;
  const ecar::GridPlanes prepared(planes, config.boundary_margin);

  std::vector<ecar::SE3> poses;
  for (double x = 1.0; x < 29.0; x += 2.0) {
    poses.push_back(ecar::lookAt(Eigen::Vector3d(x, 1.0, 1.5),
                                 Eigen::Vector3d(x + 6.0, 1.4 + 0.3 * std::sin(x), 0.6)));
    poses.push_back(ecar::lookAt(Eigen::Vector3d(x, 1.4, 1.6), Eigen::Vector3d(30.0, 1.2, 1.3)));
  }
  std::vector<ecar::CellKey> cells;
  std::vector<double> times;
  size_t total_cells = 0;
  for (int r = 0; r < runs; ++r) {
    for (const auto& T_w_c : poses) {
      t0 = threadCpuMs();
      grid.visibleCells(T_w_c, prepared, &cells);
      times.push_back(threadCpuMs() - t0);
      total_cells += cells.size();
    }
  }
  t0 = threadCpuMs();
  int visible = 0;
  const int vis_runs = 100000;
  for (int i = 0; i < vis_runs; ++i) {
    visible += grid.isVisible(poses[i % poses.size()], prepared,
                              Eigen::Vector3d(2.0 + (i % 27), 1.2, 0.0));
  }
  const double vis_us = 1e3 * (threadCpuMs() - t0) / vis_runs;

  std::cout << "grid: " << cp.width << "x" << cp.height << ", window " << window << " px, "
            << grid.numSamples() << " samples, " << kept / prepare_runs << " planes, "
            << poses.size() << " poses x " << runs << " runs\n"
            << "  visibleCells  median " << percentileOf(times, 0.5) << " ms, p95 "
            << percentileOf(times, 0.95) << " ms, max " << percentileOf(times, 1.0)
            << " ms (thread CPU), " << total_cells / times.size() << " cells per call\n"
            << "  isVisible     " << vis_us << " us per point (" << visible << " of " << vis_runs
            << " visible)\n"
            << "  GridPlanes    " << 1e3 * prepare_ms << " us to prepare " << planes.size()
            << " planes\n";

  // ---- coverage: share of the corridor's floor cells hit, by distance, from
  // x = 0.5 looking straight down the corridor (what the sampling reaches).
  const ecar::SE3 T_end =
      ecar::lookAt(Eigen::Vector3d(0.5, 1.2, 1.5), Eigen::Vector3d(30.0, 1.2, 1.5));
  grid.visibleCells(T_end, prepared, &cells);
  std::cout << "  floor cells hit from x = 0.5 m looking along the corridor (exact / within 1 "
               "cell):";
  for (int band = 0; band < 30; band += 5) {
    int total = 0, hit = 0, near = 0;
    for (int x = band * 10; x < (band + 5) * 10; ++x) {
      for (int y = 0; y < 24; ++y) {
        if (x < 5) continue;  // behind the camera
        ++total;
        hit += ecar::containsCell(cells, ecar::CellKey{x, y, 0});
        near += ecar::containsCell(cells, ecar::CellKey{x, y, 0}, 1);
      }
    }
    std::cout << " [" << band << ", " << band + 5 << ") m " << 100 * hit / std::max(1, total)
              << "% / " << 100 * near / std::max(1, total) << "%;";
  }
  std::cout << "\n";

  // ---- plane segmentation on one keyframe's points
  std::mt19937 rng(1);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::normal_distribution<double> g(0.0, 0.01);
  ecar::PlaneKeyFrameInput in;
  in.keyframe = ecar::KeyFrameId(1);
  in.camera_center_w = Eigen::Vector3d(1.0, 1.2, 1.5);
  in.up_w = Eigen::Vector3d::UnitZ();
  const int inliers = points * 9 / 10;
  for (int i = 0; i < points; ++i) {
    Eigen::Vector3d p(6.0 * u(rng), 2.4 * u(rng), 2.7 * u(rng));
    if (i < inliers) {
      switch (i % 4) {
        case 0:
          p.z() = g(rng);
          break;
        case 1:
          p.z() = 2.7 + g(rng);
          break;
        case 2:
          p.y() = g(rng);
          break;
        default:
          p.y() = 2.4 + g(rng);
          break;
      }
    }
    in.points.push_back({ecar::MapPointId(static_cast<uint32_t>(i + 1)), p});
  }
  const ecar::PlaneConfig plane_config;
  const ecar::PlaneSegmenter segmenter(plane_config);
  std::vector<double> seg_times, int_times;
  size_t found = 0;
  for (int r = 0; r < 20; ++r) {
    ecar::PlaneMap map(plane_config);
    t0 = threadCpuMs();
    const auto obs = segmenter.segment(in);
    seg_times.push_back(threadCpuMs() - t0);
    found = obs.size();
    t0 = threadCpuMs();
    map.integrate(in, obs);
    in.keyframe = ecar::KeyFrameId(2);
    map.integrate(in, obs);  // the same planes seen again: merge and refit
    in.keyframe = ecar::KeyFrameId(1);
    int_times.push_back((threadCpuMs() - t0) / 2.0);
  }
  std::cout << "planes: " << points << " points, " << found << " planes found\n"
            << "  segment       median " << percentileOf(seg_times, 0.5) << " ms ("
            << plane_config.iterations << " RANSAC iterations per plane)\n"
            << "  integrate     median " << percentileOf(int_times, 0.5) << " ms\n";
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  try {
    return run(argc, argv);
  } catch (const std::exception& e) {
    std::cerr << "ecar_bench_grid: " << e.what() << "\n";
    return 1;
  }
}
