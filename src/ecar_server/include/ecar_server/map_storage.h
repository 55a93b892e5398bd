// Saving and loading the server's whole map (SLAM keyframes and points,
// planes, grid links, virtual objects) to one map file (ecar_core/io/map_file.h),
// so that a session resumes in the same coordinate system. ROS-free: the
// MapStorage nodelet wraps these in /ecar/save_map and /ecar/load_map.
//
//   MapCounts saved = saveServerMap(*ctx, "/tmp/corridor.ecarmap");
//   MapCounts loaded = loadServerMap(*ctx, "/tmp/corridor.ecarmap", ros::Time::now().toSec());
//
// Thread-safety: both may run while devices are tracked, mapped, segmented
// and interact; see each function for what it holds off.
#pragma once

#include <cstdint>
#include <string>

#include "ecar_server/server_context.h"

namespace ecar_server {

/// What a map file holds (or held).
struct MapCounts {
  uint32_t keyframes = 0;
  uint32_t map_points = 0;
  uint32_t planes = 0;
  uint32_t objects = 0;  ///< tombstones included
  double milliseconds = 0.0;
  size_t bytes = 0;  ///< size of the file
};

/// Writes the whole map to `path` atomically (a temporary file beside it,
/// flushed, renamed over it). A consistent copy: the planes and grid are
/// frozen (Structure::lockForReplace) while the SLAM map is encoded under its
/// read lock, then the planes, grid and VOs are copied; tracking and mapping
/// wait only for the encoding, the file is written after the locks are
/// released. Throws ecar::Error naming the path and the problem (no map yet,
/// unwritable path, the VO store cannot be opened).
MapCounts saveServerMap(ServerContext& ctx, const std::string& path);

/// Replaces the whole map by the one in `path`. Every section is read,
/// CRC-checked and decoded first (nothing changes when one fails); then,
/// with the planes and grid frozen: the VO store and its database are
/// replaced (one transaction), the SLAM map is installed (running alignments
/// finish first, new ones wait; the mapper's queue is dropped; every tracker
/// relocalises; the map epoch moves on, so devices drop what they hold),
/// planes and grid links are swapped, every device mirror is reset and graphs
/// of uploads received before `now` are not published (ServerContext::mapStale).
/// Before any device connected, the SLAM system is created with the map's
/// camera; afterwards the map must have the devices' camera. The VO map
/// bounds follow the loaded keyframes. Throws ecar::Error naming the path,
/// the section and the field.
MapCounts loadServerMap(ServerContext& ctx, const std::string& path, double now);

}  // namespace ecar_server
