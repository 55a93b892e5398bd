// PlaneSegmentation (core: ecar::PlaneSegmentation): for each keyframe the
// mapper finished (/ecar/keyframe_mapped), segments the planes in the points of
// the keyframe and its covisible neighbours (labelled with the up direction
// from the keyframe's gravity) and merges them into the global graph's planes;
// publishes what it did on /ecar/keyframe_planes, where GridConnection links
// the keyframe to the grid cells it sees on them.
#include <memory>

#include <ecar_msgs/KeyFrameEvent.h>
#include <ecar_msgs/KeyFramePlanes.h>
#include <nodelet/nodelet.h>
#include <ros/ros.h>
#include <boost/make_shared.hpp>
#include <pluginlib/class_list_macros.hpp>

#include "ecar_bridge/server_pipeline.h"
#include "ecar_bridge/topics.h"
#include "ecar_core/common/error.h"
#include "ecar_core/server/plane_segmentation.h"
#include "ecar_server/ros_params.h"

namespace ecar_server {

/// Covisible neighbours whose points join the keyframe's for segmentation.
constexpr size_t kNeighbours = 10;

class PlaneSegmentationNodelet : public nodelet::Nodelet {
 public:
  ~PlaneSegmentationNodelet() override { mapped_sub_.shutdown(); }

 private:
  void onInit() override {
    initialiseOrReport(getName(), [this] { initialise(); });
  }

  void initialise() {
    ros::NodeHandle& nh = getMTNodeHandle();
    const ServerConfig config = loadServerConfig(nh);
    graph_ = sharedGraph(nh.getNamespace(), config);
    segmentation_ =
        std::make_unique<ecar::PlaneSegmentation>(graph_.get(), config.planes, kNeighbours);
    planes_pub_ = nh.advertise<ecar_msgs::KeyFramePlanes>(ecar_bridge::kKeyFramePlanesTopic, 200);
    // One subscription: keyframes are segmented one at a time, in order.
    mapped_sub_ = nh.subscribe(ecar_bridge::kKeyFrameMappedTopic, 200,
                               &PlaneSegmentationNodelet::onMapped, this);
  }

  void onMapped(const ecar_msgs::KeyFrameEvent::ConstPtr& msg) {
    const ecar_bridge::MappedKeyFrame event = ecar_bridge::fromMsg(*msg);
    ecar::KeyFramePlanes r;
    try {
      r = segmentation_->process(event.id, event.gravity_c);
    } catch (const ecar::Error& e) {
      NODELET_WARN_THROTTLE(5.0, "device %s: keyframe %u: plane segmentation failed: %s",
                            event.device.c_str(), event.id.value, e.what());
      return;
    }
    if (!r.done()) {
      if (r.skipped == "no gravity") {
        NODELET_WARN_THROTTLE(5.0, "device %s: keyframe %u has no gravity: no planes from it",
                              event.device.c_str(), event.id.value);
      }
      return;
    }
    NODELET_DEBUG(
        "keyframe %u: %zu points, %zu planes found, %zu created, %zu updated, %zu removed, "
        "%zu plane points culled since; segment %.1f ms, integrate %.1f ms",
        event.id.value, r.points, r.observations, r.update.created.size(), r.update.updated.size(),
        r.update.removed.size(), r.points_gone, r.segment_ms, r.integrate_ms);
    NODELET_INFO_THROTTLE(5.0,
                          "planes: %zu in the map; keyframe %u: %zu points, %zu planes in "
                          "%.1f + %.1f ms (segment, integrate)",
                          graph_->planes().size(), event.id.value, r.points, r.observations,
                          r.segment_ms, r.integrate_ms);
    planes_pub_.publish(
        boost::make_shared<ecar_msgs::KeyFramePlanes>(ecar_bridge::toMsg(r, event.device)));
  }

  std::shared_ptr<ecar::GlobalGraph> graph_;
  std::unique_ptr<ecar::PlaneSegmentation> segmentation_;
  ros::Publisher planes_pub_;
  ros::Subscriber mapped_sub_;
};

}  // namespace ecar_server

PLUGINLIB_EXPORT_CLASS(ecar_server::PlaneSegmentationNodelet, nodelet::Nodelet)
