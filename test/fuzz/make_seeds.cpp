// Writes the seed corpora of the fuzz targets into DIR/<target>/ (the ones in
// test/fuzz/corpus were made by this program: `make_seeds test/fuzz/corpus`).
// Seeds are small valid inputs for the fuzzer to mutate: a map file of a short
// corridor session (a few keyframes, planes, a VO and a tombstone), JPEGs of a
// 64x48 camera, shipped scenes, and byte strings for the structured targets.
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <string>
#include <vector>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "ecar_core/server/global_graph.h"
#include "ecar_core/sim/motion.h"
#include "ecar_core/sim/renderer.h"
#include "ecar_core/sim/scene.h"
#include "ecar_core/slam/slam_system.h"

namespace fs = std::filesystem;

namespace {

void write(const fs::path& path, const std::vector<uint8_t>& bytes) {
  fs::create_directories(path.parent_path());
  std::ofstream(path, std::ios::binary)
      .write(reinterpret_cast<const char*>(bytes.data()),
             static_cast<std::streamsize>(bytes.size()));
}

std::vector<uint8_t> jpeg(const cv::Mat& image, int quality, bool progressive) {
  std::vector<uint8_t> out;
  cv::imencode(".jpg", image, out,
               {cv::IMWRITE_JPEG_QUALITY, quality, cv::IMWRITE_JPEG_PROGRESSIVE, progressive});
  return out;
}

std::vector<uint8_t> bytes(size_t n, uint32_t seed) {
  std::vector<uint8_t> out(n);
  for (size_t i = 0; i < n; ++i) {
    seed = seed * 1664525u + 1013904223u;
    out[i] = static_cast<uint8_t>(seed >> 24);
  }
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 3) {
    std::cerr << "usage: make_seeds OUT_DIR REPO_ROOT\n";
    return 2;
  }
  const fs::path out(argv[1]), repo(argv[2]);

  // map_file: a short corridor session's SLAM map (a few keyframes, as a one-map file), and
  // a server's whole atlas file with planes' and VOs' sections (a VO and a tombstone).
  {
    const ecar::Scene scene = ecar::loadScene((repo / "config/scenes/corridor.yaml").string());
    ecar::Renderer renderer(scene);
    ecar::SlamSystem slam(renderer.camera());
    const auto motion = ecar::generateMotion(scene, scene.device("device_0"), 30.0);
    ecar::RenderOptions opt;
    opt.noise_sigma = static_cast<float>(scene.noise_sigma);
    ecar::RenderOutput r;
    // As devices upload: every 4th frame through JPEG; a few keyframes.
    for (size_t i = 0; i < motion.size() && i < 40; i += 4) {
      opt.noise_seed = static_cast<uint32_t>(i);
      renderer.render(motion[i].T_w_c, opt, &r);
      std::vector<uint8_t> j;
      cv::imencode(".jpg", r.image, j, {cv::IMWRITE_JPEG_QUALITY, 70});
      slam.track(ecar::DeviceId(1), cv::imdecode(j, cv::IMREAD_GRAYSCALE), motion[i].timestamp,
                 static_cast<uint32_t>(i), motion[i].gravity_c, motion[i].T_o_c);
    }
    const fs::path path = out / "map_file" / "corridor_slam.ecarmap";
    fs::create_directories(path.parent_path());
    slam.saveMap(path.string());
    std::cout << "map_file: " << slam.map().numKeyFrames() << " keyframes, " << fs::file_size(path)
              << " bytes\n";

    ecar::GlobalGraphConfig config;
    config.vo.database_path = ":memory:";
    ecar::GlobalGraph graph(config);
    graph.connect("device_0", renderer.camera(), "", 0, 0.0);
    graph.addMap(renderer.camera());
    ecar::VirtualObject line;
    line.kind = ecar::VoKind::kLine;
    line.start = {0.5, 1.0, 0.0};
    line.end = {1.0, 1.0, 0.0};
    line.normal = {0, 0, 1};
    line.width = 0.05f;
    line.owner = "device_0";
    line.map = graph.largestMap();
    graph.vos().registerObject(line);
    const ecar::VoOutcome gone = graph.vos().registerObject(line);
    graph.vos().remove(gone.id, 1, "device_0");
    graph.save((out / "map_file" / "atlas_with_vos.ecarmap").string());
  }

  // upload: JPEGs of the targets' 64x48 camera (odd first byte: the bytes are the image).
  {
    cv::Mat gray(48, 64, CV_8UC1);
    cv::randu(gray, 0, 256);
    cv::GaussianBlur(gray, gray, cv::Size(5, 5), 1.5);
    cv::Mat colour;
    cv::cvtColor(gray, colour, cv::COLOR_GRAY2BGR);
    int k = 0;
    for (const auto& [image, progressive] :
         std::vector<std::pair<cv::Mat, bool>>{{gray, false}, {colour, false}, {gray, true}}) {
      std::vector<uint8_t> seed = {1};
      const std::vector<uint8_t> j = jpeg(image, 80, progressive);
      seed.insert(seed.end(), j.begin(), j.end());
      write(out / "upload" / ("jpeg_" + std::to_string(k++)), seed);
    }
    std::vector<uint8_t> fields = bytes(120, 7);
    fields[0] = 0;
    const std::vector<uint8_t> j = jpeg(gray, 60, false);
    fields.insert(fields.end(), j.begin(), j.end());
    write(out / "upload" / "fields_and_jpeg", fields);
  }

  // local_graph and vo_request: structured targets read their fields from any bytes.
  for (uint32_t s = 1; s <= 3; ++s) {
    write(out / "local_graph" / ("bytes_" + std::to_string(s)), bytes(256 * s, s));
    write(out / "vo_request" / ("bytes_" + std::to_string(s)), bytes(512 * s, 100 + s));
  }

  // scene: the shipped scenes that are small.
  for (const char* name : {"room.yaml", "corridor.yaml", "ring_small.yaml"}) {
    const fs::path from = repo / "config/scenes" / name;
    if (fs::exists(from)) {
      fs::create_directories(out / "scene");
      fs::copy_file(from, out / "scene" / name, fs::copy_options::overwrite_existing);
    }
  }
  return 0;
}
