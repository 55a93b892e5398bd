// The "slam" section of a map file (map_file.h): the SLAM map's keyframes,
// points, id counters, epoch and the camera it was made with.
#pragma once

#include <cstdint>
#include <memory>
#include <vector>

#include "ecar_core/common/camera.h"
#include "ecar_core/io/byte_codec.h"
#include "ecar_core/slam/map.h"

namespace ecar {

/// Encodes the SLAM map: camera and pyramid it was made with, id counters,
/// epoch, then every keyframe (id, device, frame index, timestamp, T_c_w,
/// gravity and odometry when present, keypoints, descriptors, point id per
/// keypoint) and every map point (id, p_w, observations, descriptor, normal,
/// distance range, reference and first keyframe, visible / found, version).
/// The caller holds map.readLock().
std::vector<uint8_t> encodeSlamMap(const Map& map, const PinholeCamera& camera);

/// Decodes encodeSlamMap()'s bytes into a new map with `scale`, rebuilding
/// what is derived: undistorted keypoints and feature grids (Frame::finalize
/// with `camera`) and the covisibility graph; then Map::checkConsistency().
/// Throws ecar::Error naming the field when the bytes are malformed, the
/// values impossible, or the camera or pyramid differ from the saved ones.
std::unique_ptr<Map> decodeSlamMap(ByteReader in, const PinholeCamera& camera,
                                   const ScaleInfo& scale);

/// The camera a "slam" section was made with (its first fields), to create a
/// SLAM system for a map loaded before any device connected. Throws
/// ecar::Error as decodeSlamMap() does.
PinholeCamera decodeSlamCamera(ByteReader in);

}  // namespace ecar
