// ecar_slam_offline's command line: its options (Args), their help text and
// their parsing, each value checked against its range (ecar::Error names the
// option and what it got). Included by that tool only.
#pragma once

#include <cstdio>
#include <cstdlib>
#include <exception>
#include <iostream>
#include <stdexcept>
#include <string>
#include <vector>

#include "ecar_core/common/error.h"

namespace offline {

struct Args {
  std::vector<std::string> datasets;
  std::string format = "auto";
  int every = 1;
  int jpeg_quality = 0;  // 0: no compression
  int frames = 0;        // 0: all
  std::string out, summary;
  bool use_odometry = true;
  bool threads = false;
  bool loops = true;
  bool atlas = false;
  bool verbose = false;
  bool sequential = false;
  int orb_features = 0;             // 0: the library default
  double gravity_sigma_deg = -1.0;  // < 0: the library default
  double odometry_sigma = -1.0;     // < 0: the library default
  double odometry_walk = -1.0;      // < 0: the library default
  int ba_whole_map = -1;            // < 0: the library default
};

inline void usage(std::ostream& os) {
  os << "usage: ecar_slam_offline --dataset DIR [--format auto|sim|tum|kitti|euroc] [--every N]\n"
        "         [--jpeg-quality Q] [--frames N] [--out TRAJ.txt] [--summary FILE.json]\n"
        "         [--devices DIR2 ...] [--no-odometry] [--threads] [--orb-features N]\n"
        "         [--gravity-sigma DEG] [--odometry-sigma F] [--odometry-walk W]\n"
        "         [--ba-whole-map N] [--no-loops] [--atlas]\n"
        "  --every N         track every Nth frame (the server sees every 4th)\n"
        "  --jpeg-quality Q  JPEG-compress each image at quality Q (1-100) first\n"
        "  --frames N        only the first N frames of each dataset\n"
        "  --devices DIR...  more datasets (each with its own camera.yaml), run interleaved into\n"
        "                    the same map\n"
        "  --no-odometry     ignore the datasets' odometry (scale from median depth)\n"
        "  --threads         local mapping on its own thread (default: after each keyframe)\n"
        "  --verbose         one line per upload (state, tracked points, why it failed)\n"
        "  --sequential      run the datasets one after another (later ones join the map)\n"
        "  --orb-features N  ORB keypoints per image (default 1000; large images want more)\n"
        "  --gravity-sigma D gravity prior of local BA, degrees (0: off; default 0.3)\n"
        "  --no-loops        no loop closing (the figure without closing, beside it)\n"
        "  --atlas           several maps: a device that matches no map starts its own at once\n"
        "                    (and after being lost for 8 uploads); maps merge when they overlap\n"
        "                    (default: one map, later devices join it)\n"
        "  --odometry-sigma F odometry edges of local BA in metric maps: the scale-error part\n"
        "                    of their sigma, a fraction of the distance (default 0.02)\n"
        "  --odometry-walk W  their random-walk part, m per sqrt(m) (default 0; both 0:\n"
        "                    no odometry edges)\n"
        "  --ba-whole-map N  bundle-adjust a metric map whole while it has at most N keyframes\n"
        "                    (default 30; 0: windows only)\n";
}

inline Args parse(int argc, char** argv) {
  Args a;
  for (int i = 1; i < argc; ++i) {
    const std::string k = argv[i];
    auto value = [&]() -> std::string {
      if (i + 1 >= argc) throw ecar::Error("option " + k + " needs a value");
      return argv[++i];
    };
    auto integer = [&](int lo, int hi) {
      const std::string v = value();
      try {
        size_t used = 0;
        const int n = std::stoi(v, &used);
        if (used != v.size() || n < lo || n > hi) throw std::out_of_range(v);
        return n;
      } catch (const std::exception&) {
        throw ecar::Error("option " + k + " needs an integer in [" + std::to_string(lo) + ", " +
                          std::to_string(hi) + "] (got '" + v + "')");
      }
    };
    // A number in [lo, hi]; `what` names its unit in the error.
    auto real = [&](double lo, double hi, const char* what) {
      const std::string v = value();
      char* end = nullptr;
      const double x = std::strtod(v.c_str(), &end);
      if (end == v.c_str() || *end != '\0' || !(x >= lo && x <= hi)) {
        char range[64];
        std::snprintf(range, sizeof(range), "[%g, %g]", lo, hi);
        throw ecar::Error("option " + k + " needs " + what + " in " + range + " (got '" + v + "')");
      }
      return x;
    };
    if (k == "--dataset") {
      a.datasets.insert(a.datasets.begin(), value());
    } else if (k == "--devices") {
      while (i + 1 < argc && std::string(argv[i + 1]).rfind("--", 0) != 0) {
        a.datasets.push_back(argv[++i]);
      }
    } else if (k == "--format") {
      a.format = value();
    } else if (k == "--every") {
      a.every = integer(1, 1000);
    } else if (k == "--jpeg-quality") {
      a.jpeg_quality = integer(1, 100);
    } else if (k == "--frames") {
      a.frames = integer(0, 1 << 30);
    } else if (k == "--out") {
      a.out = value();
    } else if (k == "--summary") {
      a.summary = value();
    } else if (k == "--no-odometry") {
      a.use_odometry = false;
    } else if (k == "--atlas") {
      a.atlas = true;
    } else if (k == "--no-loops") {
      a.loops = false;
    } else if (k == "--threads") {
      a.threads = true;
    } else if (k == "--verbose") {
      a.verbose = true;
    } else if (k == "--sequential") {
      a.sequential = true;
    } else if (k == "--orb-features") {
      a.orb_features = integer(100, 100000);
    } else if (k == "--gravity-sigma") {
      a.gravity_sigma_deg = real(0.0, 90.0, "degrees");
    } else if (k == "--odometry-sigma") {
      a.odometry_sigma = real(0.0, 1.0, "a fraction");
    } else if (k == "--odometry-walk") {
      a.odometry_walk = real(0.0, 1.0, "metres per sqrt(m)");
    } else if (k == "--ba-whole-map") {
      a.ba_whole_map = integer(0, 500);
    } else if (k == "--help" || k == "-h") {
      usage(std::cout);
      std::exit(0);
    } else {
      throw ecar::Error("unknown option '" + k + "'");
    }
  }
  if (a.datasets.empty()) throw ecar::Error("--dataset is required");
  return a;
}

}  // namespace offline
