// Map files: the server's whole map in one binary file, so that a session can
// resume in the same coordinate system.
//
// A map file is a container of named sections ("slam", "planes", "grid",
// "vos"), each checked by its own CRC-32:
//
//   offset 0   magic "ECARMAP" and a zero byte (8 bytes)
//          8   u32 format version (kMapFileVersion)
//         12   u32 section count
//         16   per section: u8 name length, name (ASCII), u64 offset of its
//              bytes from the start of the file, u64 length, u32 CRC-32
//              u32 CRC-32 of the header (every byte before it)
//              the sections' bytes, in table order, back to back, up to the
//              end of the file
//
// Every number is little-endian and fixed-width (floats as IEEE-754 bits).
// Readers ignore the sections they do not know. A section's contents are its
// owner's affair: encode them with ByteWriter and decode them with ByteReader,
// whose errors name the file, the section and the field.
//
//   MapFileWriter writer;
//   slam.writeMapSection(&writer);            // "slam"
//   writer.addSection("planes", planes_bytes);
//   writer.write(path);                        // temporary file, fsync, rename
//
//   const MapFileReader file = MapFileReader::open(path);  // header checked
//   std::unique_ptr<Map> map = slam.readMapSection(file);  // decoded, nothing touched
//   ByteReader in = file.reader("planes");                 // CRC checked
//   ...decode every section, then swap them all in (slam.installMap(...)).
//
// Thread-safety: the classes here are plain values; share none between threads
// without a lock.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "ecar_core/camera.h"
#include "ecar_core/geometry.h"
#include "ecar_core/map.h"
#include "ecar_core/planes.h"
#include "ecar_core/types.h"
#include "ecar_core/vo_store.h"

namespace ecar {

/// The container format this build writes and reads.
constexpr uint32_t kMapFileVersion = 1;
/// Section of the SLAM map (keyframes, points, id counters, epoch, camera).
constexpr const char* kSlamSection = "slam";
/// Section of the structure planes (PlaneMap: planes, points, keyframe links, id counter).
constexpr const char* kPlanesSection = "planes";
/// Section of the grid's keyframe-cell links (GridMap).
constexpr const char* kGridSection = "grid";
/// Section of the virtual objects (VoStore: objects, tombstones, attachments, id counter).
constexpr const char* kVosSection = "vos";

/// CRC-32 of IEEE 802.3 (reflected polynomial 0xEDB88320, as zlib and PNG), of
/// `size` bytes, continuing from `crc` (0 to start). crc32("123456789") is
/// 0xCBF43926.
uint32_t crc32(const void* data, size_t size, uint32_t crc = 0);

/// Appends little-endian fixed-width values to a byte buffer.
class ByteWriter {
 public:
  void u8(uint8_t v) { bytes_.push_back(v); }
  void u16(uint16_t v) { little(v, 2); }
  void u32(uint32_t v) { little(v, 4); }
  void u64(uint64_t v) { little(v, 8); }
  void i32(int32_t v) { little(static_cast<uint32_t>(v), 4); }
  void f32(float v);
  void f64(double v);
  /// Raw bytes, no length.
  void bytes(const void* data, size_t size);
  /// A u32 length, then the bytes.
  void string(const std::string& s);
  void vec3(const Eigen::Vector3d& v);  ///< three f64
  /// Rotation row by row, then translation: twelve f64.
  void se3(const SE3& T);

  size_t size() const { return bytes_.size(); }
  const std::vector<uint8_t>& data() const { return bytes_; }
  /// The buffer, leaving the writer empty.
  std::vector<uint8_t> release() { return std::move(bytes_); }

 private:
  void little(uint64_t v, int n);
  std::vector<uint8_t> bytes_;
};

/// Reads what ByteWriter wrote, from a buffer that outlives it (or that
/// `owner` keeps alive). Every read
/// names its field: running past the end, or a value a check rejects, throws
/// ecar::Error "<context>, <scope>, field '<field>' at byte <offset>: <problem>".
class ByteReader {
 public:
  /// `context` names the data in errors, e.g. "map.ecar, section 'slam'".
  /// `owner`, when given, keeps the buffer alive as long as the reader.
  ByteReader(const uint8_t* data, size_t size, std::string context,
             std::shared_ptr<const void> owner = nullptr);

  uint8_t u8(const char* field);
  uint16_t u16(const char* field);
  uint32_t u32(const char* field);
  uint64_t u64(const char* field);
  int32_t i32(const char* field);
  float f32(const char* field);
  double f64(const char* field);
  void bytes(void* out, size_t size, const char* field);
  /// A u32 length of at most `max_size`, then the bytes.
  std::string string(const char* field, size_t max_size = 4096);
  Eigen::Vector3d vec3(const char* field);
  /// Twelve f64; the rotation must be orthonormal (1e-6) and all finite.
  SE3 se3(const char* field);
  /// A u32 element count; fails unless `count * element_bytes` bytes remain,
  /// so a corrupted count never allocates.
  uint32_t count(const char* field, size_t element_bytes);

  /// Names where the reader is in later errors (e.g. "keyframe 12"); empty for none.
  void setScope(std::string scope) { scope_ = std::move(scope); }
  size_t offset() const { return offset_; }
  size_t remaining() const { return size_ - offset_; }
  /// Throws unless every byte was read.
  void expectEnd() const;
  /// Throws ecar::Error naming the context, scope, field and offset.
  [[noreturn]] void fail(const std::string& field, const std::string& problem) const;

 private:
  const uint8_t* take(size_t n, const char* field);
  uint64_t little(int n, const char* field);

  std::shared_ptr<const void> owner_;
  const uint8_t* data_;
  size_t size_;
  size_t offset_ = 0;
  std::string context_, scope_;
};

/// Assembles a map file from named sections and writes it atomically.
class MapFileWriter {
 public:
  /// Adds a section. Names are 1..255 printable ASCII characters, unique;
  /// throws ecar::Error otherwise.
  void addSection(const std::string& name, std::vector<uint8_t> bytes);
  /// The whole file.
  std::vector<uint8_t> serialize() const;
  /// Writes serialize() to a temporary file beside `path` (`path`.tmp.<pid>.<n>),
  /// flushes it to disk and renames it over `path`: a reader sees the old file
  /// or the new one, never a part. Throws ecar::Error naming the file and the
  /// system error (the temporary file is removed).
  void write(const std::string& path) const;

 private:
  std::vector<std::pair<std::string, std::vector<uint8_t>>> sections_;
};

/// A map file read into memory, its header checked.
class MapFileReader {
 public:
  /// Reads `path` and checks magic, version, header CRC and the section
  /// table. Throws ecar::Error naming the file and the problem (missing,
  /// foreign, other version, truncated, corrupted header).
  static MapFileReader open(const std::string& path);
  /// The same for bytes in memory; `name` stands for the file in errors.
  static MapFileReader parse(std::vector<uint8_t> bytes, const std::string& name);

  const std::string& name() const { return name_; }
  uint32_t version() const { return version_; }
  size_t fileSize() const { return bytes_->size(); }
  /// Section names in file order.
  std::vector<std::string> sectionNames() const;
  bool has(const std::string& name) const;
  /// A reader over a section, after checking its CRC (it shares the file's
  /// bytes: it may outlive this MapFileReader). Throws ecar::Error naming the file and
  /// the section when it is absent or its CRC does not match.
  ByteReader reader(const std::string& section) const;
  /// A copy of a section's bytes, checked as reader() does.
  std::vector<uint8_t> section(const std::string& section) const;

 private:
  struct Entry {
    std::string name;
    uint64_t offset = 0, size = 0;
    uint32_t crc = 0;
  };
  const Entry& checked(const std::string& section) const;

  std::string name_;
  uint32_t version_ = 0;
  std::shared_ptr<const std::vector<uint8_t>> bytes_;  ///< copies share it
  std::vector<Entry> entries_;
};

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
