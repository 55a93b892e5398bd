// The "slam" section of a map file (map_file.h): the SLAM map's keyframes,
// points, id counters, epoch and the cameras of its keyframes.
#pragma once

#include <cstdint>
#include <memory>
#include <vector>

#include "ecar_core/common/camera.h"
#include "ecar_core/io/byte_codec.h"
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

}  // namespace ecar
