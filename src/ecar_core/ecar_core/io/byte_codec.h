// Little-endian fixed-width encoding of map file sections (map_file.h):
// ByteWriter appends, ByteReader reads with errors naming the file, the
// section and the field; crc32 checks them.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "ecar_core/common/geometry.h"

namespace ecar {

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

  /// Room for `bytes` in all, so that a large record grows without copies.
  void reserve(size_t bytes) { bytes_.reserve(bytes); }
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

}  // namespace ecar
