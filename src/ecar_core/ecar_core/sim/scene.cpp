#include "ecar_core/sim/scene.h"

#include <cmath>
#include <optional>
#include <set>

#include <yaml-cpp/yaml.h>

#include "ecar_core/common/error.h"

namespace ecar {
namespace {

// Reads typed values from a YAML map and reports problems as
// "<file>: <context>: <what>", so a user knows which key to fix.
class Reader {
 public:
  Reader(const YAML::Node& node, std::string file, std::string context)
      : node_(node), file_(std::move(file)), context_(std::move(context)) {
    if (!node_.IsMap()) fail("expected a map of keys");
  }

  [[noreturn]] void fail(const std::string& what) const {
    throw Error(file_ + ": " + (context_.empty() ? "" : context_ + ": ") + what);
  }

  bool has(const std::string& key) const { return static_cast<bool>(node_[key]); }

  /// Rejects keys outside `allowed` (typos must not be silently ignored).
  void allowOnly(const std::set<std::string>& allowed) const {
    for (const auto& kv : node_) {
      if (!kv.first.IsScalar()) fail("a key that is not a name (a list or a map as a key)");
      const auto key = kv.first.as<std::string>();
      if (!allowed.count(key)) fail("unknown key '" + key + "'");
    }
  }

  template <typename T>
  T get(const std::string& key) const {
    if (!has(key)) fail("missing key '" + key + "'");
    return convert<T>(key);
  }

  template <typename T>
  T get(const std::string& key, const T& fallback) const {
    return has(key) ? convert<T>(key) : fallback;
  }

  double getFinite(const std::string& key, double fallback) const {
    const double v = get<double>(key, fallback);
    if (!std::isfinite(v)) fail("key '" + key + "' must be a finite number");
    return v;
  }

  double getPositive(const std::string& key, double fallback) const {
    const double v = getFinite(key, fallback);
    if (!(v > 0)) fail("key '" + key + "' must be positive");
    return v;
  }

  Eigen::Vector3d getPoint(const std::string& key, bool allow_2d = false) const {
    const auto v = get<std::vector<double>>(key);
    return toPoint(v, "key '" + key + "'", allow_2d);
  }

  Eigen::Vector3d toPoint(const std::vector<double>& v, const std::string& what,
                          bool allow_2d) const {
    if (!(v.size() == 3 || (allow_2d && v.size() == 2))) {
      fail(what + " must be [x, y" + std::string(allow_2d ? "(, z)" : ", z") + "]");
    }
    for (double x : v) {
      if (!std::isfinite(x)) fail(what + " has a non-finite coordinate");
    }
    return {v[0], v[1], v.size() == 3 ? v[2] : 0.0};
  }

  Reader child(const std::string& key) const {
    if (!has(key)) fail("missing key '" + key + "'");
    return Reader(node_[key], file_, join(key));
  }

  YAML::Node node(const std::string& key) const { return node_[key]; }
  std::string join(const std::string& key) const {
    return context_.empty() ? key : context_ + "." + key;
  }
  const std::string& file() const { return file_; }

 private:
  template <typename T>
  T convert(const std::string& key) const {
    try {
      return node_[key].as<T>();
    } catch (const YAML::Exception&) {
      fail("key '" + key + "' has an invalid value");
    }
  }

  YAML::Node node_;
  std::string file_;
  std::string context_;
};

AlignedBox readBox(const Reader& r) {
  r.allowOnly({"name", "min", "max"});
  AlignedBox box;
  box.name = r.get<std::string>("name", "");
  box.min = r.getPoint("min");
  box.max = r.getPoint("max");
  if (!(box.max.array() > box.min.array()).all()) r.fail("'max' must exceed 'min' on every axis");
  return box;
}

std::vector<AlignedBox> readBoxes(const Reader& r, const std::string& key, bool required) {
  std::vector<AlignedBox> boxes;
  if (!r.has(key)) {
    if (required) r.fail("missing key '" + key + "'");
    return boxes;
  }
  const YAML::Node list = r.node(key);
  if (!list.IsSequence()) r.fail("key '" + key + "' must be a list of boxes");
  for (size_t i = 0; i < list.size(); ++i) {
    boxes.push_back(
        readBox(Reader(list[i], r.file(), r.join(key) + "[" + std::to_string(i) + "]")));
  }
  return boxes;
}

CameraParams readCamera(const Reader& r) {
  r.allowOnly({"width", "height", "fx", "fy", "cx", "cy", "distortion", "fps"});
  CameraParams c;
  c.width = r.get<int>("width");
  c.height = r.get<int>("height");
  for (const char* key : {"fx", "fy", "cx", "cy"}) {
    if (!r.has(key)) r.fail(std::string("missing key '") + key + "'");
  }
  c.fx = r.getPositive("fx", 0);
  c.fy = r.getPositive("fy", 0);
  c.cx = r.getFinite("cx", 0);
  c.cy = r.getFinite("cy", 0);
  c.fps = r.getPositive("fps", 30.0);
  if (r.has("distortion")) {
    const auto d = r.get<std::vector<double>>("distortion");
    if (d.size() != 4 && d.size() != 5) r.fail("key 'distortion' must be [k1, k2, p1, p2(, k3)]");
    for (size_t i = 0; i < d.size(); ++i) c.dist[i] = d[i];
  }
  if (c.width <= 0 || c.height <= 0) r.fail("'width' and 'height' must be positive");
  return c;
}

TrajectorySpec readTrajectory(const Reader& r) {
  TrajectorySpec t;
  const auto type = r.get<std::string>("type");
  const std::set<std::string> common = {"type",          "height",         "jitter_deg",
                                        "bob_amplitude", "sway_amplitude", "step_frequency",
                                        "start_pause",   "speed",          "blank"};
  auto with = [&](std::set<std::string> extra) {
    extra.insert(common.begin(), common.end());
    return extra;
  };
  t.height = r.getPositive("height", t.height);
  t.jitter_deg = r.getFinite("jitter_deg", t.jitter_deg);
  t.bob_amplitude = r.getFinite("bob_amplitude", t.bob_amplitude);
  t.sway_amplitude = r.getFinite("sway_amplitude", t.sway_amplitude);
  t.step_frequency = r.getPositive("step_frequency", t.step_frequency);
  t.start_pause = r.getFinite("start_pause", t.start_pause);
  t.speed = r.getPositive("speed", t.speed);
  if (t.start_pause < 0) r.fail("key 'start_pause' must not be negative");
  if (r.has("blank")) {
    const auto b = r.get<std::vector<double>>("blank");
    if (b.size() != 2 || !std::isfinite(b[0]) || !std::isfinite(b[1]) || b[0] < 0 || b[1] <= 0) {
      r.fail("key 'blank' must be [start_s, duration_s] with start >= 0 and duration > 0");
    }
    t.blank_start = b[0];
    t.blank_duration = b[1];
  }
  if (type == "walk") {
    r.allowOnly(with({"waypoints", "pitch_deg"}));
    t.type = TrajectoryType::kWalk;
    t.pitch_deg = r.getFinite("pitch_deg", t.pitch_deg);
    const YAML::Node list = r.node("waypoints");
    if (!list || !list.IsSequence() || list.size() < 2) {
      r.fail("key 'waypoints' must list at least two [x, y] points");
    }
    for (size_t i = 0; i < list.size(); ++i) {
      std::vector<double> v;
      try {
        v = list[i].as<std::vector<double>>();
      } catch (const YAML::Exception&) {
        r.fail("waypoints[" + std::to_string(i) + "] must be [x, y]");
      }
      t.waypoints.push_back(r.toPoint(v, "waypoints[" + std::to_string(i) + "]", true));
    }
  } else if (type == "half_circle") {
    r.allowOnly(with({"target", "radius", "start_angle_deg", "sweep_deg"}));
    t.type = TrajectoryType::kHalfCircle;
    t.target = r.getPoint("target");
    t.radius = r.getPositive("radius", t.radius);
    t.start_angle_deg = r.getFinite("start_angle_deg", t.start_angle_deg);
    t.sweep_deg = r.getFinite("sweep_deg", t.sweep_deg);
    t.speed = r.getPositive("speed", 0.4);
  } else if (type == "shake") {
    r.allowOnly(with({"position", "target", "duration", "shake_amplitude", "shake_amplitude_deg",
                      "shake_frequency"}));
    t.type = TrajectoryType::kShake;
    t.position = r.getPoint("position");
    t.target = r.getPoint("target");
    t.duration = r.getPositive("duration", t.duration);
    t.shake_amplitude = r.getFinite("shake_amplitude", t.shake_amplitude);
    t.shake_amplitude_deg = r.getFinite("shake_amplitude_deg", t.shake_amplitude_deg);
    t.shake_frequency = r.getPositive("shake_frequency", t.shake_frequency);
  } else {
    r.fail("key 'type' must be walk, half_circle or shake (got '" + type + "')");
  }
  return t;
}

// A frame number: a non-negative integer.
int readFrame(const Reader& r, const std::string& key) {
  const int frame = r.get<int>(key);
  if (frame < 0) r.fail("key '" + key + "' must be a frame number >= 0");
  return frame;
}

// A pixel [u, v] inside the image.
Eigen::Vector2d readPixel(const Reader& r, const std::string& key, const PinholeCamera& camera) {
  const auto v = r.get<std::vector<double>>(key);
  if (v.size() != 2) r.fail("key '" + key + "' must be [u, v]");
  const Eigen::Vector2d uv(v[0], v[1]);
  if (!uv.allFinite()) r.fail("key '" + key + "' has a non-finite coordinate");
  if (!camera.inImage(uv)) {
    r.fail("key '" + key + "' is outside the " + std::to_string(camera.width()) + "x" +
           std::to_string(camera.height()) + " image");
  }
  return uv;
}

// `color` and `width`, shared by events and strokes.
void readStrokeStyle(const Reader& r, TouchScriptItem* item) {
  if (r.has("color")) {
    const auto c = r.get<std::vector<int>>("color");
    if (c.size() != 3) r.fail("key 'color' must be [r, g, b]");
    for (int x : c) {
      if (x < 0 || x > 255) r.fail("key 'color' must hold integers 0-255");
    }
    item->r = static_cast<uint8_t>(c[0]);
    item->g = static_cast<uint8_t>(c[1]);
    item->b = static_cast<uint8_t>(c[2]);
  }
  item->width = r.getPositive("width", item->width);
}

// `open_stroke`: the BEGIN of the stroke in progress, if any; a MOVE or END
// takes its colour and width unless it gives its own.
TouchScriptItem readTouchEvent(const Reader& r, const PinholeCamera& camera,
                               const TouchScriptItem* open_stroke) {
  r.allowOnly({"frame", "phase", "pixel", "at", "color", "width"});
  TouchScriptItem item;
  item.start_frame = item.end_frame = readFrame(r, "frame");
  const auto phase_name = r.get<std::string>("phase");
  const auto phase = parseTouchPhase(phase_name);
  if (!phase) r.fail("key 'phase' must be begin, move or end (got '" + phase_name + "')");
  item.phase = *phase;
  if (r.has("pixel") == r.has("at")) r.fail("needs exactly one of 'pixel' and 'at'");
  item.in_world = r.has("at");
  if (item.in_world) {
    item.from_w = item.to_w = r.getPoint("at");
  } else {
    item.from_uv = item.to_uv = readPixel(r, "pixel", camera);
  }
  if (open_stroke && item.phase != TouchPhase::kBegin) {
    item.r = open_stroke->r;
    item.g = open_stroke->g;
    item.b = open_stroke->b;
    item.width = open_stroke->width;
  }
  readStrokeStyle(r, &item);
  return item;
}

TouchScriptItem readTouchStroke(const Reader& r, const PinholeCamera& camera) {
  r.allowOnly(
      {"start_frame", "end_frame", "from", "to", "from_pixel", "to_pixel", "color", "width"});
  TouchScriptItem item;
  item.stroke = true;
  item.start_frame = readFrame(r, "start_frame");
  item.end_frame = readFrame(r, "end_frame");
  if (item.end_frame <= item.start_frame) r.fail("'end_frame' must be after 'start_frame'");
  const bool world = r.has("from") || r.has("to");
  const bool pixels = r.has("from_pixel") || r.has("to_pixel");
  if (world == pixels) r.fail("needs either 'from' and 'to' or 'from_pixel' and 'to_pixel'");
  item.in_world = world;
  if (world) {
    item.from_w = r.getPoint("from");
    item.to_w = r.getPoint("to");
  } else {
    item.from_uv = readPixel(r, "from_pixel", camera);
    item.to_uv = readPixel(r, "to_pixel", camera);
  }
  readStrokeStyle(r, &item);
  return item;
}

// A device's `touches:` list. Frames strictly increase from item to item (one
// finger: no two events on one frame, strokes never overlap) and the phases
// form whole strokes.
std::vector<TouchScriptItem> readTouches(const Reader& r, const PinholeCamera& camera) {
  const YAML::Node list = r.node("touches");
  if (!list.IsSequence()) r.fail("key 'touches' must be a list");
  std::vector<TouchScriptItem> items;
  bool open = false;     // a BEGIN event started a stroke that has not ended yet
  size_t open_item = 0;  // that BEGIN's item
  for (size_t k = 0; k < list.size(); ++k) {
    const std::string ctx = r.join("touches") + "[" + std::to_string(k) + "]";
    const Reader item_reader(list[k], r.file(), ctx);
    TouchScriptItem item;
    if (item_reader.has("stroke")) {
      item_reader.allowOnly({"stroke"});
      item = readTouchStroke(item_reader.child("stroke"), camera);
    } else {
      item = readTouchEvent(item_reader, camera, open ? &items[open_item] : nullptr);
    }
    if (!items.empty() && item.start_frame <= items.back().end_frame) {
      item_reader.fail("frame " + std::to_string(item.start_frame) +
                       " must be after the previous item's (" +
                       std::to_string(items.back().end_frame) + ")");
    }
    const std::string open_at =
        open ? r.join("touches") + "[" + std::to_string(open_item) + "]" : std::string();
    if (item.stroke && open) {
      item_reader.fail("a stroke cannot start inside the stroke begun at " + open_at);
    }
    if (!item.stroke) {
      if (item.phase == TouchPhase::kBegin && open) {
        item_reader.fail("'begin' inside the stroke begun at " + open_at + " (no 'end' before)");
      }
      if (item.phase != TouchPhase::kBegin && !open) {
        item_reader.fail(std::string("'") + toString(item.phase) + "' without a 'begin' before");
      }
      if (item.phase == TouchPhase::kBegin) {
        open = true;
        open_item = k;
      }
      if (item.phase == TouchPhase::kEnd) open = false;
    }
    items.push_back(item);
  }
  if (open) {
    r.fail("touches[" + std::to_string(open_item) + "]: the stroke begun here has no 'end'");
  }
  return items;
}

DeviceSpec readDevice(const Reader& r, size_t index, const PinholeCamera& scene_camera) {
  r.allowOnly({"name", "seed", "camera", "trajectory", "odometry", "touches"});
  DeviceSpec d;
  // A device may have its own camera (another phone); touches are pixels of it.
  std::optional<PinholeCamera> own;
  if (r.has("camera")) {
    d.camera = readCamera(r.child("camera"));
    try {
      own.emplace(*d.camera);
    } catch (const Error& e) {
      r.fail(std::string("camera: ") + e.what());
    }
  }
  const PinholeCamera& camera = own ? *own : scene_camera;
  d.name = r.get<std::string>("name");
  if (d.name.empty()) r.fail("key 'name' must not be empty");
  for (char c : d.name) {
    if (!(std::isalnum(static_cast<unsigned char>(c)) || c == '_')) {
      r.fail("device name '" + d.name + "' must be a ROS name: letters, digits, '_'");
    }
  }
  d.seed = r.get<uint32_t>("seed", static_cast<uint32_t>(1000 + index));
  d.trajectory = readTrajectory(r.child("trajectory"));
  if (r.has("odometry")) {
    const Reader o = r.child("odometry");
    o.allowOnly({"scale_error", "position_walk", "yaw_walk_deg"});
    d.odometry.scale_error = o.getFinite("scale_error", d.odometry.scale_error);
    d.odometry.position_walk = o.getFinite("position_walk", d.odometry.position_walk);
    d.odometry.yaw_walk_deg = o.getFinite("yaw_walk_deg", d.odometry.yaw_walk_deg);
  }
  if (r.has("touches")) d.touches = readTouches(r, camera);
  return d;
}

}  // namespace

const CameraParams& Scene::cameraOf(const DeviceSpec& device) const {
  return device.camera ? *device.camera : camera;
}

bool Scene::isFree(const Eigen::Vector3d& p, double margin) const {
  bool inside = false;
  for (const auto& s : spaces) {
    if (s.contains(p, margin)) {
      inside = true;
      break;
    }
  }
  if (!inside) return false;
  for (const auto& s : solids) {
    if (s.contains(p, -margin)) return false;
  }
  return true;
}

const DeviceSpec& Scene::device(const std::string& device_name) const {
  for (const auto& d : devices) {
    if (d.name == device_name) return d;
  }
  std::string names;
  for (const auto& d : devices) names += (names.empty() ? "" : ", ") + d.name;
  throw Error(path + ": no device named '" + device_name + "' (devices: " + names + ")");
}

/// The scene of a parsed file (loadScene); yaml-cpp throws for values of the wrong shape.
static Scene readScene(const YAML::Node& root, const std::string& path) {
  const Reader r(root, path, "");
  r.allowOnly({"name", "camera", "noise_sigma", "texture", "spaces", "solids", "devices"});
  Scene scene;
  scene.path = path;
  scene.name = r.get<std::string>("name");
  scene.camera = readCamera(r.child("camera"));
  std::optional<PinholeCamera> camera;
  try {
    camera.emplace(scene.camera);
  } catch (const Error& e) {
    r.fail(std::string("camera: ") + e.what());
  }
  scene.noise_sigma = r.getFinite("noise_sigma", scene.noise_sigma);
  if (scene.noise_sigma < 0) r.fail("key 'noise_sigma' must not be negative");
  if (r.has("texture")) {
    const Reader t = r.child("texture");
    t.allowOnly({"seed", "texel_size", "shapes_per_m2", "min_shape_size", "max_shape_size"});
    scene.texture.seed = t.get<uint32_t>("seed", scene.texture.seed);
    scene.texture.texel_size = t.getPositive("texel_size", scene.texture.texel_size);
    scene.texture.shapes_per_m2 = t.getPositive("shapes_per_m2", scene.texture.shapes_per_m2);
    scene.texture.min_shape_size = t.getPositive("min_shape_size", scene.texture.min_shape_size);
    scene.texture.max_shape_size = t.getPositive("max_shape_size", scene.texture.max_shape_size);
    if (scene.texture.max_shape_size < scene.texture.min_shape_size) {
      t.fail("'max_shape_size' must not be below 'min_shape_size'");
    }
    if (scene.texture.texel_size < 0.001) t.fail("'texel_size' below 1 mm needs too much memory");
  }
  scene.spaces = readBoxes(r, "spaces", true);
  if (scene.spaces.empty()) r.fail("key 'spaces' must list at least one box");
  scene.solids = readBoxes(r, "solids", false);

  const YAML::Node devices = root["devices"];
  if (devices) {
    if (!devices.IsSequence()) r.fail("key 'devices' must be a list");
    std::set<std::string> names;
    for (size_t i = 0; i < devices.size(); ++i) {
      const std::string ctx = "devices[" + std::to_string(i) + "]";
      DeviceSpec d = readDevice(Reader(devices[i], path, ctx), i, *camera);
      if (!names.insert(d.name).second) r.fail(ctx + ": duplicate device name '" + d.name + "'");
      scene.devices.push_back(std::move(d));
    }
  }
  return scene;
}

Scene loadScene(const std::string& path) {
  YAML::Node root;
  try {
    root = YAML::LoadFile(path);
  } catch (const YAML::BadFile&) {
    throw Error(path + ": cannot open scene file");
  } catch (const YAML::Exception& e) {
    throw Error(path + ": not valid YAML (line " + std::to_string(e.mark.line + 1) + ": " + e.msg +
                ")");
  }
  try {
    return readScene(root, path);
  } catch (const YAML::Exception& e) {
    // A value of another shape than the key takes (a list where a number goes, ...).
    throw Error(path + ": line " + std::to_string(e.mark.line + 1) + ": " + e.msg);
  }
}

}  // namespace ecar

namespace ecar {

std::vector<TouchEvent> scriptTouches(const Scene& scene, const DeviceSpec& device,
                                      const Trajectory& frames, size_t total_frames) {
  const PinholeCamera camera(scene.cameraOf(device));
  const std::string who = scene.path + ": device '" + device.name + "': touches[";
  std::vector<TouchEvent> events;
  for (size_t k = 0; k < device.touches.size(); ++k) {
    const TouchScriptItem& item = device.touches[k];
    const std::string where = who + std::to_string(k) + "]";
    if (static_cast<size_t>(item.end_frame) >= total_frames) {
      throw Error(where + ": frame " + std::to_string(item.end_frame) +
                  " is past the device's last frame (" + std::to_string(total_frames - 1) + ")");
    }
    for (int f = item.start_frame; f <= item.end_frame; ++f) {
      if (static_cast<size_t>(f) >= frames.size()) break;
      // Linear interpolation along the stroke (an event has from = to).
      const double s = item.stroke ? static_cast<double>(f - item.start_frame) /
                                         (item.end_frame - item.start_frame)
                                   : 0.0;
      TouchEvent e;
      e.timestamp = frames[f].timestamp;
      e.frame = static_cast<size_t>(f);
      e.phase = !item.stroke            ? item.phase
                : f == item.start_frame ? TouchPhase::kBegin
                : f == item.end_frame   ? TouchPhase::kEnd
                                        : TouchPhase::kMove;
      e.r = item.r;
      e.g = item.g;
      e.b = item.b;
      e.width = item.width;
      if (item.in_world) {
        const Eigen::Vector3d p_w = (1.0 - s) * item.from_w + s * item.to_w;
        const Eigen::Vector3d p_c = frames[f].T_w_c.inverse() * p_w;
        const std::string point = "frame " + std::to_string(f) + ": world point (" +
                                  std::to_string(p_w.x()) + ", " + std::to_string(p_w.y()) + ", " +
                                  std::to_string(p_w.z()) + ")";
        const std::optional<Eigen::Vector2d> uv = camera.project(p_c);
        if (!uv) throw Error(where + ": " + point + " is behind the camera");
        if (!camera.inImage(*uv)) {
          throw Error(where + ": " + point + " projects to pixel (" + std::to_string(uv->x()) +
                      ", " + std::to_string(uv->y()) + "), outside the " +
                      std::to_string(camera.width()) + "x" + std::to_string(camera.height()) +
                      " image");
        }
        e.uv = *uv;
      } else {
        e.uv = (1.0 - s) * item.from_uv + s * item.to_uv;
      }
      events.push_back(e);
    }
  }
  // A prefix of the trajectory can cut the last stroke: end it on the last frame.
  const bool open = !events.empty() && events.back().phase != TouchPhase::kEnd;
  if (open) {
    TouchEvent& last = events.back();
    if (last.phase == TouchPhase::kMove && last.frame + 1 == frames.size()) {
      last.phase = TouchPhase::kEnd;
    } else if (last.phase == TouchPhase::kBegin && last.frame + 1 == frames.size()) {
      events.pop_back();
    } else {
      TouchEvent end = last;
      end.frame = frames.size() - 1;
      end.timestamp = frames.back().timestamp;
      end.phase = TouchPhase::kEnd;
      events.push_back(end);
    }
  }
  return events;
}

}  // namespace ecar
