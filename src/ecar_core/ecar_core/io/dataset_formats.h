// Private to the dataset reader: the loaders of each format (layouts in
// dataset.h). Each reads and validates `dir`; with need_camera false (the
// intrinsics are overridden) the camera is left unset.
#pragma once

#include "ecar_core/io/dataset_parsing.h"

namespace ecar::dataset_internal {

/// sim: our DatasetWriter's output.
Contents loadSim(const fs::path& dir, bool need_camera);
/// tum: TUM RGB-D benchmark folders.
Contents loadTum(const fs::path& dir, bool need_camera);
/// kitti: KITTI odometry sequences (left gray camera, image_0).
Contents loadKitti(const fs::path& dir, bool need_camera);
/// euroc: EuRoC MAV (ASL folder layout).
Contents loadEuroc(const fs::path& dir, bool need_camera);

}  // namespace ecar::dataset_internal
