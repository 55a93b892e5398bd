// The edge server's parameters, one struct with in-class defaults (the same
// values as config/server.yaml documents). Filled from rosparam in one place
// (ros_params.h) and validated here, without ROS.
#pragma once

#include <string>

#include "ecar_core/device/upload_quality.h"
#include "ecar_core/server/global_graph.h"
#include "ecar_core/server/grid_connection.h"
#include "ecar_core/sync/local_graph_composer.h"

namespace ecar_server {

/// How VO changes reach devices (yaml vo.share).
enum class VoShareMode {
  kGraph = 0,   ///< eCAR: in the local graphs of the devices that see them
  kDirect = 1,  ///< baseline: each accepted change straight to every other connected device
};

/// "graph" or "direct".
const char* toString(VoShareMode mode);
/// Parses "graph" / "direct"; throws ecar::Error naming the value otherwise.
VoShareMode parseVoShareMode(const std::string& text);

struct ServerConfig {
  /// Default sync mode for devices whose Connect names none: "ecar" or "edgeslam".
  std::string sync_mode = "ecar";
  /// Threads aligning uploads (one device's uploads run in order, one at a time).
  int workers = 2;
  /// A device silent for this long (s) is dropped (unsubscribed, mirror and tracker forgotten).
  double device_timeout = 10.0;
  /// Devices connected at once; a connect beyond is refused.
  int max_devices = 64;
  /// Uploads whose serialized length exceeds this (bytes) are dropped.
  int max_upload_bytes = 2000000;
  /// ROS subscriber queue of each /<device>/upload topic.
  int upload_queue_size = 5;
  /// Uploads of one device waiting for a worker; when full the oldest is dropped.
  int device_queue_size = 3;
  /// Publisher queue of each /<device>/local_graph topic.
  int graph_queue_size = 10;
  /// Bytes/s of the uplink the devices share (a speed test's figure; 0:
  /// unknown). Each local graph then gives its device a budget:
  /// uplink_capacity * uplink_utilisation over the devices uploading
  /// (LocalGraph.upload_budget, ecar::UplinkShare).
  double uplink_capacity = 0.0;
  double uplink_utilisation = 0.5;  ///< (0, 1]
  /// Device keyframe queue length assumed when Connect.keyframe_queue is 0.
  int keyframe_queue = 10;
  /// /ecar/markers rate (Hz); 0 disables the markers (tf is still published).
  double marker_rate = 1.0;
  /// ecar mode: a held point is resent when its position moved more than this (m).
  double position_tolerance = 0.001;
  /// ecar mode: and only when the move seen from the aligned camera exceeds
  /// this angle (deg) across the ray or this fraction of the distance along it
  /// (either 0: no view test).
  double position_tolerance_deg = 0.05;
  double position_tolerance_depth = 0.02;
  /// edgeslam mode: local keyframes sent (the best first); 0 = all of them.
  int edgeslam_keyframes = 10;
  /// ORB keypoints per uploaded image.
  int orb_features = 1000;
  /// Keyframes in the tracker's local map.
  int local_keyframes = 25;
  /// SLAM: a metric map of at most this many keyframes is bundle-adjusted
  /// whole, so all devices' odometry sets its scale together (0: windows only;
  /// SlamConfig::ba_whole_map_keyframes).
  int ba_whole_map_keyframes = 30;
  /// SLAM: gravity prior of local bundle adjustment, degrees (0: off).
  double gravity_sigma_deg = 0.3;
  /// SLAM: odometry edges of local BA in metric maps between consecutive
  /// keyframes of a device d m apart, sigma = min + walk * sqrt(d) + fraction * d
  /// (SlamConfig::odometrySigma; walk and fraction both 0: off).
  double odometry_sigma_fraction = 0.02;
  double odometry_sigma_walk = 0.0;  ///< m per sqrt(m)
  double odometry_sigma_min = 0.01;  ///< m
  /// SLAM: loop closing (place recognition outside the covisible
  /// neighbourhood, similarity verification, pose graph, global BA).
  bool loop_closing = true;
  int loop_min_inliers = 40;   ///< similarity inliers a loop needs
  bool loop_global_ba = true;  ///< a global bundle adjustment after each loop
  /// Loops closed through a device's odometry when it relocalises elsewhere
  /// at most loop_odometry_max_gap s after it was lost (LoopClosingConfig).
  bool loop_by_odometry = true;
  double loop_odometry_max_gap = 3.0;  ///< s, in (0, 60]
  /// ... between keyframes at least this many covisibility links apart
  /// (closer ones share points: a wrong relocalisation, not drift), in [1, 20],
  /// off by at most loop_odometry_max_drift_per_link m per link, in (0, 1].
  int loop_odometry_min_hops = 3;
  double loop_odometry_max_drift_per_link = 0.04;
  int background_nice = 5;  ///< niceness added to local mapping and loop closing (0..19)
  /// Atlas: several maps (a device that matches no map starts its own at
  /// once), merged when they overlap; false: every device joins the first map.
  bool several_maps = false;
  /// Atlas: a device lost for this many uploads starts a new map (0: never).
  int new_map_after_lost = 8;
  /// Atlas: merge maps that overlap (place recognition on every new keyframe,
  /// and a relocalisation probe into another map, one per probe in turn,
  /// by one of every merge_probe_every uploads tracked in a map, of all its
  /// devices together; 0: no probes).
  bool merge_maps = true;
  int merge_probe_every = 2;
  /// Atlas: the global bundle adjustment after a merge runs on a background
  /// thread (true; the merging upload is answered at once, the next ones track
  /// in the merged map before its adjustment lands) or inside the merging
  /// upload (false: that upload waits for it, 0.9-1.4 s on the small ring).
  bool merge_ba_in_background = true;
  /// Devices' cameras within this fraction (fx, fy, cx, cy; distortion
  /// coefficients absolutely) count as one camera. Any camera may connect.
  double camera_tolerance = 0.005;

  /// Plane segmentation and merging (yaml section planes.*).
  ecar::PlaneConfig planes;
  /// Grid connection (yaml section grid.*).
  ecar::GridConfig grid;
  /// Virtual objects (yaml section vo.*): database_path, attach_mode (vo.attach), bounds.
  /// cell_size is taken from grid.cell_size. The in-class default path is
  /// ":memory:" (tests); config/server.yaml sets a file.
  ecar::VoStoreConfig vo = defaultVoConfig();
  /// m: the VO map bounds are the keyframe centres' bounding box grown by this.
  double vo_map_margin = 10.0;
  /// vo.share: "graph" (VOs ride in local graphs) or "direct" (each accepted
  /// change is relayed on /<device>/objects to every other connected device,
  /// and local graphs carry no VOs).
  std::string vo_share = "graph";
  /// vo.marker_drag_rate, Hz: MANIPULATEs sent while an rviz interactive
  /// marker is dragged (the final one is sent on mouse-up); 0 = mouse-up only.
  double vo_marker_drag_rate = 5.0;
  /// vo.rviz_user: rviz may register (Publish Point) and move (markers) VOs as
  /// the user "rviz"; false = the markers only show them.
  bool vo_rviz_user = true;
  /// vo.max_interaction_rate (per s, 0 = unlimited) and vo.interaction_burst:
  /// each device's (and rviz's) interactions (GridConnectionConfig).
  double vo_max_interaction_rate = 50.0;
  double vo_interaction_burst = 100.0;
  /// Besides the planes hit from the aligned pose, a local graph carries the
  /// planes linked to the frame's local keyframes.
  bool graph_keyframe_planes = true;
  /// A plane the device was sent at its current shape is sent again only
  /// after this many of its local graphs (a refresh in case a graph was lost);
  /// a new or visibly re-estimated plane goes out at once. 1 = in every graph.
  int graph_plane_refresh = 10;
  /// A plane the device holds is resent at once when its normal turned by more
  /// than plane_resend_angle_deg, its offset moved more than
  /// plane_resend_offset (m) or a corner of its bounding box more than
  /// plane_resend_extent (m) (yaml planes.resend_*).
  double plane_resend_angle_deg = 1.0;
  double plane_resend_offset = 0.02;
  double plane_resend_extent = 0.25;

  /// A map file (written by /ecar/save_map) to load at startup; "" = none.
  /// Set by the operator, so it may lie anywhere (unlike the services' paths).
  std::string map_file;
  /// The folder /ecar/save_map and /ecar/load_map work in: their path is a
  /// file name ending in .ecarmap there (or an absolute path in it); created
  /// when missing (ecar::MapFolder).
  std::string map_dir = "~/.ros/ecar_maps";
  /// Largest map file loaded (MB), by the services and at startup.
  double max_map_mb = 4096.0;
  /// Autosave of the whole map: "auto" = beside the VO database
  /// (<dir>/<stem>.autosave.ecarmap; none for an in-memory database), "none"
  /// = off, or a path. Written atomically every autosave_period s and when
  /// the server shuts down.
  std::string autosave_file = "auto";
  double autosave_period = 60.0;  ///< s
  /// s between returns of the heap's free pages to the system (ecar::trimHeap),
  /// also done after every save; 0 = never.
  double heap_trim_period = 10.0;
  /// The autosave path autosave_file stands for ("" = off).
  std::string autosavePath() const;
  /// Whether map_file is this server's own autosave (the same file as
  /// autosavePath()): a resume after a crash, whose VOs are merged with the
  /// database's (ecar::VoLoad::kMergeNewer) instead of replacing them.
  bool mapFileIsAutosave() const;

  /// Throws ecar::Error naming the first invalid key.
  void validate() const;
  ecar::SyncMode syncMode() const { return ecar::parseSyncMode(sync_mode); }
  VoShareMode voShare() const { return parseVoShareMode(vo_share); }
  /// SLAM options (mapping on its own thread).
  ecar::SlamConfig slamConfig() const;
  /// The global graph's options; `first_epoch` is its map epoch before any load.
  ecar::GlobalGraphConfig graphConfig(uint32_t first_epoch) const;
  /// What goes in local graphs (the resend tolerances and refresh).
  ecar::LocalGraphComposerConfig composerConfig() const;
  /// The devices' uplink share (uplink_capacity, uplink_utilisation).
  ecar::UplinkShareConfig uplinkShareConfig() const;
  /// The grid connection's options (keyframe planes, objects looked for).
  ecar::GridConnectionConfig gridConnectionConfig() const;

 private:
  static ecar::VoStoreConfig defaultVoConfig() {
    ecar::VoStoreConfig c;
    c.database_path = ":memory:";
    return c;
  }
};

}  // namespace ecar_server
