// Renderer geometry against an independent analytic ray-box intersection.
#include "ecar_core/sim/renderer.h"

#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <random>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "ecar_core/common/error.h"

namespace ecar {
namespace {

const std::string kScenes = ECAR_REPO_ROOT "/config/scenes";

// Distance along `d` from `o` (inside `box`) to the box boundary, and the axis
// and side of the face it leaves through. Written independently of the renderer.
double exitDistance(const AlignedBox& box, const Eigen::Vector3d& o, const Eigen::Vector3d& d,
                    int* axis, int* side) {
  double best = std::numeric_limits<double>::infinity();
  for (int a = 0; a < 3; ++a) {
    if (std::fabs(d[a]) < 1e-15) continue;
    const double bound = d[a] > 0 ? box.max[a] : box.min[a];
    const double t = (bound - o[a]) / d[a];
    if (t < best) {
      best = t;
      *axis = a;
      *side = d[a] > 0 ? 1 : 0;
    }
  }
  return best;
}

// Entry distance into a solid box, or +inf when the ray misses it.
double entryDistance(const AlignedBox& box, const Eigen::Vector3d& o, const Eigen::Vector3d& d) {
  double t_near = 0.0, t_far = std::numeric_limits<double>::infinity();
  for (int a = 0; a < 3; ++a) {
    if (std::fabs(d[a]) < 1e-15) {
      if (o[a] < box.min[a] || o[a] > box.max[a]) return std::numeric_limits<double>::infinity();
      continue;
    }
    double t0 = (box.min[a] - o[a]) / d[a], t1 = (box.max[a] - o[a]) / d[a];
    if (t0 > t1) std::swap(t0, t1);
    t_near = std::max(t_near, t0);
    t_far = std::min(t_far, t1);
  }
  return t_near <= t_far ? t_near : std::numeric_limits<double>::infinity();
}

class RoomRenderTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    scene_ = new Scene(loadScene(kScenes + "/room.yaml"));
    renderer_ = new Renderer(*scene_);
  }
  static void TearDownTestSuite() {
    delete renderer_;
    delete scene_;
  }
  static Scene* scene_;
  static Renderer* renderer_;
};
Scene* RoomRenderTest::scene_ = nullptr;
Renderer* RoomRenderTest::renderer_ = nullptr;

TEST_F(RoomRenderTest, DepthAndLabelsMatchAnalyticIntersection) {
  ASSERT_EQ(scene_->spaces.size(), 1u);
  const AlignedBox& room = scene_->spaces[0];
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> ux(0.3, 5.7), uy(0.3, 4.7), uz(0.3, 2.4), ua(-M_PI, M_PI),
      upitch(-1.2, 1.2);
  RenderOutput out;
  RenderOptions opt;
  int checked = 0, by_label[5] = {0, 0, 0, 0, 0};
  for (int pose = 0; pose < 12; ++pose) {
    Eigen::Vector3d eye(ux(rng), uy(rng), uz(rng));
    if (!scene_->isFree(eye, 0.2)) continue;
    const double yaw = ua(rng), pitch = upitch(rng);
    const Eigen::Vector3d target =
        eye + Eigen::Vector3d(std::cos(pitch) * std::cos(yaw), std::cos(pitch) * std::sin(yaw),
                              std::sin(pitch));
    const SE3 T_w_c = lookAt(eye, target);
    renderer_->render(T_w_c, opt, &out);
    for (int v = 3; v < out.depth.rows; v += 37) {
      for (int u = 5; u < out.depth.cols; u += 41) {
        const Eigen::Vector3d ray_c = renderer_->camera().unproject(Eigen::Vector2d(u, v));
        const Eigen::Vector3d d = T_w_c.linear() * ray_c;
        int axis = -1, side = -1;
        double t = exitDistance(room, eye, d, &axis, &side);
        SurfaceLabel label = axis == 2 ? (side == 0 ? SurfaceLabel::kFloor : SurfaceLabel::kCeiling)
                                       : SurfaceLabel::kWall;
        for (const auto& solid : scene_->solids) {
          const double ts = entryDistance(solid, eye, d);
          if (ts < t) {
            t = ts;
            label = SurfaceLabel::kObject;
          }
        }
        // ray_c has z = 1, so t is the depth along the optical axis.
        const float depth = out.depth.at<float>(v, u);
        // Pixels right at an edge between two faces may go either way.
        const Eigen::Vector3d hit = eye + t * d;
        const double edge_margin = 2e-3 * t;
        int near_edges = 0;
        for (int a = 0; a < 3; ++a) {
          if (std::fabs(hit[a] - room.min[a]) < edge_margin ||
              std::fabs(hit[a] - room.max[a]) < edge_margin) {
            ++near_edges;
          }
        }
        if (near_edges > 1) continue;
        EXPECT_NEAR(depth, t, 1e-4 * t + 1e-4) << "pixel " << u << "," << v << " pose " << pose;
        EXPECT_EQ(out.labels.at<uint8_t>(v, u), static_cast<uint8_t>(label))
            << "pixel " << u << "," << v << " pose " << pose;
        ++by_label[static_cast<int>(label)];
        ++checked;
      }
    }
  }
  EXPECT_GT(checked, 1000);
  EXPECT_GT(by_label[1], 20);  // floor
  EXPECT_GT(by_label[2], 20);  // wall
  EXPECT_GT(by_label[3], 20);  // ceiling
  EXPECT_GT(by_label[4], 5);   // the cabinet
}

TEST_F(RoomRenderTest, CastRayAgreesWithRender) {
  const SE3 T_w_c = lookAt({1.0, 1.0, 1.5}, {4.0, 3.0, 0.3});
  RenderOutput out;
  renderer_->render(T_w_c, RenderOptions(), &out);
  for (int v = 10; v < 480; v += 60) {
    for (int u = 10; u < 640; u += 70) {
      const Eigen::Vector3d d = T_w_c.linear() * renderer_->camera().unproject({u, v});
      const auto hit = renderer_->castRay(T_w_c.translation(), d);
      ASSERT_TRUE(hit.has_value());
      EXPECT_NEAR(hit->t, out.depth.at<float>(v, u), 1e-3 * hit->t);
      EXPECT_EQ(static_cast<uint8_t>(hit->label), out.labels.at<uint8_t>(v, u));
    }
  }
}

TEST_F(RoomRenderTest, ColourAndGreyAgreeAndNoiseChangesPixels) {
  const SE3 T_w_c = lookAt({2.0, 2.0, 1.4}, {3.0, 2.5, 0.0});
  RenderOutput grey, colour, noisy;
  RenderOptions opt;
  renderer_->render(T_w_c, opt, &grey);
  opt.color = true;
  renderer_->render(T_w_c, opt, &colour);
  ASSERT_EQ(grey.image.type(), CV_8UC1);
  ASSERT_EQ(colour.image.type(), CV_8UC3);
  cv::Mat converted;
  cv::cvtColor(colour.image, converted, cv::COLOR_BGR2GRAY);
  EXPECT_LT(cv::norm(converted, grey.image, cv::NORM_L1) / grey.image.total(), 3.0);
  opt.color = false;
  opt.noise_sigma = 4.0f;
  opt.noise_seed = 3;
  renderer_->render(T_w_c, opt, &noisy);
  cv::Mat diff;
  cv::absdiff(noisy.image, grey.image, diff);
  const double mean_abs = cv::mean(diff)[0];
  EXPECT_GT(mean_abs, 1.5);  // triangular noise with sigma 4: E|n| ~ 3.3
  EXPECT_LT(mean_abs, 5.0);
}

// A covered camera: one grey level plus the noise, nothing hit.
TEST_F(RoomRenderTest, BlankViewIsUniformGreyWithNoise) {
  RenderOptions opt;
  opt.blank = true;
  opt.noise_sigma = 2.0f;
  RenderOutput out;
  renderer_->render(lookAt({2.0, 2.0, 1.4}, {3.0, 2.5, 0.0}), opt, &out);
  cv::Scalar mean, stddev;
  cv::meanStdDev(out.image, mean, stddev);
  EXPECT_NEAR(mean[0], 140.0, 1.0);
  EXPECT_GT(stddev[0], 1.0);
  EXPECT_LT(stddev[0], 3.0);
  EXPECT_EQ(cv::countNonZero(out.labels), 0);
  EXPECT_EQ(cv::countNonZero(out.depth), 0);
}

TEST_F(RoomRenderTest, CameraInsideAWallSeesNothingAndBadPoseThrows) {
  RenderOutput out;
  renderer_->render(lookAt({-1.0, 2.0, 1.0}, {3.0, 2.0, 1.0}), RenderOptions(), &out);
  EXPECT_EQ(cv::countNonZero(out.labels), 0);
  SE3 bad = SE3::Identity();
  bad.translation().x() = std::nan("");
  EXPECT_THROW(renderer_->render(bad, RenderOptions(), &out), Error);
}

// A union of two boxes (an L-shaped corridor): rays through the opening reach
// the far wall of the second box.
TEST(RendererUnionTest, RaysContinueThroughTheOpening) {
  const std::string path =
      (std::filesystem::temp_directory_path() / "ecar_renderer_union.yaml").string();
  {
    std::ofstream f(path);
    f << "name: ell\ncamera: {width: 160, height: 120, fx: 130, fy: 130, cx: 79.5, cy: 59.5}\n"
         "texture: {texel_size: 0.02}\n"
         "spaces:\n  - {min: [0, 0, 0], max: [10, 2, 2.5]}\n"
         "  - {min: [8, 0, 0], max: [10, 12, 2.5]}\n";
  }
  const Scene scene = loadScene(path);
  const Renderer renderer(scene);
  // From inside the first box, look along +y through the opening into the second.
  const Eigen::Vector3d eye(9.0, 1.0, 1.2);
  const auto hit = renderer.castRay(eye, Eigen::Vector3d(0, 1, 0));
  ASSERT_TRUE(hit.has_value());
  EXPECT_NEAR(hit->t, 11.0, 1e-9);
  EXPECT_EQ(hit->label, SurfaceLabel::kWall);
  // The same ray from x = 5 hits the first box's wall at y = 2.
  const auto blocked = renderer.castRay({5.0, 1.0, 1.2}, Eigen::Vector3d(0, 1, 0));
  ASSERT_TRUE(blocked.has_value());
  EXPECT_NEAR(blocked->t, 1.0, 1e-9);
  RenderOutput out;
  renderer.render(lookAt(eye, eye + Eigen::Vector3d(0, 1, 0)), RenderOptions(), &out);
  EXPECT_NEAR(out.depth.at<float>(59, 79), 11.0, 0.1);  // near the centre pixel
  std::filesystem::remove(path);
}

TEST(RendererDistortionTest, DepthFollowsTheDistortedRays) {
  Scene scene = loadScene(kScenes + "/room.yaml");
  scene.camera.dist = {-0.28, 0.07, 0.0002, 0.00002, 0.0};
  scene.texture.texel_size = 0.02;
  const Renderer renderer(scene);
  const SE3 T_w_c = lookAt({1.0, 2.5, 1.5}, {5.0, 2.5, 1.0});
  RenderOutput out;
  renderer.render(T_w_c, RenderOptions(), &out);
  for (const auto& px :
       {Eigen::Vector2d(5, 5), Eigen::Vector2d(630, 470), Eigen::Vector2d(320, 5)}) {
    const Eigen::Vector3d ray = renderer.camera().unproject(px);
    const auto hit = renderer.castRay(T_w_c.translation(), T_w_c.linear() * ray);
    ASSERT_TRUE(hit.has_value());
    EXPECT_NEAR(out.depth.at<float>(static_cast<int>(px.y()), static_cast<int>(px.x())), hit->t,
                1e-3 * hit->t);
    // The hit point projects back to the same distorted pixel.
    const auto back = renderer.camera().project(T_w_c.inverse() * hit->p_w);
    ASSERT_TRUE(back.has_value());
    EXPECT_NEAR((*back - px).norm(), 0.0, 1e-6);
  }
}

}  // namespace
}  // namespace ecar
