// The virtual-object side of Device: touches (strokes and drags sent as
// interactions), interaction results, VO states relayed straight to the
// device, and the drawing of the held VOs into ar_view.
#include "ecar_device/device.h"

#include <algorithm>
#include <cmath>
#include <string>

#include <std_msgs/Header.h>
#include <opencv2/imgproc.hpp>

#include <ecar_msgs/Interaction.h>
#include <ecar_msgs/InteractionResult.h>
#include <ecar_msgs/Touch.h>
#include <ecar_msgs/VirtualObject.h>

#include "device_internal.h"
#include "ecar_bridge/objects.h"
#include "ecar_core/common/error.h"

namespace ecar_device {

using device_internal::kWarnPeriod;

void Device::onTouch(const ecar_msgs::TouchConstPtr& msg) {
  std::lock_guard<std::mutex> lock(mutex_);
  const char* id = config_.device_id.c_str();
  ecar::Touch touch;
  try {
    touch = ecar_bridge::fromMsg(*msg);
  } catch (const ecar::Error& e) {
    ROS_WARN_THROTTLE(kWarnPeriod, "%s: touch dropped: %s", id, e.what());
    return;
  }
  applyTouch(touch, msg->header.stamp.isZero() ? ros::Time::now() : msg->header.stamp);
}

void Device::applyTouch(const ecar::Touch& touch, const ros::Time& stamp) {
  const char* id = config_.device_id.c_str();
  // A stroke or drag goes on from the last pose; a new one needs a recent pose.
  const bool begin = touch.phase == ecar::TouchPhase::kBegin;
  if (!camera_ || !T_w_c_ ||
      (begin && (last_image_stamp_ - pose_stamp_).toSec() > config_.touch_pose_timeout)) {
    ROS_WARN_THROTTLE(kWarnPeriod, "%s: touch dropped: no pose within ~touch_pose_timeout", id);
    return;
  }
  requests_.clear();
  if (objects_.touch(touch, *T_w_c_, *camera_, &requests_) == ecar::TouchOutcome::kMissed) {
    // The user sees nothing happen: say why (the planes come with the local graphs).
    ROS_WARN_THROTTLE(kWarnPeriod,
                      "%s: touch at (%.0f, %.0f) px hits none of the %zu planes and %zu objects "
                      "held within %.0f m: nothing drawn",
                      id, touch.uv.x(), touch.uv.y(), objects_.planeCount(),
                      objects_.objects().size(), objects_.config().max_distance);
  }
  std_msgs::Header header;
  header.stamp = stamp;
  header.frame_id = config_.map_frame;
  for (ecar::VoRequest& r : requests_) {
    r.device = config_.device_id;
    // The coordinates are those of the server map this device holds: a
    // request that arrives after that map merged is refused, not misplaced.
    r.object.map = ecar::MapId(map_id_);
    ecar_msgs::Interaction msg = ecar_bridge::toMsg(r, header);
    msg.session = session_;
    interaction_pub_.publish(msg);
  }
}

void Device::onInteractionResult(const ecar_msgs::InteractionResultConstPtr& msg) {
  std::lock_guard<std::mutex> lock(mutex_);
  const char* id = config_.device_id.c_str();
  if (msg->device_id != config_.device_id) {
    ROS_WARN_THROTTLE(kWarnPeriod,
                      "%s: interaction_result dropped: device_id \"%s\" is another device", id,
                      msg->device_id.c_str());
    return;
  }
  std::string what;
  if (objects_.applyResult(ecar_bridge::fromMsg(*msg), &what)) {
    noteObjectArrivals();
    ROS_DEBUG("%s: %s", id, what.c_str());
  } else {
    ROS_WARN_THROTTLE(0.5, "%s: %s", id, what.c_str());
  }
}

void Device::onDirectObject(const ecar_msgs::VirtualObjectConstPtr& msg) {
  std::lock_guard<std::mutex> lock(mutex_);
  try {
    graph_objects_.assign(1, ecar_bridge::fromMsg(*msg, "object"));
    objects_.applyGraph({}, graph_objects_);
    noteObjectArrivals();
  } catch (const ecar::Error& e) {
    ROS_WARN_THROTTLE(kWarnPeriod, "%s: %s dropped: %s", config_.device_id.c_str(),
                      config_.direct_objects_topic.c_str(), e.what());
  }
}

void Device::noteObjectArrivals() {
  const ros::Time now = ros::Time::now();
  const auto& held = objects_.objects();
  for (const auto& [object, vo] : held) {
    auto& [version, arrived] = object_arrival_[object.value];
    if (version != vo.version || arrived.isZero()) {
      version = vo.version;
      arrived = now;
    }
  }
  if (object_arrival_.size() > held.size()) {  // some were deleted or dropped with the map
    for (auto it = object_arrival_.begin(); it != object_arrival_.end();) {
      it = held.count(ecar::ObjectId(it->first)) ? std::next(it) : object_arrival_.erase(it);
    }
  }
}

void Device::drawObjects(const ecar::SE3& T_w_c) {
  if (!camera_) return;
  objects_.drawList(T_w_c, *camera_, &draw_lines_);
  constexpr double kMaxPx = 1e7;  // beyond int range once scaled: never on screen anyway
  for (const ecar::ScreenLine& l : draw_lines_) {
    if (l.a.cwiseAbs().maxCoeff() > kMaxPx || l.b.cwiseAbs().maxCoeff() > kMaxPx) continue;
    const cv::Point a(static_cast<int>(std::lround(l.a.x())),
                      static_cast<int>(std::lround(l.a.y())));
    const cv::Point b(static_cast<int>(std::lround(l.b.x())),
                      static_cast<int>(std::lround(l.b.y())));
    const int thickness = std::max(1, static_cast<int>(std::lround(l.thickness)));
    // Strokes not acknowledged yet get a white outline.
    if (l.pending) cv::line(ar_image_, a, b, cv::Scalar(255, 255, 255), thickness + 2, cv::LINE_AA);
    cv::line(ar_image_, a, b, cv::Scalar(l.blue, l.green, l.red), thickness, cv::LINE_AA);
  }
}

}  // namespace ecar_device
