// DeviceConfig: read from rosparam in one place, validated.
#include <algorithm>
#include <cctype>
#include <cmath>

#include "ecar_bridge/params.h"
#include "ecar_core/common/error.h"
#include "ecar_device/device.h"

namespace ecar_device {
namespace {

bool isDeviceName(const std::string& name) {
  if (name.empty() || !std::isalpha(static_cast<unsigned char>(name[0]))) return false;
  return std::all_of(name.begin(), name.end(), [](char c) {
    return std::isalnum(static_cast<unsigned char>(c)) || c == '_';
  });
}

}  // namespace

void DeviceConfig::validate() const {
  auto fail = [](const std::string& key, const std::string& why) {
    throw ecar::Error("~" + key + ": " + why);
  };
  if (!isDeviceName(device_id)) {
    fail("device_id",
         "\"" + device_id + "\" is not a device name (a letter, then letters, digits, _)");
  }
  if (every < 1) fail("every", "must be >= 1");
  if (jpeg_quality < 1 || jpeg_quality > 100) fail("jpeg_quality", "must be in [1, 100]");
  if (min_jpeg_quality < 1 || min_jpeg_quality > 100) {
    fail("min_jpeg_quality", "must be in [1, 100]");
  }
  if (!sync_mode.empty() && sync_mode != "ecar" && sync_mode != "edgeslam") {
    fail("sync_mode", "must be \"\", \"ecar\" or \"edgeslam\", got \"" + sync_mode + "\"");
  }
  if (max_pending < 1) fail("max_pending", "must be >= 1");
  if (max_in_flight < 0) fail("max_in_flight", "must be >= 0 (0 = no limit)");
  if (!std::isfinite(connect_period) || connect_period <= 0.0)
    fail("connect_period", "must be > 0 s");
  if (!std::isfinite(reconnect_timeout) || reconnect_timeout <= 0.0) {
    fail("reconnect_timeout", "must be > 0 s");
  }
  if (pace_in_flight < 0) fail("pace_in_flight", "must be >= 0 (0 = no pacing)");
  if (!std::isfinite(pace_timeout) || pace_timeout <= 0.0) fail("pace_timeout", "must be > 0 s");
  if (map_frame.empty() || map_frame.front() == '/') {
    fail("map_frame", "must be a non-empty frame id without a leading slash");
  }
  if (connect_service.empty()) fail("connect_service", "must not be empty");
  if (global_metrics_topic.empty()) fail("global_metrics_topic", "must not be empty");
  if (direct_objects_topic.empty()) fail("direct_objects_topic", "must not be empty");
  if (image_transport.empty()) fail("image_transport", "must not be empty (e.g. raw, compressed)");
  if (!std::isfinite(touch_pose_timeout) || touch_pose_timeout <= 0.0) {
    fail("touch_pose_timeout", "must be > 0 s");
  }
  if (!std::isfinite(light.rate) || light.rate <= 0.0) fail("light/rate", "must be > 0");
  if (light.max_frames < 0) fail("light/max_frames", "must be >= 0 (0 = all frames)");
  if (!std::isfinite(light.wait_subscribers) || light.wait_subscribers < 0.0) {
    fail("light/wait_subscribers", "must be >= 0 s");
  }
  try {
    objects.validate();
  } catch (const ecar::Error& e) {
    throw ecar::Error(std::string("~objects/") + e.what());
  }
  try {
    tracker.validate();
  } catch (const ecar::Error& e) {
    const std::string what = e.what();
    // The core names its keys without the ROS prefix.
    if (what.rfind("keyframe_queue", 0) == 0 || what.rfind("orb.", 0) == 0) {
      std::string key = what;
      std::replace(key.begin(), key.begin() + std::min(key.find(':'), key.size()), '.', '/');
      throw ecar::Error("~" + key);
    }
    throw ecar::Error("~tracking/" + what);
  }
}

DeviceConfig parseDeviceConfig(const XmlRpc::XmlRpcValue& params, const std::string& ns,
                               std::vector<std::string>* unknown) {
  DeviceConfig c;
  c.device_id = ns;
  c.device_id.erase(0, c.device_id.find_first_not_of('/'));
  ecar_bridge::ParamReader r(params, "~");
  r.read("device_id", &c.device_id);
  r.read("every", &c.every);
  r.read("jpeg_quality", &c.jpeg_quality);
  r.read("min_jpeg_quality", &c.min_jpeg_quality);
  r.read("sync_mode", &c.sync_mode);
  r.read("max_pending", &c.max_pending);
  r.read("max_in_flight", &c.max_in_flight);
  r.read("connect_period", &c.connect_period);
  r.read("reconnect_timeout", &c.reconnect_timeout);
  r.read("pace_in_flight", &c.pace_in_flight);
  r.read("pace_timeout", &c.pace_timeout);
  r.read("map_frame", &c.map_frame);
  r.read("publish_tf", &c.publish_tf);
  r.read("connect_service", &c.connect_service);
  r.read("global_metrics_topic", &c.global_metrics_topic);
  r.read("touch_pose_timeout", &c.touch_pose_timeout);
  r.read("direct_objects_topic", &c.direct_objects_topic);
  r.read("image_transport", &c.image_transport);
  r.read("draw_points", &c.ar_view.draw_points);
  r.read("draw_objects", &c.ar_view.draw_objects);
  r.read("draw_status", &c.ar_view.draw_status);
  r.read("keyframe_queue", &c.tracker.keyframe_queue);
  ecar_bridge::ParamReader& t = r.child("tracking");
  t.read("projection_radius", &c.tracker.projection_radius);
  t.read("keyframe_radius", &c.tracker.keyframe_radius);
  t.read("refine_radius", &c.tracker.refine_radius);
  t.read("min_matches", &c.tracker.min_matches);
  t.read("min_inliers", &c.tracker.min_inliers);
  ecar_bridge::ParamReader& o = r.child("orb");
  o.read("num_features", &c.tracker.orb.num_features);
  o.read("scale_factor", &c.tracker.orb.scale_factor);
  o.read("num_levels", &c.tracker.orb.num_levels);
  o.read("fast_threshold", &c.tracker.orb.fast_threshold);
  o.read("min_fast_threshold", &c.tracker.orb.min_fast_threshold);
  ecar_bridge::ParamReader& v = r.child("objects");
  v.read("segment_length", &c.objects.segment_length);
  v.read("min_segment_length", &c.objects.min_segment_length);
  v.read("max_distance", &c.objects.max_distance);
  v.read("pick_radius", &c.objects.pick_radius);
  v.read("boundary_margin", &c.objects.boundary_margin);
  v.read("near_clip", &c.objects.near_clip);
  v.read("max_thickness_px", &c.objects.max_thickness_px);
  ecar_bridge::ParamReader& l = r.child("light");
  l.read("dataset", &c.light.dataset);
  l.read("rate", &c.light.rate);
  l.read("max_frames", &c.light.max_frames);
  l.read("cache_dir", &c.light.cache_dir);
  l.read("wait_subscribers", &c.light.wait_subscribers);
  l.read("start_topic", &c.light.start_topic);
  l.read("loop", &c.light.loop);
  if (unknown) *unknown = r.unknown();
  c.validate();
  return c;
}

DeviceConfig loadDeviceConfig(const ros::NodeHandle& pnh, const std::string& ns) {
  std::vector<std::string> unknown;
  DeviceConfig c = parseDeviceConfig(ecar_bridge::paramsOf(pnh), ns, &unknown);
  for (const auto& k : unknown) {
    ROS_WARN("%s: unknown parameter ~%s (ignored)", c.device_id.c_str(), k.c_str());
  }
  return c;
}

}  // namespace ecar_device
