// The device's parameters: defaults, config/device.yaml (every key known, the
// documented values are the defaults), and errors naming the parameter.
#include <string>

#include <gtest/gtest.h>

#include "ecar_bridge/params.h"
#include "ecar_core/common/error.h"
#include "ecar_device/device.h"

namespace ecar_device {
namespace {

std::string errorOf(const XmlRpc::XmlRpcValue& params) {
  try {
    parseDeviceConfig(params, "/device_0", nullptr);
  } catch (const ecar::Error& e) {
    return e.what();
  }
  return "";
}

TEST(DeviceConfigTest, DefaultsComeFromTheNamespace) {
  const DeviceConfig c = parseDeviceConfig(XmlRpc::XmlRpcValue(), "/device_7", nullptr);
  EXPECT_EQ(c.device_id, "device_7");
  EXPECT_EQ(c.every, 4);
  EXPECT_EQ(c.jpeg_quality, 70);
  EXPECT_EQ(c.tracker.keyframe_queue, 10);
  EXPECT_THROW(parseDeviceConfig(XmlRpc::XmlRpcValue(), "/", nullptr), ecar::Error);
}

TEST(DeviceConfigTest, ShippedYamlHasOnlyKnownKeysWithTheDefaults) {
  std::vector<std::string> unknown;
  const DeviceConfig c = parseDeviceConfig(
      ecar_bridge::paramsFromYaml(ECAR_REPO_ROOT "/config/device.yaml"), "/device_0", &unknown);
  EXPECT_TRUE(unknown.empty()) << unknown.front();
  const DeviceConfig d = parseDeviceConfig(XmlRpc::XmlRpcValue(), "/device_0", nullptr);
  EXPECT_EQ(c.every, d.every);
  EXPECT_EQ(c.jpeg_quality, d.jpeg_quality);
  EXPECT_EQ(c.min_jpeg_quality, d.min_jpeg_quality);
  EXPECT_EQ(c.sync_mode, d.sync_mode);
  EXPECT_EQ(c.max_pending, d.max_pending);
  EXPECT_DOUBLE_EQ(c.reconnect_timeout, d.reconnect_timeout);
  EXPECT_DOUBLE_EQ(c.connect_period, d.connect_period);
  EXPECT_EQ(c.pace_in_flight, d.pace_in_flight);
  EXPECT_DOUBLE_EQ(c.pace_timeout, d.pace_timeout);
  EXPECT_EQ(c.tracker.keyframe_queue, d.tracker.keyframe_queue);
  EXPECT_DOUBLE_EQ(c.tracker.projection_radius, d.tracker.projection_radius);
  EXPECT_DOUBLE_EQ(c.tracker.keyframe_radius, d.tracker.keyframe_radius);
  EXPECT_DOUBLE_EQ(c.tracker.refine_radius, d.tracker.refine_radius);
  EXPECT_EQ(c.tracker.min_matches, d.tracker.min_matches);
  EXPECT_EQ(c.tracker.min_inliers, d.tracker.min_inliers);
  EXPECT_EQ(c.tracker.orb.num_features, d.tracker.orb.num_features);
  EXPECT_FLOAT_EQ(c.tracker.orb.scale_factor, d.tracker.orb.scale_factor);
  EXPECT_EQ(c.tracker.orb.num_levels, d.tracker.orb.num_levels);
  EXPECT_DOUBLE_EQ(c.touch_pose_timeout, d.touch_pose_timeout);
  EXPECT_EQ(c.direct_objects_topic, d.direct_objects_topic);
  EXPECT_DOUBLE_EQ(c.objects.segment_length, d.objects.segment_length);
  EXPECT_DOUBLE_EQ(c.objects.min_segment_length, d.objects.min_segment_length);
  EXPECT_DOUBLE_EQ(c.objects.max_distance, d.objects.max_distance);
  EXPECT_DOUBLE_EQ(c.objects.pick_radius, d.objects.pick_radius);
  EXPECT_DOUBLE_EQ(c.objects.boundary_margin, d.objects.boundary_margin);
  EXPECT_DOUBLE_EQ(c.objects.near_clip, d.objects.near_clip);
  EXPECT_DOUBLE_EQ(c.objects.max_thickness_px, d.objects.max_thickness_px);
}

TEST(DeviceConfigTest, BadValuesNameTheParameter) {
  XmlRpc::XmlRpcValue p;
  p["every"] = 0;
  EXPECT_NE(errorOf(p).find("~every"), std::string::npos);
  p = XmlRpc::XmlRpcValue();
  p["jpeg_quality"] = 1.5;
  EXPECT_NE(errorOf(p).find("~jpeg_quality"), std::string::npos);
  p = XmlRpc::XmlRpcValue();
  p["min_jpeg_quality"] = 0;
  EXPECT_NE(errorOf(p).find("~min_jpeg_quality"), std::string::npos);
  p = XmlRpc::XmlRpcValue();
  p["sync_mode"] = std::string("full");
  EXPECT_NE(errorOf(p).find("~sync_mode"), std::string::npos);
  p = XmlRpc::XmlRpcValue();
  p["keyframe_queue"] = 0;
  EXPECT_NE(errorOf(p).find("~keyframe_queue"), std::string::npos);
  p = XmlRpc::XmlRpcValue();
  p["tracking"]["min_inliers"] = 2;
  EXPECT_NE(errorOf(p).find("~tracking/min_inliers"), std::string::npos) << errorOf(p);
  p = XmlRpc::XmlRpcValue();
  p["orb"]["num_levels"] = 0;
  EXPECT_NE(errorOf(p).find("~orb/num_levels"), std::string::npos) << errorOf(p);
  p = XmlRpc::XmlRpcValue();
  p["pace_timeout"] = -1.0;
  EXPECT_NE(errorOf(p).find("~pace_timeout"), std::string::npos);
  p = XmlRpc::XmlRpcValue();
  p["objects"]["segment_length"] = 0.0;
  EXPECT_NE(errorOf(p).find("~objects/segment_length"), std::string::npos) << errorOf(p);
  p = XmlRpc::XmlRpcValue();
  p["objects"]["pick_radius"] = std::string("wide");
  EXPECT_NE(errorOf(p).find("~objects/pick_radius"), std::string::npos) << errorOf(p);
  p = XmlRpc::XmlRpcValue();
  p["light"]["rate"] = 0.0;
  EXPECT_NE(errorOf(p).find("~light/rate"), std::string::npos) << errorOf(p);
  p = XmlRpc::XmlRpcValue();
  p["light"]["wait_subscribers"] = -1.0;
  EXPECT_NE(errorOf(p).find("~light/wait_subscribers"), std::string::npos) << errorOf(p);
}

}  // namespace
}  // namespace ecar_device
