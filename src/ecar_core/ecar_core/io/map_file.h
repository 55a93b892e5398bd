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

#include "ecar_core/io/byte_codec.h"

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

/// Largest map file read by default (bytes).
constexpr size_t kMaxMapFileBytes = size_t{4} << 30;

/// Assembles a map file from named sections and writes it atomically.
class MapFileWriter {
 public:
  /// Adds a section. Names are 1..255 printable ASCII characters, unique;
  /// throws ecar::Error otherwise.
  void addSection(const std::string& name, std::vector<uint8_t> bytes);
  /// The whole file.
  std::vector<uint8_t> serialize() const;
  /// Writes serialize()'s bytes (the header, then each section from where it
  /// is held, without one buffer of the whole file) to a temporary file beside
  /// `path` (`path`.tmp.<pid>.<n>),
  /// flushes it to disk and renames it over `path`: a reader sees the old file
  /// or the new one, never a part. Throws ecar::Error naming the file and the
  /// system error (the temporary file is removed).
  void write(const std::string& path) const;

 private:
  /// Magic, version and the section table with its CRCs.
  std::vector<uint8_t> header() const;

  std::vector<std::pair<std::string, std::vector<uint8_t>>> sections_;
};

/// A map file read into memory, its header checked.
class MapFileReader {
 public:
  /// Reads `path` and checks magic, version, header CRC and the section
  /// table. Throws ecar::Error naming the file and the problem (missing,
  /// foreign, other version, truncated, corrupted header), and refuses
  /// without reading what is not a regular file (a symbolic link, a FIFO: never
  /// waited on) or is larger than `max_bytes`.
  static MapFileReader open(const std::string& path, size_t max_bytes = kMaxMapFileBytes);
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

}  // namespace ecar
