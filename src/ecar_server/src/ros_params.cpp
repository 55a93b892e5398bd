#include "ecar_server/ros_params.h"

#include <algorithm>
#include <chrono>
#include <cstdlib>
#include <map>
#include <mutex>
#include <string>
#include <vector>

#include "ecar_bridge/params.h"
#include "ecar_core/common/error.h"

namespace ecar_server {
namespace {

// Keys of the manager's namespace that are not ServerConfig's: the manager's
// own thread count and the nodelets' private namespaces (server.launch names
// them /edge_server/<module>).
const std::vector<std::string> kManagerKeys = {
    "num_worker_threads", "device_registry", "tracking",   "local_mapping", "plane_segmentation",
    "grid_connection",    "graph_publisher", "visualizer", "map_storage"};

// "~/..." is the home directory (ROS params do not expand it).
std::string expandHome(const std::string& path) {
  if (path.rfind("~/", 0) != 0) return path;
  const char* home = std::getenv("HOME");
  return std::string(home ? home : ".") + path.substr(1);
}

}  // namespace

ServerConfig parseServerConfig(const XmlRpc::XmlRpcValue& params, const std::string& name,
                               std::vector<std::string>* unknown) {
  ServerConfig c;
  ecar_bridge::ParamReader r(params, name);
  r.read("sync_mode", &c.sync_mode);
  r.read("workers", &c.workers);
  r.read("device_timeout", &c.device_timeout);
  r.read("max_devices", &c.max_devices);
  r.read("max_upload_bytes", &c.max_upload_bytes);
  r.read("upload_queue_size", &c.upload_queue_size);
  r.read("device_queue_size", &c.device_queue_size);
  r.read("graph_queue_size", &c.graph_queue_size);
  r.read("uplink_capacity", &c.uplink_capacity);
  r.read("uplink_utilisation", &c.uplink_utilisation);
  r.read("keyframe_queue", &c.keyframe_queue);
  r.read("marker_rate", &c.marker_rate);
  r.read("position_tolerance", &c.position_tolerance);
  r.read("position_tolerance_deg", &c.position_tolerance_deg);
  r.read("position_tolerance_depth", &c.position_tolerance_depth);
  r.read("edgeslam_keyframes", &c.edgeslam_keyframes);
  r.read("orb_features", &c.orb_features);
  r.read("local_keyframes", &c.local_keyframes);
  r.read("ba_whole_map_keyframes", &c.ba_whole_map_keyframes);
  r.read("gravity_sigma_deg", &c.gravity_sigma_deg);
  r.read("odometry_sigma_fraction", &c.odometry_sigma_fraction);
  r.read("odometry_sigma_walk", &c.odometry_sigma_walk);
  r.read("odometry_sigma_min", &c.odometry_sigma_min);
  r.read("loop_closing", &c.loop_closing);
  r.read("loop_min_inliers", &c.loop_min_inliers);
  r.read("loop_global_ba", &c.loop_global_ba);
  r.read("loop_by_odometry", &c.loop_by_odometry);
  r.read("loop_odometry_max_gap", &c.loop_odometry_max_gap);
  r.read("loop_odometry_min_hops", &c.loop_odometry_min_hops);
  r.read("loop_odometry_max_drift_per_link", &c.loop_odometry_max_drift_per_link);
  r.read("background_nice", &c.background_nice);
  r.read("camera_tolerance", &c.camera_tolerance);
  r.read("several_maps", &c.several_maps);
  r.read("new_map_after_lost", &c.new_map_after_lost);
  r.read("merge_maps", &c.merge_maps);
  r.read("merge_probe_every", &c.merge_probe_every);
  r.read("merge_ba_in_background", &c.merge_ba_in_background);
  r.read("map_file", &c.map_file);
  c.map_file = expandHome(c.map_file);
  r.read("map_dir", &c.map_dir);
  c.map_dir = expandHome(c.map_dir);
  r.read("max_map_mb", &c.max_map_mb);
  r.read("autosave_file", &c.autosave_file);
  if (c.autosave_file != "auto" && c.autosave_file != "none") {
    c.autosave_file = expandHome(c.autosave_file);
  }
  r.read("autosave_period", &c.autosave_period);
  r.read("heap_trim_period", &c.heap_trim_period);

  ecar::PlaneConfig& p = c.planes;
  ecar_bridge::ParamReader& planes = r.child("planes");
  planes.read("distance_threshold", &p.distance_threshold);
  planes.read("min_inliers", &p.min_inliers);
  planes.read("iterations", &p.iterations);
  planes.read("max_planes", &p.max_planes);
  planes.read("seed", &p.seed);
  planes.read("cluster_cell", &p.cluster_cell);
  planes.read("min_separation", &p.min_separation);
  planes.read("horizontal_tolerance_deg", &p.horizontal_tolerance_deg);
  planes.read("vertical_tolerance_deg", &p.vertical_tolerance_deg);
  planes.read("merge_angle_deg", &p.merge_angle_deg);
  planes.read("merge_distance", &p.merge_distance);
  planes.read("merge_gap", &p.merge_gap);
  planes.read("keep_factor", &p.keep_factor);
  planes.read("graph_keyframe_planes", &c.graph_keyframe_planes);
  planes.read("graph_plane_refresh", &c.graph_plane_refresh);
  planes.read("resend_angle_deg", &c.plane_resend_angle_deg);
  planes.read("resend_offset", &c.plane_resend_offset);
  planes.read("resend_extent", &c.plane_resend_extent);

  ecar::GridConfig& g = c.grid;
  ecar_bridge::ParamReader& grid = r.child("grid");
  grid.read("window", &g.window);
  grid.read("max_distance", &g.max_distance);
  grid.read("cell_size", &g.cell_size);
  grid.read("boundary_margin", &g.boundary_margin);

  ecar::VoStoreConfig& v = c.vo;
  ecar_bridge::ParamReader& vo = r.child("vo");
  vo.read("database", &v.database_path);
  v.database_path = expandHome(v.database_path);
  std::string attach = ecar::toString(v.attach_mode);
  vo.read("attach", &attach);
  try {
    v.attach_mode = ecar::parseVoAttachMode(attach);
  } catch (const ecar::Error&) {
    throw ecar::Error("server parameter '" + name +
                      "vo/attach' must be 'grid' or 'keyframe' (got '" + attach + "')");
  }
  vo.read("synchronous", &v.synchronous);
  vo.read("attach_margin", &v.attach_margin);
  vo.read("map_min", &v.map_min);
  vo.read("map_max", &v.map_max);
  vo.read("map_margin", &c.vo_map_margin);
  vo.read("share", &c.vo_share);
  vo.read("marker_drag_rate", &c.vo_marker_drag_rate);
  vo.read("rviz_user", &c.vo_rviz_user);
  if (!c.vo_rviz_user) v.privileged_editor.clear();
  vo.read("min_line_length", &v.min_line_length);
  vo.read("max_line_length", &v.max_line_length);
  vo.read("max_width", &v.max_width);
  vo.read("max_objects", &v.max_objects);
  std::string policy = ecar::toString(v.policy);
  vo.read("policy", &policy);
  try {
    v.policy = ecar::parseVoPolicy(policy);
  } catch (const ecar::Error&) {
    throw ecar::Error("server parameter '" + name +
                      "vo/policy' must be 'open', 'owner_delete' or 'owner_only' (got '" + policy +
                      "')");
  }
  vo.read("tombstone_retention", &v.tombstone_retention);
  vo.read("max_tombstones", &v.max_tombstones);
  vo.read("max_interaction_rate", &c.vo_max_interaction_rate);
  vo.read("interaction_burst", &c.vo_interaction_burst);
  vo.read("accept_own_stale", &v.accept_own_stale);
  vo.read("max_database_mb", &v.max_database_mb);
  v.cell_size = g.cell_size;
  if (unknown) *unknown = r.unknown();
  c.validate();
  return c;
}

ServerConfig loadServerConfig(const ros::NodeHandle& nh) {
  std::vector<std::string> unknown;
  const ServerConfig c =
      parseServerConfig(ecar_bridge::paramsOf(nh), nh.getNamespace() + "/", &unknown);
  std::string list;
  for (const std::string& key : unknown) {
    const bool manager = std::any_of(kManagerKeys.begin(), kManagerKeys.end(), [&](const auto& k) {
      return key == k || key.rfind(k + "/", 0) == 0;
    });
    if (!manager) list += (list.empty() ? "'" : ", '") + nh.getNamespace() + "/" + key + "'";
  }
  if (!list.empty()) {
    throw ecar::Error("unknown server parameter " + list +
                      " (misspelt? every key is documented in config/server.yaml)");
  }
  return c;
}

std::shared_ptr<ecar::GlobalGraph> sharedGraph(const std::string& key, const ServerConfig& config) {
  static std::mutex registry_mutex;
  static std::map<std::string, std::weak_ptr<ecar::GlobalGraph>> registry;
  std::lock_guard<std::mutex> lock(registry_mutex);
  std::shared_ptr<ecar::GlobalGraph> graph = registry[key].lock();
  if (!graph) {
    // Milliseconds of the wall clock: a restarted server has another epoch.
    const auto ms = std::chrono::duration_cast<std::chrono::milliseconds>(
                        std::chrono::system_clock::now().time_since_epoch())
                        .count();
    const uint32_t first_epoch = std::max<uint32_t>(1, static_cast<uint32_t>(ms));
    graph = std::make_shared<ecar::GlobalGraph>(config.graphConfig(first_epoch));
    registry[key] = graph;
  }
  return graph;
}

}  // namespace ecar_server
