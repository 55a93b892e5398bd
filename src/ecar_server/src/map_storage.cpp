#include "ecar_server/map_storage.h"

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <limits>
#include <memory>

#include "ecar_core/common/error.h"
#include "ecar_core/io/map_file.h"
#include "ecar_core/io/slam_map_codec.h"
#include "ecar_core/io/structure_codec.h"

namespace ecar_server {
namespace {

double msSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
      .count();
}

// Keyframes and points of a map (its read lock held, or unshared).
void countMap(const ecar::Map& map, MapCounts* counts) {
  counts->keyframes = static_cast<uint32_t>(map.keyframeIds().size());
  counts->map_points = static_cast<uint32_t>(map.pointIds().size());
}

// The keyframe centres' extent plus `margin`, within the configured bounds.
void updateVoBounds(ServerContext& ctx, const ecar::SlamSystem& slam) {
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::max());
  Eigen::Vector3d hi = -lo;
  {
    auto lock = slam.map().readLock();
    for (const auto& id : slam.map().keyframeIds()) {
      const ecar::KeyFrame* k = slam.map().keyframe(id);
      if (!k || k->bad) continue;
      lo = lo.cwiseMin(k->center());
      hi = hi.cwiseMax(k->center());
    }
  }
  if (lo.x() > hi.x()) return;
  const Eigen::Vector3d margin = Eigen::Vector3d::Constant(ctx.config().vo_map_margin);
  const ecar::VoStoreConfig& vo = ctx.config().vo;
  ctx.structure().vos().setMapBounds((lo - margin).cwiseMax(vo.map_min),
                                     (hi + margin).cwiseMin(vo.map_max));
}

}  // namespace

MapCounts saveServerMap(ServerContext& ctx, const std::string& path) {
  const auto start = std::chrono::steady_clock::now();
  const std::string where = "map file '" + path + "'";
  const std::shared_ptr<ecar::SlamSystem> slam = ctx.slam();
  if (!slam) throw ecar::Error(where + ": nothing to save, no device has connected yet");
  MapCounts counts;
  ecar::MapFileWriter writer;
  {
    Structure& structure = ctx.structure();
    auto frozen = structure.lockForReplace();
    std::vector<uint8_t> slam_bytes;
    {
      auto lock = slam->map().readLock();
      slam_bytes = ecar::encodeSlamMap(slam->map(), slam->camera());
      countMap(slam->map(), &counts);
    }
    writer.addSection(ecar::kSlamSection, std::move(slam_bytes));
    ecar::StructureState state;
    try {
      state = structure.save();
    } catch (const ecar::Error& e) {
      throw ecar::Error(where + ": " + e.what());
    }
    counts.planes = static_cast<uint32_t>(state.planes.size());
    counts.objects = static_cast<uint32_t>(state.vos.objects.size());
    ecar::addStructureSections(&writer, state);
  }
  writer.write(path);  // names the path in its errors
  std::error_code ec;
  counts.bytes = static_cast<size_t>(std::filesystem::file_size(path, ec));
  counts.milliseconds = msSince(start);
  return counts;
}

MapCounts loadServerMap(ServerContext& ctx, const std::string& path, double now) {
  const auto start = std::chrono::steady_clock::now();
  const ecar::MapFileReader file = ecar::MapFileReader::open(path);
  // Decode everything before anything changes.
  std::shared_ptr<ecar::SlamSystem> slam = ctx.slam();
  const ecar::PinholeCamera camera =
      slam ? slam->camera() : ecar::decodeSlamCamera(file.reader(ecar::kSlamSection));
  const ecar::ScaleInfo scale =
      slam ? slam->map().scale() : ecar::ScaleInfo::fromConfig(ctx.config().slamConfig().orb);
  std::unique_ptr<ecar::Map> map =
      ecar::decodeSlamMap(file.reader(ecar::kSlamSection), camera, scale);
  const ecar::StructureState state = ecar::readStructureSections(file);
  MapCounts counts;
  countMap(*map, &counts);
  counts.planes = static_cast<uint32_t>(state.planes.size());
  counts.objects = static_cast<uint32_t>(state.vos.objects.size());
  counts.bytes = file.fileSize();

  ctx.beginMapReplace();
  try {
    Structure& structure = ctx.structure();
    auto frozen = structure.lockForReplace();
    // The VO store first: a database failure changes nothing.
    structure.replace(state, [&] {
      if (!slam) slam = ctx.slamFor(camera);
      slam->installMap(std::move(map));
    });
    ctx.resetMirrors();
  } catch (const ecar::Error& e) {
    ctx.mapReplaceFailed();
    throw ecar::Error("map file '" + path + "': " + e.what());
  }
  ctx.mapReplaced(now);
  try {
    updateVoBounds(ctx, *slam);
  } catch (const ecar::Error&) {
    // The configured bounds stay (the map's keyframes lie inside them anyway).
  }
  counts.milliseconds = msSince(start);
  return counts;
}

}  // namespace ecar_server
