#include "ecar_core/io/structure_codec.h"

#include <algorithm>
#include <cmath>
#include <set>

#include "ecar_core/common/error.h"
#include "ecar_core/structure/vo_store.h"

namespace ecar {
namespace {

// Layouts of the structure sections (independent of the container's).
// Version 2 of planes and vos adds each one's atlas map id (version 1, still
// read, had one map: id 1).
constexpr uint32_t kPlanesSectionVersion = 2;
constexpr uint32_t kGridSectionVersion = 1;
constexpr uint32_t kVosSectionVersion = 2;
constexpr size_t kMaxOwnerBytes = 4096;

/// Reads the section version: `expected` or, when given, `oldest` up to it.
uint32_t checkVersion(ByteReader* in, const char* section, uint32_t expected, uint32_t oldest = 0) {
  const uint32_t version = in->u32("version");
  if (version != expected && (oldest == 0 || version < oldest || version > expected)) {
    in->fail("version", std::string(section) + " section version " + std::to_string(version) +
                            ", this build reads version " +
                            (oldest ? std::to_string(oldest) + " to " : std::string()) +
                            std::to_string(expected));
  }
  return version;
}

}  // namespace

std::vector<uint8_t> encodePlanes(const std::vector<PlaneRecord>& planes, uint32_t next_id) {
  ByteWriter out;
  out.u32(kPlanesSectionVersion);
  out.u32(next_id);
  out.u32(static_cast<uint32_t>(planes.size()));
  for (const PlaneRecord& r : planes) {
    const Plane& p = r.plane;
    out.u32(p.id.value);
    out.u32(p.map.value);
    out.u8(static_cast<uint8_t>(p.label));
    out.vec3(p.normal);
    out.f64(p.offset);
    out.u32(p.version);
    out.u32(p.num_points);
    out.u32(static_cast<uint32_t>(p.boundary.size()));
    for (const Eigen::Vector3d& b : p.boundary) out.vec3(b);
    out.u32(static_cast<uint32_t>(r.points.size()));
    for (const PlanePoint& q : r.points) {
      out.u32(q.id.value);
      out.vec3(q.p_w);
    }
    out.u32(static_cast<uint32_t>(r.keyframes.size()));
    for (const KeyFrameId kf : r.keyframes) out.u32(kf.value);
  }
  return out.release();
}

std::vector<PlaneRecord> decodePlanes(ByteReader in, uint32_t* next_id) {
  const uint32_t version = checkVersion(&in, kPlanesSection, kPlanesSectionVersion, 1);
  const uint32_t next = in.u32("next plane id");
  if (next < 1) in.fail("next plane id", "0");
  const uint32_t count = in.count("plane count", 4 + 1 + 24 + 8 + 4 + 4 + 12);
  std::vector<PlaneRecord> planes;
  planes.reserve(count);
  std::set<uint32_t> ids;
  std::set<uint32_t> owned_points;
  for (uint32_t k = 0; k < count; ++k) {
    in.setScope("plane #" + std::to_string(k));
    PlaneRecord r;
    Plane& p = r.plane;
    p.id = PlaneId(in.u32("id"));
    if (!p.id.valid() || p.id.value >= next || !ids.insert(p.id.value).second) {
      in.fail("id", "plane id " + std::to_string(p.id.value) +
                        " is 0, duplicate or not below the next id " + std::to_string(next));
    }
    in.setScope("plane " + std::to_string(p.id.value));
    p.map = version >= 2 ? MapId(in.u32("map")) : MapId(1);
    const uint8_t label = in.u8("label");
    if (label > static_cast<uint8_t>(PlaneLabel::kOther)) {
      in.fail("label", "unknown label " + std::to_string(label));
    }
    p.label = static_cast<PlaneLabel>(label);
    p.normal = in.vec3("normal");
    p.offset = in.f64("offset");
    if (!p.normal.allFinite() || std::fabs(p.normal.norm() - 1.0) > 1e-6 ||
        !std::isfinite(p.offset)) {
      in.fail("normal", "not a unit vector, or a non-finite offset");
    }
    p.version = in.u32("version");
    p.num_points = in.u32("num_points");
    const uint32_t num_boundary = in.count("boundary count", 24);
    for (uint32_t b = 0; b < num_boundary; ++b) {
      p.boundary.push_back(in.vec3("boundary"));
      if (!p.boundary.back().allFinite()) in.fail("boundary", "non-finite vertex");
    }
    const uint32_t num_points = in.count("point count", 28);
    for (uint32_t i = 0; i < num_points; ++i) {
      PlanePoint q;
      q.id = MapPointId(in.u32("point id"));
      q.p_w = in.vec3("point p_w");
      if (!q.id.valid() || !owned_points.insert(q.id.value).second) {
        in.fail("point id", "point " + std::to_string(q.id.value) +
                                " is 0 or held by another plane (or twice)");
      }
      if (!q.p_w.allFinite()) in.fail("point p_w", "non-finite position");
      r.points.push_back(q);
    }
    const uint32_t num_keyframes = in.count("keyframe count", 4);
    std::set<uint32_t> kfs;
    for (uint32_t i = 0; i < num_keyframes; ++i) {
      const KeyFrameId kf(in.u32("keyframe"));
      if (!kf.valid() || !kfs.insert(kf.value).second) {
        in.fail("keyframe", "keyframe " + std::to_string(kf.value) + " is 0 or twice");
      }
      r.keyframes.push_back(kf);
    }
    planes.push_back(std::move(r));
  }
  in.setScope("");
  in.expectEnd();
  *next_id = next;
  return planes;
}

std::vector<uint8_t> encodeGrid(const GridLinks& links) {
  ByteWriter out;
  out.u32(kGridSectionVersion);
  out.u32(static_cast<uint32_t>(links.size()));
  for (const auto& [kf, cells] : links) {
    out.u32(kf.value);
    out.u32(static_cast<uint32_t>(cells.size()));
    for (const CellKey& c : cells) {
      out.i32(c.x);
      out.i32(c.y);
      out.i32(c.z);
    }
  }
  return out.release();
}

GridLinks decodeGrid(ByteReader in) {
  checkVersion(&in, kGridSection, kGridSectionVersion);
  const uint32_t count = in.count("keyframe count", 8);
  GridLinks links;
  links.reserve(count);
  std::set<uint32_t> kfs;
  for (uint32_t k = 0; k < count; ++k) {
    in.setScope("link #" + std::to_string(k));
    const KeyFrameId kf(in.u32("keyframe"));
    if (!kf.valid() || !kfs.insert(kf.value).second) {
      in.fail("keyframe", "keyframe " + std::to_string(kf.value) + " is 0 or twice");
    }
    in.setScope("keyframe " + std::to_string(kf.value));
    const uint32_t n = in.count("cell count", 12);
    std::vector<CellKey> cells(n);
    for (CellKey& c : cells) {
      c.x = in.i32("cell.x");
      c.y = in.i32("cell.y");
      c.z = in.i32("cell.z");
    }
    links.emplace_back(kf, std::move(cells));
  }
  in.setScope("");
  in.expectEnd();
  return links;
}

std::vector<uint8_t> encodeVos(const VoSnapshot& vos) {
  ByteWriter out;
  out.u32(kVosSectionVersion);
  out.u32(vos.next_id.value);
  out.u32(static_cast<uint32_t>(vos.objects.size()));
  for (const VoRecord& r : vos.objects) {
    const VirtualObject& vo = r.vo;
    out.u32(vo.id.value);
    out.u32(vo.map.value);
    out.u8(static_cast<uint8_t>(vo.kind));
    out.vec3(vo.position);
    out.vec3(vo.start);
    out.vec3(vo.end);
    out.u8(vo.r);
    out.u8(vo.g);
    out.u8(vo.b);
    out.f32(vo.width);
    out.vec3(vo.normal);
    out.u32(vo.plane.value);
    out.string(vo.owner);
    out.u32(vo.version);
    out.u8(vo.deleted ? 1 : 0);
    out.u32(r.keyframe.value);
    out.string(r.last_editor);
    out.u32(r.editor_since);
  }
  return out.release();
}

VoSnapshot decodeVos(ByteReader in) {
  const uint32_t version = checkVersion(&in, kVosSection, kVosSectionVersion, 1);
  VoSnapshot vos;
  vos.next_id = ObjectId(in.u32("next object id"));
  if (!vos.next_id.valid()) in.fail("next object id", "0");
  const uint32_t count =
      in.count("object count", 4 + 1 + 72 + 3 + 4 + 24 + 4 + 4 + 4 + 1 + 4 + 4 + 4);
  vos.objects.reserve(count);
  for (uint32_t k = 0; k < count; ++k) {
    in.setScope("object #" + std::to_string(k));
    VoRecord r;
    VirtualObject& vo = r.vo;
    vo.id = ObjectId(in.u32("id"));
    in.setScope("object " + std::to_string(vo.id.value));
    vo.map = version >= 2 ? MapId(in.u32("map")) : MapId(1);
    const uint8_t kind = in.u8("kind");
    if (kind > static_cast<uint8_t>(VoKind::kAnchor)) {
      in.fail("kind", "unknown kind " + std::to_string(kind));
    }
    vo.kind = static_cast<VoKind>(kind);
    vo.position = in.vec3("position");
    vo.start = in.vec3("start");
    vo.end = in.vec3("end");
    vo.r = in.u8("r");
    vo.g = in.u8("g");
    vo.b = in.u8("b");
    vo.width = in.f32("width");
    vo.normal = in.vec3("normal");
    vo.plane = PlaneId(in.u32("plane"));
    vo.owner = in.string("owner", kMaxOwnerBytes);
    vo.version = in.u32("version");
    const uint8_t deleted = in.u8("deleted");
    if (deleted > 1) in.fail("deleted", "not 0 or 1");
    vo.deleted = deleted == 1;
    r.keyframe = KeyFrameId(in.u32("keyframe"));
    r.last_editor = in.string("last editor", kMaxOwnerBytes);
    r.editor_since = in.u32("editor since");
    vos.objects.push_back(std::move(r));
  }
  in.setScope("");
  in.expectEnd();
  try {
    checkVoSnapshot(vos, "objects");
  } catch (const Error& e) {
    in.fail("objects", e.what());
  }
  return vos;
}

void addStructureSections(MapFileWriter* writer, const StructureState& state) {
  writer->addSection(kPlanesSection, encodePlanes(state.planes, state.next_plane_id));
  writer->addSection(kGridSection, encodeGrid(state.grid));
  writer->addSection(kVosSection, encodeVos(state.vos));
}

StructureState readStructureSections(const MapFileReader& reader) {
  StructureState state;
  state.planes = decodePlanes(reader.reader(kPlanesSection), &state.next_plane_id);
  state.grid = decodeGrid(reader.reader(kGridSection));
  state.vos = decodeVos(reader.reader(kVosSection));
  return state;
}

}  // namespace ecar
