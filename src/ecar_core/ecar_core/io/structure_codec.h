// The structure sections of a map file (map_file.h): "planes", "grid" and
// "vos", what a map holds besides the SLAM map.
#pragma once

#include <cstdint>
#include <utility>
#include <vector>

#include "ecar_core/common/types.h"
#include "ecar_core/io/byte_codec.h"
#include "ecar_core/io/map_file.h"
#include "ecar_core/structure/plane_map.h"
#include "ecar_core/structure/virtual_object.h"

namespace ecar {

/// Keyframe-cell links as GridMap::save() returns them.
using GridLinks = std::vector<std::pair<KeyFrameId, std::vector<CellKey>>>;

/// Planes, grid links and virtual objects: what a map file holds besides the
/// SLAM map. Plain values: decoded into one, then swapped in.
struct StructureState {
  std::vector<PlaneRecord> planes;  ///< PlaneMap::save()
  uint32_t next_plane_id = 1;       ///< PlaneMap::nextId()
  GridLinks grid;                   ///< GridMap::save()
  VoSnapshot vos;                   ///< VoStore::snapshot()
};

/// "planes" section: u32 version, u32 next id, u32 count, each plane: u32 id,
/// u8 label, vec3 normal, f64 offset, u32 version, u32 num_points, u32 B, B x
/// vec3 boundary, u32 P, P x (u32 point id, vec3 p_w), u32 K, K x u32 keyframe.
std::vector<uint8_t> encodePlanes(const std::vector<PlaneRecord>& planes, uint32_t next_id);
/// Decodes and checks (ids valid, unique, below the next id; unit finite
/// normals; a point in one plane; label known). Throws ecar::Error naming the
/// field.
std::vector<PlaneRecord> decodePlanes(ByteReader in, uint32_t* next_id);

/// "grid" section: u32 version, u32 count, each: u32 keyframe, u32 N, N x
/// (i32 x, y, z).
std::vector<uint8_t> encodeGrid(const GridLinks& links);
/// Decodes and checks (keyframe ids valid and unique). Throws ecar::Error.
GridLinks decodeGrid(ByteReader in);

/// "vos" section: u32 version, u32 next id, u32 count, each: u32 id, u8 kind,
/// vec3 position, start, end, u8 r, g, b, f32 width, vec3 normal, u32 plane,
/// string owner, u32 version, u8 deleted, u32 keyframe, string last editor,
/// u32 editor since.
std::vector<uint8_t> encodeVos(const VoSnapshot& vos);
/// Decodes and checks (checkVoSnapshot). Throws ecar::Error naming the field.
VoSnapshot decodeVos(ByteReader in);

/// Adds the "planes", "grid" and "vos" sections.
void addStructureSections(MapFileWriter* writer, const StructureState& state);
/// Decodes the "planes", "grid" and "vos" sections (CRC checked, each
/// required). Touches nothing; throws ecar::Error naming the file, the
/// section and the field.
StructureState readStructureSections(const MapFileReader& reader);

}  // namespace ecar
