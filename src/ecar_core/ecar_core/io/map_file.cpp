#include "ecar_core/io/map_file.h"

#include <algorithm>
#include <array>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <set>

#include "ecar_core/common/error.h"
#include "ecar_core/common/text.h"
#include "ecar_core/io/atomic_file.h"
#include "ecar_core/io/safe_file.h"

namespace ecar {
namespace {

constexpr std::array<uint8_t, 8> kMagic = {'E', 'C', 'A', 'R', 'M', 'A', 'P', 0};
constexpr uint32_t kMaxSections = 4096;

bool validSectionName(const std::string& name) {
  if (name.empty() || name.size() > 255) return false;
  for (const char c : name) {
    if (c < 0x21 || c > 0x7e) return false;
  }
  return true;
}

}  // namespace

// ---------------------------------------------------------------- MapFileWriter

void MapFileWriter::addSection(const std::string& name, std::vector<uint8_t> bytes) {
  if (!validSectionName(name)) {
    throw Error("MapFileWriter::addSection: invalid section name " + quote(name) +
                " (1..255 printable ASCII characters)");
  }
  for (const auto& s : sections_) {
    if (s.first == name) throw Error("MapFileWriter::addSection: duplicate section " + quote(name));
  }
  sections_.emplace_back(name, std::move(bytes));
}

std::vector<uint8_t> MapFileWriter::header() const {
  ByteWriter header;
  header.bytes(kMagic.data(), kMagic.size());
  header.u32(kMapFileVersion);
  header.u32(static_cast<uint32_t>(sections_.size()));
  size_t header_size = header.size() + 4;  // + the header CRC
  for (const auto& s : sections_) header_size += 1 + s.first.size() + 8 + 8 + 4;
  uint64_t offset = header_size;
  for (const auto& s : sections_) {
    header.u8(static_cast<uint8_t>(s.first.size()));
    header.bytes(s.first.data(), s.first.size());
    header.u64(offset);
    header.u64(s.second.size());
    header.u32(crc32(s.second.data(), s.second.size()));
    offset += s.second.size();
  }
  header.u32(crc32(header.data().data(), header.size()));
  return header.release();
}

std::vector<uint8_t> MapFileWriter::serialize() const {
  std::vector<uint8_t> out = header();
  size_t size = out.size();
  for (const auto& s : sections_) size += s.second.size();
  out.reserve(size);
  for (const auto& s : sections_) out.insert(out.end(), s.second.begin(), s.second.end());
  return out;
}

void MapFileWriter::write(const std::string& path) const {
  const std::vector<uint8_t> head = header();
  std::vector<ByteSpan> parts = {{head.data(), head.size()}};
  for (const auto& s : sections_) parts.push_back({s.second.data(), s.second.size()});
  writeFilePartsAtomically(path, parts, "map file " + quote(path));
}

// ---------------------------------------------------------------- MapFileReader

MapFileReader MapFileReader::open(const std::string& path, size_t max_bytes) {
  return parse(readRegularFile(path, max_bytes, "map file"), path);
}

MapFileReader MapFileReader::parse(std::vector<uint8_t> bytes, const std::string& name) {
  MapFileReader file;
  file.name_ = name;
  auto shared = std::make_shared<const std::vector<uint8_t>>(std::move(bytes));
  file.bytes_ = shared;
  const std::vector<uint8_t>& data = *shared;
  const std::string where = "map file " + quote(name);
  if (data.size() < kMagic.size() || !std::equal(kMagic.begin(), kMagic.end(), data.begin())) {
    throw Error(where + ": not an eCAR map file (bad magic" +
                (data.size() < kMagic.size() ? ", only " + std::to_string(data.size()) + " bytes"
                                             : std::string()) +
                ")");
  }
  ByteReader in(data.data(), data.size(), where + ", header");
  uint8_t magic[8];
  in.bytes(magic, sizeof(magic), "magic");
  file.version_ = in.u32("version");
  if (file.version_ != kMapFileVersion) {
    throw Error(where + ": format version " + std::to_string(file.version_) +
                ", this build reads version " + std::to_string(kMapFileVersion));
  }
  const uint32_t n = in.u32("section count");
  if (n > kMaxSections) in.fail("section count", std::to_string(n) + " sections (corrupted)");
  std::set<std::string> names;
  for (uint32_t i = 0; i < n; ++i) {
    in.setScope("section table entry " + std::to_string(i));
    Entry e;
    const uint8_t length = in.u8("name length");
    e.name.resize(length);
    in.bytes(e.name.data(), length, "name");
    e.offset = in.u64("offset");
    e.size = in.u64("length");
    e.crc = in.u32("crc");
    if (!validSectionName(e.name) || !names.insert(e.name).second) {
      in.fail("name", "invalid or duplicate section name (corrupted header)");
    }
    file.entries_.push_back(std::move(e));
  }
  in.setScope("");
  const size_t header_end = in.offset();
  const uint32_t header_crc = in.u32("header crc");
  if (crc32(data.data(), header_end) != header_crc) {
    throw Error(where + ": header CRC mismatch (the header is corrupted)");
  }
  uint64_t expected = in.offset();
  for (const Entry& e : file.entries_) {
    if (e.offset != expected) {
      throw Error(where + ", section " + quote(e.name) + ": starts at byte " +
                  std::to_string(e.offset) + ", expected " + std::to_string(expected) +
                  " (corrupted header)");
    }
    if (e.size > data.size() || e.offset > data.size() - e.size) {
      throw Error(where + ", section " + quote(e.name) + ": truncated (" + std::to_string(e.size) +
                  " bytes from byte " + std::to_string(e.offset) + ", the file has " +
                  std::to_string(data.size()) + ")");
    }
    expected = e.offset + e.size;
  }
  if (expected != data.size()) {
    throw Error(where + ": " + std::to_string(data.size() - expected) +
                " unexpected bytes after the last section");
  }
  return file;
}

std::vector<std::string> MapFileReader::sectionNames() const {
  std::vector<std::string> names;
  for (const Entry& e : entries_) names.push_back(e.name);
  return names;
}

bool MapFileReader::has(const std::string& section) const {
  for (const Entry& e : entries_) {
    if (e.name == section) return true;
  }
  return false;
}

const MapFileReader::Entry& MapFileReader::checked(const std::string& section) const {
  for (const Entry& e : entries_) {
    if (e.name != section) continue;
    const uint32_t crc = crc32(bytes_->data() + e.offset, e.size);
    if (crc != e.crc) {
      throw Error("map file " + quote(name_) + ", section " + quote(section) +
                  ": CRC mismatch (the section is corrupted)");
    }
    return e;
  }
  throw Error("map file " + quote(name_) + ": no section " + quote(section));
}

ByteReader MapFileReader::reader(const std::string& section) const {
  const Entry& e = checked(section);
  return ByteReader(bytes_->data() + e.offset, e.size,
                    "map file " + quote(name_) + ", section " + quote(section), bytes_);
}

std::vector<uint8_t> MapFileReader::section(const std::string& section) const {
  const Entry& e = checked(section);
  return std::vector<uint8_t>(bytes_->begin() + e.offset, bytes_->begin() + e.offset + e.size);
}

}  // namespace ecar
