#include "ecar_core/map_io.h"

#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <set>

#include "ecar_core/error.h"

namespace ecar {
namespace {

constexpr std::array<uint8_t, 8> kMagic = {'E', 'C', 'A', 'R', 'M', 'A', 'P', 0};
/// Layout of the "slam" section's contents (independent of the container's).
constexpr uint32_t kSlamSectionVersion = 1;
constexpr size_t kDescriptorBytes = 32;
constexpr size_t kKeypointBytes = 6 * 4;  // x, y, size, angle, response, octave
constexpr size_t kObservationBytes = 8;   // keyframe id, keypoint index
constexpr uint32_t kMaxSections = 4096;

// Four tables of 256 entries: the CRC of a byte in each of the four positions
// of a 32-bit word ("slicing by 4"), about 4x faster than one table.
struct CrcTables {
  uint32_t t[4][256];
  CrcTables() {
    for (uint32_t i = 0; i < 256; ++i) {
      uint32_t c = i;
      for (int k = 0; k < 8; ++k) c = (c & 1) ? 0xEDB88320u ^ (c >> 1) : c >> 1;
      t[0][i] = c;
    }
    for (uint32_t i = 0; i < 256; ++i) {
      for (int s = 1; s < 4; ++s) t[s][i] = (t[s - 1][i] >> 8) ^ t[0][t[s - 1][i] & 0xff];
    }
  }
};

std::string errnoText() { return std::strerror(errno); }

std::string quoted(const std::string& s) { return "'" + s + "'"; }

bool validSectionName(const std::string& name) {
  if (name.empty() || name.size() > 255) return false;
  for (const char c : name) {
    if (c < 0x21 || c > 0x7e) return false;
  }
  return true;
}

// Writes all of `bytes` to the open descriptor `fd`.
bool writeAll(int fd, const std::vector<uint8_t>& bytes) {
  size_t done = 0;
  while (done < bytes.size()) {
    const ssize_t n = ::write(fd, bytes.data() + done, bytes.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) return false;
    done += static_cast<size_t>(n);
  }
  return true;
}

bool nearlyEqual(double a, double b) {
  return std::fabs(a - b) <= 1e-9 * std::max(1.0, std::max(std::fabs(a), std::fabs(b)));
}

}  // namespace

uint32_t crc32(const void* data, size_t size, uint32_t crc) {
  static const CrcTables tables;
  const auto& t = tables.t;
  const auto* p = static_cast<const uint8_t*>(data);
  uint32_t c = ~crc;
  for (; size >= 4; size -= 4, p += 4) {
    c ^= static_cast<uint32_t>(p[0]) | static_cast<uint32_t>(p[1]) << 8 |
         static_cast<uint32_t>(p[2]) << 16 | static_cast<uint32_t>(p[3]) << 24;
    c = t[3][c & 0xff] ^ t[2][(c >> 8) & 0xff] ^ t[1][(c >> 16) & 0xff] ^ t[0][c >> 24];
  }
  for (; size > 0; --size, ++p) c = t[0][(c ^ *p) & 0xff] ^ (c >> 8);
  return ~c;
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
  throw Error(where + ", field " + quoted(field) + " at byte " + std::to_string(offset_) + ": " +
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

// ---------------------------------------------------------------- MapFileWriter

void MapFileWriter::addSection(const std::string& name, std::vector<uint8_t> bytes) {
  if (!validSectionName(name)) {
    throw Error("MapFileWriter::addSection: invalid section name " + quoted(name) +
                " (1..255 printable ASCII characters)");
  }
  for (const auto& s : sections_) {
    if (s.first == name)
      throw Error("MapFileWriter::addSection: duplicate section " + quoted(name));
  }
  sections_.emplace_back(name, std::move(bytes));
}

std::vector<uint8_t> MapFileWriter::serialize() const {
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
  std::vector<uint8_t> out = header.release();
  out.reserve(offset);
  for (const auto& s : sections_) out.insert(out.end(), s.second.begin(), s.second.end());
  return out;
}

void MapFileWriter::write(const std::string& path) const {
  const std::vector<uint8_t> bytes = serialize();
  // A name of its own per write: two writers of one path never share it.
  static std::atomic<uint32_t> writes{0};
  const std::string tmp =
      path + ".tmp." + std::to_string(::getpid()) + "." + std::to_string(writes++);
  const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) {
    throw Error("map file " + quoted(path) + ": cannot create its temporary file " + quoted(tmp) +
                ": " + errnoText());
  }
  if (!writeAll(fd, bytes) || ::fsync(fd) != 0) {
    const std::string why = errnoText();
    ::close(fd);
    ::unlink(tmp.c_str());
    throw Error("map file " + quoted(path) + ": writing " + quoted(tmp) + " failed: " + why);
  }
  if (::close(fd) != 0) {
    const std::string why = errnoText();
    ::unlink(tmp.c_str());
    throw Error("map file " + quoted(path) + ": closing " + quoted(tmp) + " failed: " + why);
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) {
    const std::string why = errnoText();
    ::unlink(tmp.c_str());
    throw Error("map file " + quoted(path) + ": cannot rename " + quoted(tmp) + " to it: " + why);
  }
  // The rename itself reaches the disk with its directory.
  std::string dir = std::filesystem::path(path).parent_path().string();
  if (dir.empty()) dir = ".";
  const int dfd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (dfd >= 0) {
    ::fsync(dfd);
    ::close(dfd);
  }
}

// ---------------------------------------------------------------- MapFileReader

MapFileReader MapFileReader::open(const std::string& path) {
  std::ifstream in(path, std::ios::binary | std::ios::ate);
  if (!in) throw Error("map file " + quoted(path) + ": cannot open: " + errnoText());
  const std::streamoff size = in.tellg();
  if (size < 0) throw Error("map file " + quoted(path) + ": cannot determine its size");
  std::vector<uint8_t> bytes(static_cast<size_t>(size));
  in.seekg(0);
  if (size > 0 && !in.read(reinterpret_cast<char*>(bytes.data()), size)) {
    throw Error("map file " + quoted(path) + ": read error");
  }
  return parse(std::move(bytes), path);
}

MapFileReader MapFileReader::parse(std::vector<uint8_t> bytes, const std::string& name) {
  MapFileReader file;
  file.name_ = name;
  auto shared = std::make_shared<const std::vector<uint8_t>>(std::move(bytes));
  file.bytes_ = shared;
  const std::vector<uint8_t>& data = *shared;
  const std::string where = "map file " + quoted(name);
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
      throw Error(where + ", section " + quoted(e.name) + ": starts at byte " +
                  std::to_string(e.offset) + ", expected " + std::to_string(expected) +
                  " (corrupted header)");
    }
    if (e.size > data.size() || e.offset > data.size() - e.size) {
      throw Error(where + ", section " + quoted(e.name) + ": truncated (" + std::to_string(e.size) +
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
      throw Error("map file " + quoted(name_) + ", section " + quoted(section) +
                  ": CRC mismatch (the section is corrupted)");
    }
    return e;
  }
  throw Error("map file " + quoted(name_) + ": no section " + quoted(section));
}

ByteReader MapFileReader::reader(const std::string& section) const {
  const Entry& e = checked(section);
  return ByteReader(bytes_->data() + e.offset, e.size,
                    "map file " + quoted(name_) + ", section " + quoted(section), bytes_);
}

std::vector<uint8_t> MapFileReader::section(const std::string& section) const {
  const Entry& e = checked(section);
  return std::vector<uint8_t>(bytes_->begin() + e.offset, bytes_->begin() + e.offset + e.size);
}

// ---------------------------------------------------------------- the SLAM map
//
// Layout of the "slam" section (version kSlamSectionVersion):
//   u32 version; camera: i32 width, i32 height, f64 fx, fy, cx, cy, f64 x5
//   distortion; u32 pyramid levels, f32 scale per level; u32 epoch, u32 next
//   keyframe id, u32 next point id;
//   u32 keyframe count, each: u32 id, u32 device, u32 frame index,
//     f64 timestamp, se3 T_c_w, u8 flags (1 bad, 2 gravity, 4 odometry),
//     [vec3 gravity_c], [se3 T_o_c], u32 N, N x (f32 x, y, size, angle,
//     response, i32 octave), u8 descriptors present, [N x 32 bytes],
//     N x u32 point id (0: none);
//   u32 point count, each: u32 id, vec3 p_w, vec3 normal, f32 min and max
//     distance, u32 reference and first keyframe, i32 visible, i32 found,
//     u32 version, u8 flags (1 bad, 2 descriptor), [32 bytes descriptor],
//     u32 M, M x (u32 keyframe id, i32 keypoint index).

std::vector<uint8_t> encodeSlamMap(const Map& map, const PinholeCamera& camera) {
  ByteWriter out;
  out.u32(kSlamSectionVersion);
  const CameraParams& c = camera.params();
  out.i32(c.width);
  out.i32(c.height);
  for (const double v : {c.fx, c.fy, c.cx, c.cy}) out.f64(v);
  for (const double v : c.dist) out.f64(v);
  const ScaleInfo& scale = map.scale();
  out.u32(static_cast<uint32_t>(scale.levels()));
  for (const float s : scale.scale) out.f32(s);
  out.u32(map.epoch());
  out.u32(map.nextKeyFrameId().value);
  out.u32(map.nextPointId().value);

  const std::vector<KeyFrameId> keyframes = map.keyframeIds();
  out.u32(static_cast<uint32_t>(keyframes.size()));
  for (const KeyFrameId id : keyframes) {
    const KeyFrame& kf = *map.keyframe(id);
    const Frame& f = kf.features;
    out.u32(kf.id.value);
    out.u32(kf.device.value);
    out.u32(kf.frame_index);
    out.f64(kf.timestamp);
    out.se3(kf.T_c_w);
    out.u8(static_cast<uint8_t>((kf.bad ? 1 : 0) | (f.gravity_c ? 2 : 0) | (f.T_o_c ? 4 : 0)));
    if (f.gravity_c) out.vec3(*f.gravity_c);
    if (f.T_o_c) out.se3(*f.T_o_c);
    const bool has_descriptors = !f.descriptors.empty();
    if (has_descriptors && (f.descriptors.rows != static_cast<int>(f.keypoints.size()) ||
                            f.descriptors.cols != static_cast<int>(kDescriptorBytes) ||
                            f.descriptors.type() != CV_8U)) {
      throw Error("encodeSlamMap: keyframe " + std::to_string(id.value) +
                  " has descriptors unlike its keypoints (not N x 32 CV_8U)");
    }
    out.u32(static_cast<uint32_t>(f.keypoints.size()));
    for (const cv::KeyPoint& k : f.keypoints) {
      out.f32(k.pt.x);
      out.f32(k.pt.y);
      out.f32(k.size);
      out.f32(k.angle);
      out.f32(k.response);
      out.i32(k.octave);
    }
    // Descriptors: one 32-byte row per keypoint (none when the matrix is empty).
    out.u8(has_descriptors ? 1 : 0);
    for (int r = 0; has_descriptors && r < f.descriptors.rows; ++r) {
      out.bytes(f.descriptors.ptr<uint8_t>(r), kDescriptorBytes);
    }
    for (const MapPointId pid : kf.points) out.u32(pid.value);
  }

  const std::vector<MapPointId> points = map.pointIds();
  out.u32(static_cast<uint32_t>(points.size()));
  for (const MapPointId id : points) {
    const MapPoint& p = *map.point(id);
    out.u32(p.id.value);
    out.vec3(p.p_w);
    out.vec3(p.normal);
    out.f32(p.min_distance);
    out.f32(p.max_distance);
    out.u32(p.reference.value);
    out.u32(p.first_keyframe.value);
    out.i32(p.visible);
    out.i32(p.found);
    out.u32(p.version);
    const bool has_descriptor = !p.descriptor.empty();
    if (has_descriptor && (p.descriptor.total() != kDescriptorBytes ||
                           p.descriptor.type() != CV_8U || !p.descriptor.isContinuous())) {
      throw Error("encodeSlamMap: point " + std::to_string(id.value) +
                  " has a descriptor other than 1 x 32 CV_8U");
    }
    out.u8(static_cast<uint8_t>((p.bad ? 1 : 0) | (has_descriptor ? 2 : 0)));
    if (has_descriptor) out.bytes(p.descriptor.ptr<uint8_t>(0), kDescriptorBytes);
    out.u32(static_cast<uint32_t>(p.observations.size()));
    for (const auto& [kid, idx] : p.observations) {
      out.u32(kid.value);
      out.i32(idx);
    }
  }
  return out.release();
}

namespace {

// Reads the camera and pyramid the map was made with and checks them against
// this system's: keypoints, descriptors and distances mean nothing with others.
void checkCameraAndScale(ByteReader* in, const PinholeCamera& camera, const ScaleInfo& scale) {
  const CameraParams& c = camera.params();
  const auto same_int = [in](const char* field, int saved, int ours) {
    if (saved != ours) {
      in->fail(field, "the map was made with " + std::to_string(saved) + ", this camera has " +
                          std::to_string(ours));
    }
  };
  const auto same = [in](const char* field, double saved, double ours) {
    if (!nearlyEqual(saved, ours)) {
      in->fail(field, "the map was made with " + std::to_string(saved) + ", this camera has " +
                          std::to_string(ours));
    }
  };
  same_int("camera.width", in->i32("camera.width"), c.width);
  same_int("camera.height", in->i32("camera.height"), c.height);
  same("camera.fx", in->f64("camera.fx"), c.fx);
  same("camera.fy", in->f64("camera.fy"), c.fy);
  same("camera.cx", in->f64("camera.cx"), c.cx);
  same("camera.cy", in->f64("camera.cy"), c.cy);
  for (size_t i = 0; i < c.dist.size(); ++i)
    same("camera.distortion", in->f64("camera.distortion"), c.dist[i]);
  const uint32_t levels = in->u32("pyramid.levels");
  if (levels != static_cast<uint32_t>(scale.levels())) {
    in->fail("pyramid.levels", "the map was made with " + std::to_string(levels) +
                                   " ORB levels, this system has " +
                                   std::to_string(scale.levels()));
  }
  for (uint32_t l = 0; l < levels; ++l) {
    const float s = in->f32("pyramid.scale");
    if (std::fabs(s - scale.scale[l]) > 1e-5f * scale.scale[l]) {
      in->fail("pyramid.scale", "level " + std::to_string(l) + " scale " + std::to_string(s) +
                                    ", this system has " + std::to_string(scale.scale[l]));
    }
  }
}

}  // namespace

std::unique_ptr<Map> decodeSlamMap(ByteReader in, const PinholeCamera& camera,
                                   const ScaleInfo& scale) {
  const uint32_t version = in.u32("slam version");
  if (version != kSlamSectionVersion) {
    in.fail("slam version", "version " + std::to_string(version) + ", this build reads version " +
                                std::to_string(kSlamSectionVersion));
  }
  checkCameraAndScale(&in, camera, scale);
  const uint32_t epoch = in.u32("epoch");
  const KeyFrameId next_keyframe(in.u32("next keyframe id"));
  const MapPointId next_point(in.u32("next point id"));

  auto map = std::make_unique<Map>(scale);
  const uint32_t num_keyframes = in.count("keyframe count", 4 + 4 + 4 + 8 + 96 + 1 + 4 + 1);
  for (uint32_t k = 0; k < num_keyframes; ++k) {
    in.setScope("keyframe #" + std::to_string(k));
    KeyFrame kf;
    kf.id = KeyFrameId(in.u32("id"));
    if (!kf.id.valid() || !(kf.id < next_keyframe) || map->keyframe(kf.id)) {
      in.fail("id", "keyframe id " + std::to_string(kf.id.value) +
                        " is 0, duplicate or not below the next id " +
                        std::to_string(next_keyframe.value));
    }
    in.setScope("keyframe " + std::to_string(kf.id.value));
    kf.device = DeviceId(in.u32("device"));
    kf.frame_index = in.u32("frame index");
    kf.timestamp = in.f64("timestamp");
    kf.T_c_w = in.se3("T_c_w");
    Frame& f = kf.features;
    f.frame_index = kf.frame_index;
    f.timestamp = kf.timestamp;
    const uint8_t flags = in.u8("flags");
    if (flags & ~7u) in.fail("flags", "unknown flags " + std::to_string(flags));
    kf.bad = (flags & 1) != 0;
    if (flags & 2) {
      f.gravity_c = in.vec3("gravity");
      if (!f.gravity_c->allFinite()) in.fail("gravity", "non-finite");
    }
    if (flags & 4) f.T_o_c = in.se3("odometry T_o_c");
    const uint32_t n = in.count("keypoint count", kKeypointBytes + 4);
    f.keypoints.resize(n);
    for (uint32_t i = 0; i < n; ++i) {
      cv::KeyPoint& kp = f.keypoints[i];
      kp.pt.x = in.f32("keypoint.x");
      kp.pt.y = in.f32("keypoint.y");
      kp.size = in.f32("keypoint.size");
      kp.angle = in.f32("keypoint.angle");
      kp.response = in.f32("keypoint.response");
      kp.octave = in.i32("keypoint.octave");
      if (!std::isfinite(kp.pt.x) || !std::isfinite(kp.pt.y) || !std::isfinite(kp.angle) ||
          !std::isfinite(kp.size) || kp.octave < 0 || kp.octave >= scale.levels()) {
        in.fail("keypoint", "keypoint " + std::to_string(i) +
                                " has a non-finite value or an octave outside the pyramid");
      }
    }
    const uint8_t has_descriptors = in.u8("descriptors present");
    if (has_descriptors > 1) in.fail("descriptors present", "not 0 or 1");
    if (has_descriptors) {
      if (n * kDescriptorBytes > in.remaining()) {
        in.fail("descriptors", "truncated (" + std::to_string(n) + " rows of 32 bytes)");
      }
      f.descriptors.create(static_cast<int>(n), static_cast<int>(kDescriptorBytes), CV_8U);
      for (uint32_t i = 0; i < n; ++i) {
        in.bytes(f.descriptors.ptr<uint8_t>(static_cast<int>(i)), kDescriptorBytes, "descriptors");
      }
    }
    kf.points.resize(n);
    for (uint32_t i = 0; i < n; ++i) kf.points[i] = MapPointId(in.u32("point id"));
    f.finalize(camera);
    map->insertKeyFrame(std::move(kf));
  }

  in.setScope("");
  const uint32_t num_points = in.count("point count", 4 + 48 + 8 + 8 + 12 + 1 + 4);
  for (uint32_t k = 0; k < num_points; ++k) {
    in.setScope("point #" + std::to_string(k));
    MapPoint p;
    p.id = MapPointId(in.u32("id"));
    if (!p.id.valid() || !(p.id < next_point) || map->point(p.id)) {
      in.fail("id", "point id " + std::to_string(p.id.value) +
                        " is 0, duplicate or not below the next id " +
                        std::to_string(next_point.value));
    }
    in.setScope("point " + std::to_string(p.id.value));
    p.p_w = in.vec3("p_w");
    p.normal = in.vec3("normal");
    if (!p.p_w.allFinite() || !p.normal.allFinite())
      in.fail("p_w", "non-finite position or normal");
    p.min_distance = in.f32("min distance");
    p.max_distance = in.f32("max distance");
    p.reference = KeyFrameId(in.u32("reference keyframe"));
    p.first_keyframe = KeyFrameId(in.u32("first keyframe"));
    p.visible = in.i32("visible");
    p.found = in.i32("found");
    p.version = in.u32("version");
    const uint8_t flags = in.u8("flags");
    if (flags & ~3u) in.fail("flags", "unknown flags " + std::to_string(flags));
    p.bad = (flags & 1) != 0;
    if (flags & 2) {
      p.descriptor.create(1, static_cast<int>(kDescriptorBytes), CV_8U);
      in.bytes(p.descriptor.ptr<uint8_t>(0), kDescriptorBytes, "descriptor");
    }
    const uint32_t num_obs = in.count("observation count", kObservationBytes);
    for (uint32_t o = 0; o < num_obs; ++o) {
      const KeyFrameId kid(in.u32("observation keyframe"));
      const int32_t idx = in.i32("observation keypoint");
      const KeyFrame* kf = map->keyframe(kid);
      if (!kf) {
        in.fail("observation keyframe",
                "keyframe " + std::to_string(kid.value) + " is not in the map");
      }
      if (idx < 0 || idx >= static_cast<int32_t>(kf->points.size()) || kf->points[idx] != p.id) {
        in.fail("observation keypoint", "keypoint " + std::to_string(idx) + " of keyframe " +
                                            std::to_string(kid.value) +
                                            " does not hold this point");
      }
      if (!p.observations.emplace(kid, idx).second) {
        in.fail("observation keyframe", "keyframe " + std::to_string(kid.value) + " twice");
      }
    }
    map->insertPoint(std::move(p));
  }
  in.setScope("");
  in.expectEnd();
  map->setCounters(next_keyframe, next_point, epoch);
  for (const KeyFrameId id : map->keyframeIds()) map->updateCovisibility(id);
  const std::string problem = map->checkConsistency();
  if (!problem.empty()) in.fail("map", "inconsistent map: " + problem);
  return map;
}

}  // namespace ecar

// ---------------------------------------------------------------- structure

namespace ecar {
namespace {

// Layouts of the structure sections (independent of the container's).
constexpr uint32_t kPlanesSectionVersion = 1;
constexpr uint32_t kGridSectionVersion = 1;
constexpr uint32_t kVosSectionVersion = 1;
constexpr size_t kMaxOwnerBytes = 4096;

void checkVersion(ByteReader* in, const char* section, uint32_t expected) {
  const uint32_t version = in->u32("version");
  if (version != expected) {
    in->fail("version", std::string(section) + " section version " + std::to_string(version) +
                            ", this build reads version " + std::to_string(expected));
  }
}

}  // namespace

PinholeCamera decodeSlamCamera(ByteReader in) {
  const uint32_t version = in.u32("slam version");
  if (version != kSlamSectionVersion) {
    in.fail("slam version", "version " + std::to_string(version) + ", this build reads version " +
                                std::to_string(kSlamSectionVersion));
  }
  CameraParams c;
  c.width = in.i32("camera.width");
  c.height = in.i32("camera.height");
  c.fx = in.f64("camera.fx");
  c.fy = in.f64("camera.fy");
  c.cx = in.f64("camera.cx");
  c.cy = in.f64("camera.cy");
  for (double& d : c.dist) d = in.f64("camera.distortion");
  try {
    return PinholeCamera(c);
  } catch (const Error& e) {
    in.fail("camera", e.what());
  }
}

std::vector<uint8_t> encodePlanes(const std::vector<PlaneRecord>& planes, uint32_t next_id) {
  ByteWriter out;
  out.u32(kPlanesSectionVersion);
  out.u32(next_id);
  out.u32(static_cast<uint32_t>(planes.size()));
  for (const PlaneRecord& r : planes) {
    const Plane& p = r.plane;
    out.u32(p.id.value);
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
  checkVersion(&in, kPlanesSection, kPlanesSectionVersion);
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
  checkVersion(&in, kVosSection, kVosSectionVersion);
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
