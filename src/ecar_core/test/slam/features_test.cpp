// The synthetic world must be trackable: OpenCV ORB finds plenty of
// well-spread keypoints along the corridor walk, on floor, walls and ceiling.
#include <numeric>

#include <gtest/gtest.h>
#include <opencv2/features2d.hpp>

#include "ecar_core/sim/motion.h"
#include "ecar_core/sim/renderer.h"

namespace ecar {
namespace {

const std::string kScenes = ECAR_REPO_ROOT "/config/scenes";

TEST(FeaturesTest, OrbFindsManyWellSpreadKeypointsAlongTheCorridorWalk) {
  const Scene scene = loadScene(kScenes + "/corridor.yaml");
  const Renderer renderer(scene);
  const auto motion = generateMotion(scene, scene.devices[0], scene.camera.fps);
  auto orb = cv::ORB::create(1000, 1.2f, 8);
  RenderOptions opt;
  opt.noise_sigma = static_cast<float>(scene.noise_sigma);
  RenderOutput out;
  std::vector<double> total, per_label[5];
  double min_cells = 1e9;
  const size_t step = motion.size() / 12;
  for (size_t i = 0; i < motion.size(); i += step) {
    opt.noise_seed = static_cast<uint32_t>(i);
    renderer.render(motion[i].T_w_c, opt, &out);
    std::vector<cv::KeyPoint> kps;
    orb->detect(out.image, kps);
    total.push_back(static_cast<double>(kps.size()));
    int labels[5] = {0, 0, 0, 0, 0};
    bool cell[6][8] = {};
    for (const auto& kp : kps) {
      ++labels[out.labels.at<uint8_t>(cvRound(kp.pt.y), cvRound(kp.pt.x))];
      cell[static_cast<int>(kp.pt.y) * 6 / out.image.rows]
          [static_cast<int>(kp.pt.x) * 8 / out.image.cols] = true;
    }
    for (int l = 0; l < 5; ++l) per_label[l].push_back(labels[l]);
    int cells = 0;
    for (auto& row : cell) cells += std::count(std::begin(row), std::end(row), true);
    min_cells = std::min<double>(min_cells, cells);
  }
  auto mean = [](const std::vector<double>& v) {
    return std::accumulate(v.begin(), v.end(), 0.0) / v.size();
  };
  EXPECT_GE(mean(total), 500.0);
  EXPECT_GE(*std::min_element(total.begin(), total.end()), 300.0);
  // Spread: keypoints in most of a 8 x 6 grid of the image in every frame.
  EXPECT_GE(min_cells, 30.0);
  EXPECT_GE(mean(per_label[1]), 50.0) << "floor";
  EXPECT_GE(mean(per_label[2]), 100.0) << "walls";
  EXPECT_GE(mean(per_label[3]), 10.0) << "ceiling";
}

TEST(FeaturesTest, KeypointsAtNearAndFarRange) {
  // Facing a wall at 0.5 m and at 10 m: ORB still finds distinct corners.
  const Scene scene = loadScene(kScenes + "/corridor.yaml");
  const Renderer renderer(scene);
  auto orb = cv::ORB::create(1000, 1.2f, 8);
  RenderOutput out;
  for (const double range : {0.5, 2.0, 10.0}) {
    // Look at the far end wall (x = 30) from `range` metres away.
    const Eigen::Vector3d eye(30.0 - range, 1.2, 1.35);
    renderer.render(lookAt(eye, eye + Eigen::Vector3d(1, 0, 0)), RenderOptions(), &out);
    cv::Mat mask = (out.labels == static_cast<uint8_t>(SurfaceLabel::kWall)) &
                   (out.depth > range - 0.01) & (out.depth < range + 0.01);
    std::vector<cv::KeyPoint> kps;
    orb->detect(out.image, kps, mask);
    EXPECT_GE(kps.size(), 100u) << "end wall at " << range << " m";
  }
  for (const double range : {0.5, 2.0, 10.0}) {
    // Floor and ceiling seen at `range` metres ahead.
    const Eigen::Vector3d eye(5.0, 1.2, 1.35);
    for (const double z : {0.0, 2.7}) {
      const Eigen::Vector3d target(5.0 + range, 1.2, z);
      renderer.render(lookAt(eye, target), RenderOptions(), &out);
      const double dist = (target - eye).norm();
      cv::Mat mask = (out.depth > 0.7 * dist) & (out.depth < 1.3 * dist);
      std::vector<cv::KeyPoint> kps;
      orb->detect(out.image, kps, mask);
      EXPECT_GE(kps.size(), 50u) << (z == 0 ? "floor" : "ceiling") << " at " << range << " m";
    }
  }
}

}  // namespace
}  // namespace ecar
