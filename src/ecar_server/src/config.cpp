#include "ecar_server/config.h"

#include <cmath>
#include <filesystem>

#include "ecar_core/common/error.h"

namespace ecar_server {

const char* toString(VoShareMode mode) { return mode == VoShareMode::kDirect ? "direct" : "graph"; }

VoShareMode parseVoShareMode(const std::string& text) {
  if (text == "graph") return VoShareMode::kGraph;
  if (text == "direct") return VoShareMode::kDirect;
  throw ecar::Error("unknown vo share mode '" + text + "' (expected 'graph' or 'direct')");
}

void ServerConfig::validate() const {
  const auto fail = [](const std::string& key, const std::string& why) {
    throw ecar::Error("server parameter '" + key + "' " + why);
  };
  try {
    ecar::parseSyncMode(sync_mode);
  } catch (const ecar::Error&) {
    fail("sync_mode", "must be 'ecar' or 'edgeslam' (got '" + sync_mode + "')");
  }
  if (workers < 1 || workers > 64) fail("workers", "must be in [1, 64]");
  if (!(device_timeout > 0.0)) fail("device_timeout", "must be > 0 s");
  if (max_devices < 1 || max_devices > 1024) fail("max_devices", "must be in [1, 1024]");
  if (max_upload_bytes < 1000) fail("max_upload_bytes", "must be >= 1000");
  if (upload_queue_size < 1) fail("upload_queue_size", "must be >= 1");
  if (device_queue_size < 1) fail("device_queue_size", "must be >= 1");
  if (graph_queue_size < 1) fail("graph_queue_size", "must be >= 1");
  if (!(uplink_capacity >= 0.0) || !std::isfinite(uplink_capacity)) {
    fail("uplink_capacity", "must be >= 0 bytes/s (0: unknown)");
  }
  if (!(uplink_utilisation > 0.0 && uplink_utilisation <= 1.0)) {
    fail("uplink_utilisation", "must be in (0, 1]");
  }
  if (keyframe_queue < 1) fail("keyframe_queue", "must be >= 1");
  if (!(marker_rate >= 0.0) || marker_rate > 100.0) fail("marker_rate", "must be in [0, 100] Hz");
  if (!(position_tolerance >= 0.0) || position_tolerance > 0.1) {
    fail("position_tolerance", "must be in [0, 0.1] m");
  }
  if (!(position_tolerance_deg >= 0.0) || position_tolerance_deg > 10.0) {
    fail("position_tolerance_deg", "must be in [0, 10] degrees");
  }
  if (!(position_tolerance_depth >= 0.0) || position_tolerance_depth > 1.0) {
    fail("position_tolerance_depth", "must be in [0, 1]");
  }
  if (edgeslam_keyframes < 0) fail("edgeslam_keyframes", "must be >= 0");
  if (orb_features < 100 || orb_features > 100000) fail("orb_features", "must be in [100, 100000]");
  if (local_keyframes < 2) fail("local_keyframes", "must be >= 2");
  if (ba_whole_map_keyframes < 0 || ba_whole_map_keyframes > 500) {
    fail("ba_whole_map_keyframes", "must be in [0, 500]");
  }
  if (!(gravity_sigma_deg >= 0.0) || gravity_sigma_deg > 90.0) {
    fail("gravity_sigma_deg", "must be in [0, 90] degrees");
  }
  if (!(odometry_sigma_fraction >= 0.0 && odometry_sigma_fraction <= 1.0)) {
    fail("odometry_sigma_fraction", "must be in [0, 1]");
  }
  if (!(odometry_sigma_walk >= 0.0 && odometry_sigma_walk <= 1.0)) {
    fail("odometry_sigma_walk", "must be in [0, 1] m per sqrt(m)");
  }
  if (!(odometry_sigma_min > 0.0 && odometry_sigma_min <= 1.0)) {
    fail("odometry_sigma_min", "must be in (0, 1] m");
  }
  if (background_nice < 0 || background_nice > 19) fail("background_nice", "must be in [0, 19]");
  if (!(autosave_period >= 1.0 && autosave_period <= 86400.0)) {
    fail("autosave_period", "must be in [1, 86400] s");
  }
  if (!(heap_trim_period >= 0.0 && heap_trim_period <= 3600.0)) {
    fail("heap_trim_period", "must be in [0, 3600] s (0 = never)");
  }
  if (map_dir.empty()) fail("map_dir", "must be a folder");
  if (!(max_map_mb >= 1.0 && max_map_mb <= 65536.0)) fail("max_map_mb", "must be in [1, 65536] MB");
  if (autosave_file.empty()) fail("autosave_file", "must be 'auto', 'none' or a path");
  if (loop_min_inliers < 10 || loop_min_inliers > 10000) {
    fail("loop_min_inliers", "must be in [10, 10000]");
  }
  if (!(loop_odometry_max_gap > 0.0 && loop_odometry_max_gap <= 60.0)) {
    fail("loop_odometry_max_gap", "must be in (0, 60] s");
  }
  if (loop_odometry_min_hops < 1 || loop_odometry_min_hops > 20) {
    fail("loop_odometry_min_hops", "must be in [1, 20] covisibility links");
  }
  if (!(loop_odometry_max_drift_per_link > 0.0 && loop_odometry_max_drift_per_link <= 1.0)) {
    fail("loop_odometry_max_drift_per_link", "must be in (0, 1] m");
  }
  if (!(camera_tolerance >= 0.0 && camera_tolerance < 1.0)) {
    fail("camera_tolerance", "must be in [0, 1)");
  }
  if (new_map_after_lost < 0 || new_map_after_lost > 100000) {
    fail("new_map_after_lost", "must be in [0, 100000] uploads");
  }
  if (merge_probe_every < 0 || merge_probe_every > 100000) {
    fail("merge_probe_every", "must be in [0, 100000] uploads");
  }
  if (graph_plane_refresh < 1) fail("planes/graph_plane_refresh", "must be >= 1");
  try {
    composerConfig().validate();
  } catch (const ecar::Error& e) {
    fail("planes/resend", e.what());
  }
  planes.validate();
  grid.validate();
  try {
    vo.validate();
  } catch (const ecar::Error& e) {
    fail("vo", e.what());
  }
  if (vo.database_path.empty()) fail("vo.database", "must not be empty");
  if (!(vo_map_margin >= 0.0)) fail("vo.map_margin", "must be >= 0 m");
  try {
    parseVoShareMode(vo_share);
  } catch (const ecar::Error&) {
    fail("vo.share", "must be 'graph' or 'direct' (got '" + vo_share + "')");
  }
  if (!(vo_max_interaction_rate >= 0.0 && vo_max_interaction_rate <= 1e6)) {
    fail("vo.max_interaction_rate", "must be in [0, 1e6] per second (0 = unlimited)");
  }
  if (!(vo_interaction_burst >= 1.0 && vo_interaction_burst <= 1e6)) {
    fail("vo.interaction_burst", "must be in [1, 1e6]");
  }
  if (!(vo_marker_drag_rate >= 0.0) || vo_marker_drag_rate > 100.0) {
    fail("vo.marker_drag_rate", "must be in [0, 100] Hz");
  }
}

std::string ServerConfig::autosavePath() const {
  if (autosave_file == "none") return {};
  if (autosave_file != "auto") return autosave_file;
  if (vo.database_path.empty() || vo.database_path == ":memory:") return {};
  const std::filesystem::path db(vo.database_path);
  return (db.parent_path() / (db.stem().string() + ".autosave.ecarmap")).string();
}

bool ServerConfig::mapFileIsAutosave() const {
  const std::string autosave = autosavePath();
  if (map_file.empty() || autosave.empty()) return false;
  std::error_code a, b;  // the same file, however written ("x/../db.autosave.ecarmap")
  const std::filesystem::path p = std::filesystem::weakly_canonical(map_file, a);
  const std::filesystem::path q = std::filesystem::weakly_canonical(autosave, b);
  return !a && !b && p == q;
}

ecar::SlamConfig ServerConfig::slamConfig() const {
  ecar::SlamConfig c;
  c.orb.num_features = orb_features;
  c.local_keyframes = local_keyframes;
  c.ba_whole_map_keyframes = ba_whole_map_keyframes;
  c.ba.gravity_sigma_deg = gravity_sigma_deg;
  c.odometry_sigma_fraction = odometry_sigma_fraction;
  c.odometry_sigma_walk = odometry_sigma_walk;
  c.odometry_sigma_min = odometry_sigma_min;
  c.loops.enabled = loop_closing;
  c.loops.min_inliers = loop_min_inliers;
  c.loops.global_ba = loop_global_ba;
  c.loops.by_odometry = loop_by_odometry;
  c.loops.odometry_max_gap = loop_odometry_max_gap;
  c.loops.odometry_min_hops = loop_odometry_min_hops;
  c.loops.odometry_max_drift_per_link = loop_odometry_max_drift_per_link;
  c.background_nice = background_nice;
  c.synchronous_mapping = false;
  return c;
}

ecar::GlobalGraphConfig ServerConfig::graphConfig(uint32_t first_epoch) const {
  ecar::GlobalGraphConfig c;
  c.slam = slamConfig();
  c.slam.first_epoch = first_epoch;
  c.planes = planes;
  c.grid = grid;
  c.vo = vo;
  c.vo.cell_size = grid.cell_size;
  c.vo_map_margin = vo_map_margin;
  c.camera_tolerance = camera_tolerance;
  c.atlas.several_maps = several_maps;
  c.atlas.new_map_after_lost = new_map_after_lost;
  c.atlas.merge = merge_maps;
  c.atlas.relocalise_every = merge_probe_every;
  c.atlas.background_merge_ba = merge_ba_in_background;
  c.devices.default_mode = syncMode();
  c.devices.default_keyframe_queue = static_cast<size_t>(keyframe_queue);
  c.devices.device_timeout = device_timeout;
  c.devices.max_devices = static_cast<size_t>(max_devices);
  return c;
}

ecar::UplinkShareConfig ServerConfig::uplinkShareConfig() const {
  ecar::UplinkShareConfig c;
  c.capacity = uplink_capacity;
  c.utilisation = uplink_utilisation;
  return c;
}

ecar::LocalGraphComposerConfig ServerConfig::composerConfig() const {
  ecar::LocalGraphComposerConfig c;
  c.edgeslam_keyframes = edgeslam_keyframes;
  c.position_tolerance = position_tolerance;
  c.position_tolerance_deg = position_tolerance_deg;
  c.position_tolerance_depth = position_tolerance_depth;
  c.plane_refresh = graph_plane_refresh;
  c.plane_resend_angle_deg = plane_resend_angle_deg;
  c.plane_resend_offset = plane_resend_offset;
  c.plane_resend_extent = plane_resend_extent;
  return c;
}

ecar::GridConnectionConfig ServerConfig::gridConnectionConfig() const {
  ecar::GridConnectionConfig c;
  c.keyframe_planes = graph_keyframe_planes;
  c.objects = voShare() == VoShareMode::kGraph;
  c.max_interaction_rate = vo_max_interaction_rate;
  c.interaction_burst = vo_interaction_burst;
  return c;
}

}  // namespace ecar_server
