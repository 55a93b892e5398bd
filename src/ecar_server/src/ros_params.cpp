#include "ecar_server/ros_params.h"

#include <chrono>

#include "ecar_core/error.h"

namespace ecar_server {
namespace {

// Reads `key` into *value when present; a value of another type is an error.
template <typename T>
void read(const ros::NodeHandle& nh, const std::string& key, T* value) {
  if (!nh.hasParam(key)) return;
  if (!nh.getParam(key, *value)) {
    throw ecar::Error("server parameter '" + nh.resolveName(key) + "' has the wrong type");
  }
}

// Doubles also accept integers written without a decimal point.
void read(const ros::NodeHandle& nh, const std::string& key, double* value) {
  if (!nh.hasParam(key)) return;
  int as_int = 0;
  if (nh.getParam(key, *value)) return;
  if (nh.getParam(key, as_int)) {
    *value = as_int;
    return;
  }
  throw ecar::Error("server parameter '" + nh.resolveName(key) + "' must be a number");
}

}  // namespace

ServerConfig loadServerConfig(const ros::NodeHandle& nh) {
  ServerConfig c;
  read(nh, "sync_mode", &c.sync_mode);
  read(nh, "workers", &c.workers);
  read(nh, "device_timeout", &c.device_timeout);
  read(nh, "max_upload_bytes", &c.max_upload_bytes);
  read(nh, "upload_queue_size", &c.upload_queue_size);
  read(nh, "device_queue_size", &c.device_queue_size);
  read(nh, "graph_queue_size", &c.graph_queue_size);
  read(nh, "keyframe_queue", &c.keyframe_queue);
  read(nh, "marker_rate", &c.marker_rate);
  read(nh, "position_tolerance", &c.position_tolerance);
  read(nh, "position_tolerance_deg", &c.position_tolerance_deg);
  read(nh, "position_tolerance_depth", &c.position_tolerance_depth);
  read(nh, "edgeslam_keyframes", &c.edgeslam_keyframes);
  read(nh, "orb_features", &c.orb_features);
  read(nh, "local_keyframes", &c.local_keyframes);
  read(nh, "camera_tolerance", &c.camera_tolerance);
  c.validate();
  return c;
}

double steadySeconds() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

}  // namespace ecar_server
