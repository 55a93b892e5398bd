// Generates a device's synthetic dataset from a scene file:
//
//   rosrun ecar_sim make_dataset --scene config/scenes/corridor.yaml --device device_0
//                                --out data/corridor_device_0 [--frames N] [--seed S]
//                                [--gray] [--bag] [--quiet]
//
// Writes the TUM layout (rgb/, rgb.txt, groundtruth.txt, camera.yaml, imu.txt,
// gravity.txt, odometry.txt and, when the scene scripts touches for the device,
// touches.txt; see ecar_core/dataset_writer.h), a contact sheet
// (contact_sheet.png) and, with --bag, DIR/<device>.bag holding the device's
// topics as the dataset player publishes them (scripted touches included).
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <ecar_msgs/Touch.h>
#include <geometry_msgs/PoseStamped.h>
#include <rosbag/bag.h>
#include <tf2_msgs/TFMessage.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "ecar_bridge/camera.h"
#include "ecar_bridge/geometry.h"
#include "ecar_bridge/objects.h"
#include "ecar_bridge/topics.h"
#include "ecar_core/common/error.h"
#include "ecar_core/io/dataset_writer.h"
#include "ecar_core/sim/motion.h"
#include "ecar_core/sim/renderer.h"
#include "ecar_core/sim/scene.h"

namespace {

struct Options {
  std::string scene, device, out;
  int frames = 0;  // 0 = the whole trajectory
  std::optional<uint32_t> seed;
  bool gray = false, bag = false, quiet = false;
};

void usage(std::ostream& os) {
  os << "usage: make_dataset --scene FILE --device NAME --out DIR [--frames N] [--seed S]\n"
        "                    [--gray] [--bag] [--quiet]\n"
        "  --frames N  only the first N frames (default: the whole trajectory)\n"
        "  --seed S    texture seed (overrides the scene's texture.seed)\n"
        "  --gray      8-bit grey images instead of colour\n"
        "  --bag       also write DIR/<device>.bag with the device's topics\n";
}

Options parseArgs(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    const std::string k = argv[i];
    auto value = [&]() -> std::string {
      if (i + 1 >= argc) throw ecar::Error("option " + k + " needs a value");
      return argv[++i];
    };
    auto number = [&](const std::string& v) {
      try {
        size_t used = 0;
        const long n = std::stol(v, &used);
        if (used != v.size() || n < 0) throw std::invalid_argument(v);
        return n;
      } catch (const std::exception&) {
        throw ecar::Error("option " + k + " needs a non-negative integer (got '" + v + "')");
      }
    };
    if (k == "--scene")
      o.scene = value();
    else if (k == "--device")
      o.device = value();
    else if (k == "--out")
      o.out = value();
    else if (k == "--frames")
      o.frames = static_cast<int>(number(value()));
    else if (k == "--seed")
      o.seed = static_cast<uint32_t>(number(value()));
    else if (k == "--gray")
      o.gray = true;
    else if (k == "--bag")
      o.bag = true;
    else if (k == "--quiet")
      o.quiet = true;
    else if (k == "--help" || k == "-h") {
      usage(std::cout);
      std::exit(0);
    } else {
      throw ecar::Error("unknown option '" + k + "'");
    }
  }
  if (o.scene.empty() || o.device.empty() || o.out.empty()) {
    throw ecar::Error("--scene, --device and --out are required");
  }
  return o;
}

// A grid of thumbnails spread over the sequence, each labelled with its frame.
class ContactSheet {
 public:
  ContactSheet(int total_frames, int cols, int rows, cv::Size image_size)
      : total_(total_frames), cols_(cols), rows_(rows) {
    thumb_ = cv::Size(image_size.width / 4, image_size.height / 4);
    sheet_ = cv::Mat(rows * thumb_.height, cols * thumb_.width, CV_8UC3, cv::Scalar(0, 0, 0));
  }
  void offer(int frame, const cv::Mat& image) {
    const int slots = cols_ * rows_;
    const int slot =
        total_ > 1 ? static_cast<int>(static_cast<long>(frame) * (slots - 1) / (total_ - 1)) : 0;
    if (slot >= slots || filled_ > slot) return;
    cv::Mat small, bgr;
    cv::resize(image, small, thumb_, 0, 0, cv::INTER_AREA);
    if (small.channels() == 1) {
      cv::cvtColor(small, bgr, cv::COLOR_GRAY2BGR);
    } else {
      bgr = small;
    }
    cv::putText(bgr, std::to_string(frame), {4, 14}, cv::FONT_HERSHEY_SIMPLEX, 0.4,
                cv::Scalar(0, 255, 255), 1, cv::LINE_AA);
    bgr.copyTo(sheet_(cv::Rect((slot % cols_) * thumb_.width, (slot / cols_) * thumb_.height,
                               thumb_.width, thumb_.height)));
    filled_ = slot + 1;
  }
  void save(const std::string& path) const {
    if (!cv::imwrite(path, sheet_)) throw ecar::Error(path + ": cannot write contact sheet");
  }

 private:
  int total_, cols_, rows_, filled_ = 0;
  cv::Size thumb_;
  cv::Mat sheet_;
};

// Writes the device's topics into a bag, as the dataset player publishes them.
class BagWriter {
 public:
  BagWriter(const std::string& path, const std::string& device, const ecar::PinholeCamera& camera)
      : topics_{device}, camera_(camera) {
    bag_.open(path, rosbag::bagmode::Write);
    bag_.setCompression(rosbag::compression::LZ4);
  }
  void addFrame(int index, double t, const cv::Mat& image, const ecar::MotionSample& m) {
    const ros::Time stamp = kEpoch + ros::Duration(t);
    std_msgs::Header h;
    h.seq = static_cast<uint32_t>(index);
    h.stamp = stamp;
    h.frame_id = topics_.camera_frame();
    bag_.write("/" + topics_.image_raw(), stamp, ecar_bridge::toImageMsg(image, h));
    bag_.write("/" + topics_.camera_info(), stamp, ecar_bridge::toMsg(camera_, h));
    bag_.write("/" + topics_.imu(), stamp,
               ecar_bridge::toMsg(ecar::ImuSample{t, m.gravity_c, m.gyro_c}, h));
    std_msgs::Header world = h;
    world.frame_id = "map";
    tf2_msgs::TFMessage tf;
    tf.transforms.push_back(ecar_bridge::toTransformMsg(m.T_w_c, world, topics_.gt_frame()));
    bag_.write("/tf", stamp, tf);
    geometry_msgs::PoseStamped odom;
    odom.header = h;
    odom.header.frame_id = topics_.odom_frame();
    odom.pose = ecar_bridge::toMsg(m.T_o_c);
    bag_.write("/" + topics_.odometry(), stamp, odom);
  }
  /// A scripted touch of the frame at dataset time t: header stamp = the
  /// frame's; bag time 1 us later, so that `rosbag play` sends it after the
  /// frame's image (as the player does).
  void addTouch(double t, const ecar::TouchEvent& touch) {
    std_msgs::Header h;
    h.stamp = kEpoch + ros::Duration(t);
    h.frame_id = topics_.camera_frame();
    bag_.write("/" + topics_.touch(), h.stamp + ros::Duration(0, 1000),
               ecar_bridge::toMsg(touch, h));
  }
  void close() { bag_.close(); }

 private:
  static inline const ros::Time kEpoch{1000000000, 0};
  rosbag::Bag bag_;
  ecar_bridge::DeviceTopics topics_;
  ecar::PinholeCamera camera_;
};

int run(const Options& o) {
  ecar::Scene scene = ecar::loadScene(o.scene);
  if (o.seed) scene.texture.seed = *o.seed;
  const ecar::DeviceSpec& device = scene.device(o.device);
  const ecar::CameraParams& camera = scene.cameraOf(device);  // its own, or the scene's
  std::vector<ecar::MotionSample> motion = ecar::generateMotion(scene, device, camera.fps);
  const size_t total_frames = motion.size();
  if (o.frames > 0 && static_cast<size_t>(o.frames) < motion.size()) motion.resize(o.frames);
  // Stamps at the microsecond resolution of rgb.txt, so a frame, its IMU
  // sample and its touches carry exactly the same time.
  for (ecar::MotionSample& m : motion) m.timestamp = std::round(m.timestamp * 1e6) * 1e-6;
  ecar::Trajectory frames;
  for (const ecar::MotionSample& m : motion) frames.push_back({m.timestamp, m.T_w_c});
  const std::vector<ecar::TouchEvent> touches =
      ecar::scriptTouches(scene, device, frames, total_frames);
  const ecar::Renderer renderer(scene, ecar::PinholeCamera(camera));
  ecar::DatasetWriter writer(o.out, renderer.camera());
  ContactSheet sheet(static_cast<int>(motion.size()), 4, 3,
                     cv::Size(renderer.camera().width(), renderer.camera().height()));
  std::unique_ptr<BagWriter> bag;
  const std::string bag_path = (std::filesystem::path(o.out) / (o.device + ".bag")).string();
  if (o.bag) bag = std::make_unique<BagWriter>(bag_path, o.device, renderer.camera());

  ecar::RenderOptions ropt;
  ropt.color = !o.gray;
  ropt.depth = false;
  ropt.labels = false;
  ropt.noise_sigma = static_cast<float>(scene.noise_sigma);
  ecar::RenderOutput out;
  const auto start = std::chrono::steady_clock::now();
  auto touch = touches.begin();
  for (size_t i = 0; i < motion.size(); ++i) {
    const ecar::MotionSample& m = motion[i];
    const double t = m.timestamp;
    ropt.noise_seed = static_cast<uint32_t>(i);
    ropt.blank = m.blank;
    renderer.render(m.T_w_c, ropt, &out);
    writer.addImu(ecar::ImuSample{t, m.gravity_c, m.gyro_c});
    writer.addFrame(t, out.image, m.T_w_c, m.gravity_c, m.T_o_c);
    sheet.offer(static_cast<int>(i), out.image);
    if (bag) bag->addFrame(static_cast<int>(i), t, out.image, m);
    for (; touch != touches.end() && touch->frame == i; ++touch) {
      writer.addTouch(*touch);
      if (bag) bag->addTouch(t, *touch);
    }
    if (!o.quiet && (i % 25 == 0 || i + 1 == motion.size())) {
      const double el =
          std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
      std::fprintf(stderr, "\r[make_dataset] %s/%s: frame %zu/%zu (%.0f%%), %.1f fps   ",
                   scene.name.c_str(), o.device.c_str(), i + 1, motion.size(),
                   100.0 * (i + 1) / motion.size(), (i + 1) / std::max(el, 1e-6));
    }
  }
  if (!o.quiet) std::fprintf(stderr, "\n");
  writer.finish();
  if (bag) bag->close();
  const std::string sheet_path = (std::filesystem::path(o.out) / "contact_sheet.png").string();
  sheet.save(sheet_path);
  const double length = [&] {
    double s = 0;
    for (size_t i = 1; i < motion.size(); ++i) {
      s += (motion[i].T_w_c.translation() - motion[i - 1].T_w_c.translation()).norm();
    }
    return s;
  }();
  std::printf("dataset:       %s\n", std::filesystem::absolute(o.out).c_str());
  std::printf("frames:        %zu (%.1f s at %.0f fps, %.1f m travelled)\n", motion.size(),
              motion.empty() ? 0.0 : motion.back().timestamp, camera.fps, length);
  std::printf("contact sheet: %s\n", std::filesystem::absolute(sheet_path).c_str());
  if (!touches.empty()) {
    std::printf("touches:       %zu scripted (touches.txt)\n", touches.size());
  }
  if (bag) std::printf("bag:           %s\n", std::filesystem::absolute(bag_path).c_str());
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  try {
    return run(parseArgs(argc, argv));
  } catch (const ecar::Error& e) {
    std::cerr << "make_dataset: " << e.what() << "\n";
    if (std::string(e.what()).find("required") != std::string::npos ||
        std::string(e.what()).find("option") != std::string::npos) {
      usage(std::cerr);
      return 2;
    }
    return 1;
  } catch (const std::exception& e) {
    std::cerr << "make_dataset: " << e.what() << "\n";
    return 1;
  }
}
