#include "ecar_core/io/byte_codec.h"

#include <cmath>
#include <cstring>

#include <zlib.h>

#include "ecar_core/common/error.h"
#include "ecar_core/common/text.h"

namespace ecar {

uint32_t crc32(const void* data, size_t size, uint32_t crc) {
  // zlib's crc32 takes at most UInt (32-bit) lengths per call.
  const auto* p = static_cast<const Bytef*>(data);
  uLong c = crc;
  while (size > 0) {
    const uInt n = static_cast<uInt>(std::min<size_t>(size, 1u << 30));
    c = ::crc32(c, p, n);
    p += n;
    size -= n;
  }
  return static_cast<uint32_t>(c);
}

// ---------------------------------------------------------------- ByteWriter

void ByteWriter::little(uint64_t v, int n) {
  for (int i = 0; i < n; ++i) bytes_.push_back(static_cast<uint8_t>(v >> (8 * i)));
}

void ByteWriter::f32(float v) {
  uint32_t bits;
  std::memcpy(&bits, &v, 4);
  u32(bits);
}

void ByteWriter::f64(double v) {
  uint64_t bits;
  std::memcpy(&bits, &v, 8);
  u64(bits);
}

void ByteWriter::bytes(const void* data, size_t size) {
  const auto* p = static_cast<const uint8_t*>(data);
  bytes_.insert(bytes_.end(), p, p + size);
}

void ByteWriter::string(const std::string& s) {
  u32(static_cast<uint32_t>(s.size()));
  bytes(s.data(), s.size());
}

void ByteWriter::vec3(const Eigen::Vector3d& v) {
  for (int i = 0; i < 3; ++i) f64(v[i]);
}

void ByteWriter::se3(const SE3& T) {
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) f64(T.linear()(r, c));
  }
  vec3(T.translation());
}

// ---------------------------------------------------------------- ByteReader

ByteReader::ByteReader(const uint8_t* data, size_t size, std::string context,
                       std::shared_ptr<const void> owner)
    : owner_(std::move(owner)), data_(data), size_(size), context_(std::move(context)) {}

void ByteReader::fail(const std::string& field, const std::string& problem) const {
  std::string where = context_;
  if (!scope_.empty()) where += ", " + scope_;
  throw Error(where + ", field " + quote(field) + " at byte " + std::to_string(offset_) + ": " +
              problem);
}

const uint8_t* ByteReader::take(size_t n, const char* field) {
  if (n > remaining()) {
    fail(field, "truncated (needs " + std::to_string(n) + " bytes, " + std::to_string(remaining()) +
                    " left)");
  }
  const uint8_t* p = data_ + offset_;
  offset_ += n;
  return p;
}

uint64_t ByteReader::little(int n, const char* field) {
  const uint8_t* p = take(static_cast<size_t>(n), field);
  uint64_t v = 0;
  for (int i = 0; i < n; ++i) v |= static_cast<uint64_t>(p[i]) << (8 * i);
  return v;
}

uint8_t ByteReader::u8(const char* field) { return *take(1, field); }
uint16_t ByteReader::u16(const char* field) { return static_cast<uint16_t>(little(2, field)); }
uint32_t ByteReader::u32(const char* field) { return static_cast<uint32_t>(little(4, field)); }
uint64_t ByteReader::u64(const char* field) { return little(8, field); }
int32_t ByteReader::i32(const char* field) { return static_cast<int32_t>(u32(field)); }

float ByteReader::f32(const char* field) {
  const uint32_t bits = u32(field);
  float v;
  std::memcpy(&v, &bits, 4);
  return v;
}

double ByteReader::f64(const char* field) {
  const uint64_t bits = u64(field);
  double v;
  std::memcpy(&v, &bits, 8);
  return v;
}

void ByteReader::bytes(void* out, size_t size, const char* field) {
  if (size > 0) std::memcpy(out, take(size, field), size);
}

std::string ByteReader::string(const char* field, size_t max_size) {
  const uint32_t n = u32(field);
  if (n > max_size) {
    fail(field, "length " + std::to_string(n) + " above " + std::to_string(max_size));
  }
  const uint8_t* p = take(n, field);
  return std::string(reinterpret_cast<const char*>(p), n);
}

Eigen::Vector3d ByteReader::vec3(const char* field) {
  Eigen::Vector3d v;
  for (int i = 0; i < 3; ++i) v[i] = f64(field);
  return v;
}

SE3 ByteReader::se3(const char* field) {
  const size_t start = offset_;
  SE3 T = SE3::Identity();
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) T.linear()(r, c) = f64(field);
  }
  T.translation() = vec3(field);
  if (!T.matrix().allFinite()) {
    offset_ = start;
    fail(field, "non-finite transform");
  }
  const double error = (T.linear() * T.linear().transpose() - Eigen::Matrix3d::Identity()).norm();
  if (error > 1e-6 || T.linear().determinant() < 0) {
    offset_ = start;
    fail(field, "rotation is not orthonormal (error " + std::to_string(error) + ")");
  }
  return T;
}

uint32_t ByteReader::count(const char* field, size_t element_bytes) {
  const uint32_t n = u32(field);
  if (element_bytes > 0 && n > remaining() / element_bytes) {
    offset_ -= 4;
    fail(field, "count " + std::to_string(n) + " of " + std::to_string(element_bytes) +
                    "-byte elements exceeds the " + std::to_string(remaining() - 4) +
                    " bytes left (truncated or corrupted)");
  }
  return n;
}

void ByteReader::expectEnd() const {
  if (remaining() != 0) {
    fail("end", std::to_string(remaining()) + " bytes left over after the last field");
  }
}

}  // namespace ecar
