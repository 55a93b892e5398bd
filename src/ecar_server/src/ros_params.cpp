#include "ecar_server/ros_params.h"

#include <chrono>
#include <cstdlib>
#include <string>
#include <vector>

#include "ecar_core/common/error.h"

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

// Unsigned integers are read as int and range-checked.
void read(const ros::NodeHandle& nh, const std::string& key, uint32_t* value) {
  int v = static_cast<int>(*value);
  read<int>(nh, key, &v);
  if (v < 0) throw ecar::Error("server parameter '" + nh.resolveName(key) + "' must be >= 0");
  *value = static_cast<uint32_t>(v);
}

void read(const ros::NodeHandle& nh, const std::string& key, size_t* value) {
  uint32_t v = static_cast<uint32_t>(*value);
  read(nh, key, &v);
  *value = v;
}

// "~/..." is the home directory (ROS params do not expand it).
std::string expandHome(const std::string& path) {
  if (path.rfind("~/", 0) != 0) return path;
  const char* home = std::getenv("HOME");
  return std::string(home ? home : ".") + path.substr(1);
}

void readBounds(const ros::NodeHandle& nh, const std::string& key, Eigen::Vector3d* value) {
  if (!nh.hasParam(key)) return;
  std::vector<double> v;
  if (!nh.getParam(key, v) || v.size() != 3) {
    throw ecar::Error("server parameter '" + nh.resolveName(key) + "' must be a list of 3 numbers");
  }
  *value = Eigen::Vector3d(v[0], v[1], v[2]);
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
  read(nh, "gravity_sigma_deg", &c.gravity_sigma_deg);
  read(nh, "camera_tolerance", &c.camera_tolerance);

  ecar::PlaneConfig& p = c.planes;
  read(nh, "planes/distance_threshold", &p.distance_threshold);
  read(nh, "planes/min_inliers", &p.min_inliers);
  read(nh, "planes/iterations", &p.iterations);
  read(nh, "planes/max_planes", &p.max_planes);
  read(nh, "planes/seed", &p.seed);
  read(nh, "planes/cluster_cell", &p.cluster_cell);
  read(nh, "planes/horizontal_tolerance_deg", &p.horizontal_tolerance_deg);
  read(nh, "planes/vertical_tolerance_deg", &p.vertical_tolerance_deg);
  read(nh, "planes/merge_angle_deg", &p.merge_angle_deg);
  read(nh, "planes/merge_distance", &p.merge_distance);
  read(nh, "planes/merge_gap", &p.merge_gap);
  read(nh, "planes/keep_factor", &p.keep_factor);
  read(nh, "planes/graph_keyframe_planes", &c.graph_keyframe_planes);
  read(nh, "planes/graph_plane_refresh", &c.graph_plane_refresh);

  ecar::GridConfig& g = c.grid;
  read(nh, "grid/window", &g.window);
  read(nh, "grid/max_distance", &g.max_distance);
  read(nh, "grid/cell_size", &g.cell_size);
  read(nh, "grid/boundary_margin", &g.boundary_margin);

  ecar::VoStoreConfig& v = c.vo;
  read(nh, "vo/database", &v.database_path);
  v.database_path = expandHome(v.database_path);
  std::string attach = ecar::toString(v.attach_mode);
  read(nh, "vo/attach", &attach);
  try {
    v.attach_mode = ecar::parseVoAttachMode(attach);
  } catch (const ecar::Error&) {
    throw ecar::Error("server parameter '" + nh.resolveName("vo/attach") +
                      "' must be 'grid' or 'keyframe' (got '" + attach + "')");
  }
  read(nh, "vo/synchronous", &v.synchronous);
  read(nh, "vo/attach_margin", &v.attach_margin);
  readBounds(nh, "vo/map_min", &v.map_min);
  readBounds(nh, "vo/map_max", &v.map_max);
  read(nh, "vo/map_margin", &c.vo_map_margin);
  read(nh, "vo/share", &c.vo_share);
  read(nh, "vo/marker_drag_rate", &c.vo_marker_drag_rate);
  read(nh, "vo/min_line_length", &v.min_line_length);
  read(nh, "vo/max_line_length", &v.max_line_length);
  read(nh, "vo/max_width", &v.max_width);
  read(nh, "vo/max_objects", &v.max_objects);
  read(nh, "vo/accept_own_stale", &v.accept_own_stale);
  read(nh, "vo/max_database_mb", &v.max_database_mb);
  v.cell_size = g.cell_size;
  c.validate();
  return c;
}

double steadySeconds() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

}  // namespace ecar_server
