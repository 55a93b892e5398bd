#include "ecar_server/vo_marker_server.h"

#include <cmath>
#include <utility>

#include "ecar_server/markers.h"
#include "ecar_server/ros_params.h"

namespace ecar_server {
namespace {

// True when the marker of `b` looks like that of `a` apart from its position
// (so moving it is enough; re-inserting a marker would break a drag in rviz).
bool sameLook(const ecar::VirtualObject& a, const ecar::VirtualObject& b) {
  return a.r == b.r && a.g == b.g && a.b == b.b && a.normal.isApprox(b.normal, 1e-9) &&
         std::abs((a.end - a.start).norm() - (b.end - b.start).norm()) < 1e-6;
}

geometry_msgs::Pose poseOf(const ecar::VirtualObject& vo) {
  geometry_msgs::Pose pose;
  pose.position.x = vo.position.x();
  pose.position.y = vo.position.y();
  pose.position.z = vo.position.z();
  pose.orientation.w = 1.0;
  return pose;
}

}  // namespace

VoMarkerServer::VoMarkerServer(ros::NodeHandle nh, const std::string& topic_ns,
                               const std::string& frame, double drag_rate, GetFn get, MoveFn move)
    : frame_(frame), drag_rate_(drag_rate), get_(std::move(get)), move_(std::move(move)) {
  server_ = std::make_unique<interactive_markers::InteractiveMarkerServer>(topic_ns, "", true);
  name_check_sub_ =
      nh.subscribe(topic_ns + "/feedback", 100, &VoMarkerServer::checkFeedbackName, this);
}

VoMarkerServer::~VoMarkerServer() {
  name_check_sub_.shutdown();
  server_.reset();  // joins its spinner before the callbacks' targets go
}

size_t VoMarkerServer::size() const {
  std::lock_guard<std::mutex> lock(sync_mutex_);
  return shown_.size();
}

void VoMarkerServer::sync(const std::vector<ecar::VirtualObject>& objects) {
  std::lock_guard<std::mutex> lock(sync_mutex_);
  bool changed = false;
  std::map<ecar::ObjectId, ecar::VirtualObject> now;
  for (const auto& vo : objects) {
    if (vo.deleted) continue;
    now.emplace(vo.id, vo);
    const auto it = shown_.find(vo.id);
    if (it != shown_.end() && it->second.version == vo.version) continue;
    if (it != shown_.end() && sameLook(it->second, vo)) {
      server_->setPose(voMarkerName(vo.id), poseOf(vo));
    } else {
      server_->insert(voInteractiveMarker(vo, frame_),
                      [this](const visualization_msgs::InteractiveMarkerFeedbackConstPtr& f) {
                        onFeedback(f);
                      });
    }
    changed = true;
  }
  for (const auto& kv : shown_) {
    if (now.count(kv.first)) continue;
    server_->erase(voMarkerName(kv.first));
    changed = true;
  }
  shown_ = std::move(now);
  if (changed) server_->applyChanges();
}

void VoMarkerServer::checkFeedbackName(
    const visualization_msgs::InteractiveMarkerFeedbackConstPtr& feedback) {
  const ecar::ObjectId id = voMarkerId(feedback->marker_name);
  bool known = false;
  if (id.valid()) {
    std::lock_guard<std::mutex> lock(sync_mutex_);
    known = shown_.count(id) > 0;
  }
  if (!known) {
    ROS_WARN_THROTTLE(1.0, "rviz: feedback for unknown interactive marker '%s': ignored",
                      feedback->marker_name.c_str());
  }
}

void VoMarkerServer::resetMarker(const ecar::VirtualObject& vo) {
  server_->setPose(voMarkerName(vo.id), poseOf(vo));
  server_->applyChanges();
}

void VoMarkerServer::onFeedback(
    const visualization_msgs::InteractiveMarkerFeedbackConstPtr& feedback) {
  using Feedback = visualization_msgs::InteractiveMarkerFeedback;
  const bool mouse_up = feedback->event_type == Feedback::MOUSE_UP;
  if (!mouse_up && feedback->event_type != Feedback::POSE_UPDATE) return;
  const ecar::ObjectId id = voMarkerId(feedback->marker_name);
  if (!id.valid()) return;
  if (!feedback->header.frame_id.empty() && feedback->header.frame_id != frame_) {
    ROS_WARN_THROTTLE(1.0, "rviz: marker %s moved in frame '%s', not '%s': ignored",
                      feedback->marker_name.c_str(), feedback->header.frame_id.c_str(),
                      frame_.c_str());
    return;
  }
  if (!mouse_up) {
    if (!(drag_rate_ > 0.0)) return;
    const double now = steadySeconds();
    std::lock_guard<std::mutex> lock(drag_mutex_);
    double& last = last_move_[id];
    if (now - last < 1.0 / drag_rate_) return;
    last = now;
  } else {
    std::lock_guard<std::mutex> lock(drag_mutex_);
    last_move_.erase(id);
  }
  const std::optional<ecar::VirtualObject> current = get_(id);
  if (!current || current->deleted) {
    ROS_WARN_THROTTLE(1.0, "rviz: marker %s: object %u is %s: ignored",
                      feedback->marker_name.c_str(), id.value, current ? "deleted" : "unknown");
    return;
  }
  const geometry_msgs::Point& p = feedback->pose.position;
  const ecar::VirtualObject moved = movedInPlane(*current, Eigen::Vector3d(p.x, p.y, p.z));
  if (mouse_up && (moved.position - current->position).norm() < 1e-6) return;  // a click
  const ecar::VoOutcome outcome = move_(id, current->version, moved);
  if (!outcome.accepted) {
    ROS_WARN_THROTTLE(1.0, "rviz: move of object %u rejected: %s", id.value,
                      outcome.reason.c_str());
    resetMarker(*current);
    return;
  }
  ROS_DEBUG("rviz: object %u moved to (%.3f, %.3f, %.3f), version %u", id.value, moved.position.x(),
            moved.position.y(), moved.position.z(), outcome.version);
  // The marker snaps into the plane on mouse-up; sync() follows with the version.
  if (mouse_up) resetMarker(moved);
}

}  // namespace ecar_server
