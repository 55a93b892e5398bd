// The "slam" section of a map file (map_file.h): the SLAM map's keyframes,
// points, id counters, epoch and the cameras of its keyframes.
#pragma once

#include <cstdint>
#include <memory>
#include <vector>

#include "ecar_core/common/camera.h"
#include "ecar_core/io/byte_codec.h"
#include "ecar_core/io/map_file.h"
#include "ecar_core/slam/map.h"

namespace ecar {

/// Encodes the SLAM map: `default_camera` (the SLAM system's, for devices with
/// none of their own) and the distinct cameras of its keyframes, the pyramid it
/// was made with, id counters, epoch, then every keyframe (id, device, frame
/// index, timestamp, T_c_w, camera index, gravity and odometry when present,
/// keypoints, descriptors, point id per keypoint) and every map point (id,
/// p_w, observations, descriptor, normal, distance range, reference and first
/// keyframe, visible / found, version). The caller holds map.readLock().
/// Throws ecar::Error when a keyframe has no camera.
std::vector<uint8_t> encodeSlamMap(const Map& map, const PinholeCamera& default_camera);

/// Decodes encodeSlamMap()'s bytes (or a version-1 section, with one camera
/// for the whole map) into a new map with `scale`. Keyframes share one camera
/// object per saved camera; what is derived is rebuilt: undistorted keypoints
/// and feature grids (Frame::finalize with the keyframe's camera) and the
/// covisibility graph; then Map::checkConsistency(). Throws ecar::Error naming
/// the field when the bytes are malformed, the values impossible (a camera
/// PinholeCamera refuses, a camera index past the list) or the pyramid
/// differs from the saved one.
std::unique_ptr<Map> decodeSlamMap(ByteReader in, const ScaleInfo& scale);

/// The default camera of a "slam" section (its first), to create a SLAM
/// system for a map loaded before any device connected. Throws ecar::Error
/// as decodeSlamMap() does.
PinholeCamera decodeSlamCamera(ByteReader in);

/// An atlas in a map file: section "atlas" (version 1, the number of maps,
/// their ids) and each map's SLAM section, the first map's as "slam" (what a
/// one-map reader reads), the others' as "slam.<id>".
void addAtlasSections(MapFileWriter* writer,
                      std::vector<std::pair<MapId, std::vector<uint8_t>>> maps);
/// The maps of a file with the names of their SLAM sections; a file without
/// an atlas section (an older build's) holds map 1 in "slam". Throws
/// ecar::Error naming the section and field (no map, id 0 or twice, a
/// missing section).
std::vector<std::pair<MapId, std::string>> atlasSections(const MapFileReader& file);

}  // namespace ecar
