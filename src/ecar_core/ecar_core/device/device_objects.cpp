#include "ecar_core/device/device_objects.h"

#include <algorithm>
#include <cmath>

#include "ecar_core/common/error.h"

namespace ecar {
namespace {

constexpr double kEps = 1e-12;

/// The held state `held` is replaced by `incoming` when this is true.
bool newer(uint32_t incoming, uint32_t held) { return incoming > held; }

void moveBy(VirtualObject* vo, const Eigen::Vector3d& delta) {
  vo->position += delta;
  vo->start += delta;
  vo->end += delta;
}

template <typename Map>
void capSize(Map* map, size_t max) {
  while (map->size() > max) map->erase(map->begin());
}

}  // namespace

void DeviceObjectsConfig::validate() const {
  auto positive = [](double v, const char* key) {
    if (!std::isfinite(v) || v <= 0.0) throw Error(std::string(key) + ": must be > 0");
  };
  positive(segment_length, "segment_length");
  positive(min_segment_length, "min_segment_length");
  if (min_segment_length > segment_length) {
    throw Error("min_segment_length: must not exceed segment_length");
  }
  positive(max_distance, "max_distance");
  positive(pick_radius, "pick_radius");
  if (!std::isfinite(boundary_margin) || boundary_margin < 0.0) {
    throw Error("boundary_margin: must be >= 0");
  }
  positive(near_clip, "near_clip");
  if (!std::isfinite(max_thickness_px) || max_thickness_px < 1.0) {
    throw Error("max_thickness_px: must be >= 1");
  }
}

std::optional<ScreenLine> projectSegment(const SE3& T_w_c, const PinholeCamera& camera,
                                         const Eigen::Vector3d& a_w, const Eigen::Vector3d& b_w,
                                         double width, double near_clip, double max_thickness) {
  const SE3 T_c_w = T_w_c.inverse();
  Eigen::Vector3d a = T_c_w * a_w;
  Eigen::Vector3d b = T_c_w * b_w;
  if (a.z() < near_clip && b.z() < near_clip) return std::nullopt;
  if (a.z() < near_clip) {
    a = a + (b - a) * ((near_clip - a.z()) / (b.z() - a.z()));
  } else if (b.z() < near_clip) {
    b = b + (a - b) * ((near_clip - b.z()) / (a.z() - b.z()));
  }
  const auto pa = camera.project(a);
  const auto pb = camera.project(b);
  if (!pa || !pb) return std::nullopt;
  ScreenLine line;
  line.a = *pa;
  line.b = *pb;
  const double depth = std::max(near_clip, std::min(a.z(), b.z()));
  line.thickness = std::clamp(camera.params().fx * width / depth, 1.0, max_thickness);
  return line;
}

double raySegmentDistance(const Eigen::Vector3d& o, const Eigen::Vector3d& d,
                          const Eigen::Vector3d& a, const Eigen::Vector3d& b, double* s_ray) {
  const Eigen::Vector3d e = b - a;
  const Eigen::Vector3d r = a - o;
  const double B = d.dot(e), C = e.dot(e), D = d.dot(r), E = e.dot(r);
  double s = 0.0, t = 0.0;
  if (C < kEps) {
    s = std::max(0.0, D);
  } else {
    const double denom = C - B * B;  // |d| = 1
    s = denom > kEps * C ? std::max(0.0, (C * D - B * E) / denom) : std::max(0.0, D);
    t = std::clamp((s * B - E) / C, 0.0, 1.0);
    s = std::max(0.0, t * B + D);
    t = std::clamp((s * B - E) / C, 0.0, 1.0);
  }
  if (s_ray) *s_ray = s;
  return (o + s * d - (a + t * e)).norm();
}

DeviceObjects::DeviceObjects(const DeviceObjectsConfig& config, const std::string& owner)
    : config_(config), owner_(owner) {
  config_.validate();
}

size_t DeviceObjects::applyGraph(const std::vector<Plane>& planes,
                                 const std::vector<VirtualObject>& objects,
                                 const std::vector<PlaneId>& removed_planes) {
  size_t changed = 0;
  for (const Plane& p : planes) {
    if (!p.id.valid()) continue;
    auto it = planes_.find(p.id);
    if (it != planes_.end() && !newer(p.version, it->second.version)) continue;
    planes_[p.id] = p;
    planes_dirty_ = true;
    ++changed;
  }
  for (const PlaneId id : removed_planes) {
    if (planes_.erase(id) == 0) continue;
    planes_dirty_ = true;
    ++changed;
  }
  for (const VirtualObject& vo : objects) {
    if (!vo.id.valid()) continue;
    const auto tomb = tombstones_.find(vo.id);
    if (tomb != tombstones_.end() && vo.version <= tomb->second) continue;
    auto it = objects_.find(vo.id);
    const bool moved_here = moved_here_.count(vo.id) > 0;
    if (it != objects_.end()) {
      const bool take =
          newer(vo.version, it->second.version) || (moved_here && vo.version == it->second.version);
      if (!take) continue;
    }
    ++changed;
    if (vo.deleted) {
      objects_.erase(vo.id);
      tombstones_[vo.id] = vo.version;
      moved_here_.erase(vo.id);
      if (grab_.active && grab_.id == vo.id) grab_.active = false;
      continue;
    }
    if (grab_.active && grab_.id == vo.id && it != objects_.end()) {
      // Dragging: the server's state lags the finger; keep the drawn geometry.
      it->second.version = vo.version;
      continue;
    }
    objects_[vo.id] = vo;
    moved_here_.erase(vo.id);
  }
  return changed;
}

bool DeviceObjects::applyResult(const VoResult& result, std::string* what) {
  auto set_what = [&](const std::string& text) {
    if (what) *what = text;
  };
  const std::string rid = "request " + std::to_string(result.request_id);
  if (auto it = registering_.find(result.request_id); it != registering_.end()) {
    VirtualObject vo = std::move(it->second);
    registering_.erase(it);
    if (!result.accepted) {
      set_what(rid + " (REGISTER) rejected: " + result.reason);
      return false;
    }
    vo.id = result.object_id;
    vo.version = result.version;
    set_what(rid + " (REGISTER) accepted: object " + std::to_string(vo.id.value) + " version " +
             std::to_string(vo.version));
    const auto tomb = tombstones_.find(vo.id);
    if (tomb != tombstones_.end() && vo.version <= tomb->second) return true;
    auto held = objects_.find(vo.id);
    if (held == objects_.end() || newer(vo.version, held->second.version)) objects_[vo.id] = vo;
    return true;
  }
  if (auto it = manipulating_.find(result.request_id); it != manipulating_.end()) {
    const VirtualObject sent = std::move(it->second);
    manipulating_.erase(it);
    if (!result.accepted) {
      set_what(rid + " (MANIPULATE of object " + std::to_string(sent.id.value) +
               ") rejected: " + result.reason);
      return false;
    }
    set_what(rid + " (MANIPULATE) accepted: object " + std::to_string(result.object_id.value) +
             " version " + std::to_string(result.version));
    auto held = objects_.find(result.object_id);
    if (held != objects_.end() && newer(result.version, held->second.version)) {
      const bool dragging = grab_.active && grab_.id == result.object_id;
      if (!dragging) {
        held->second = sent;
        moved_here_.erase(result.object_id);
      }
      held->second.version = result.version;
    }
    return true;
  }
  set_what(rid + ": no such request in flight");
  return false;
}

void DeviceObjects::rebuildPlanes() const {
  if (!planes_dirty_) return;
  std::vector<Plane> all;
  all.reserve(planes_.size());
  for (const auto& kv : planes_) all.push_back(kv.second);
  grid_planes_ = GridPlanes(all, config_.boundary_margin);
  planes_dirty_ = false;
}

std::optional<Eigen::Vector3d> DeviceObjects::hitInfinitePlane(const Eigen::Vector3d& o,
                                                               const Eigen::Vector3d& dir,
                                                               const Eigen::Vector3d& n, double d,
                                                               double max_distance) {
  const double denom = n.dot(dir);
  if (std::abs(denom) < 1e-9) return std::nullopt;
  const double s = -(n.dot(o) + d) / denom;
  if (!(s > 0.0) || s * dir.norm() > max_distance) return std::nullopt;
  return Eigen::Vector3d(o + s * dir);
}

std::optional<DeviceObjects::Hit> DeviceObjects::cast(const Eigen::Vector2d& uv, const SE3& T_w_c,
                                                      const PinholeCamera& camera) const {
  rebuildPlanes();
  const Eigen::Vector3d o = T_w_c.translation();
  const Eigen::Vector3d dir = (T_w_c.linear() * camera.unproject(uv)).normalized();
  std::optional<Hit> hit;
  if (const auto plane_hit = grid_planes_.intersect(o, dir, config_.max_distance)) {
    hit = Hit{ObjectId(), plane_hit->plane, plane_hit->p_w, plane_hit->distance};
  }
  const double plane_distance = hit ? hit->distance : config_.max_distance;
  double best = std::numeric_limits<double>::infinity();
  const VirtualObject* picked = nullptr;
  double picked_s = 0.0;
  for (const auto& kv : objects_) {
    const VirtualObject& vo = kv.second;
    if (vo.deleted) continue;
    double s = 0.0;
    const double dist = vo.kind == VoKind::kLine
                            ? raySegmentDistance(o, dir, vo.start, vo.end, &s)
                            : raySegmentDistance(o, dir, vo.position, vo.position, &s);
    if (dist > 0.5 * vo.width + config_.pick_radius) continue;
    if (s <= 0.0 || s > config_.max_distance || s > plane_distance + config_.pick_radius) continue;
    // Among the VOs near the ray (none hidden by a plane), the one nearest to it.
    if (dist < best) {
      best = dist;
      picked = &vo;
      picked_s = s;
    }
  }
  if (picked) {
    return Hit{picked->id, picked->plane, o + picked_s * dir, picked_s};
  }
  return hit;
}

void DeviceObjects::sendSegment(const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                                std::vector<VoRequest>* out) {
  VirtualObject vo;
  vo.kind = VoKind::kLine;
  vo.start = a;
  vo.end = b;
  vo.position = 0.5 * (a + b);
  vo.r = stroke_.r;
  vo.g = stroke_.g;
  vo.b = stroke_.b;
  vo.width = stroke_.width;
  vo.normal = stroke_.normal;
  vo.plane = stroke_.plane;
  vo.owner = owner_;
  VoRequest req;
  req.request_id = next_request_++;
  req.type = VoRequestType::kRegister;
  req.object = vo;
  registering_[req.request_id] = vo;
  capSize(&registering_, kMaxUnanswered);
  out->push_back(std::move(req));
}

TouchOutcome DeviceObjects::touch(const Touch& touch, const SE3& T_w_c, const PinholeCamera& camera,
                                  std::vector<VoRequest>* out) {
  const Eigen::Vector3d o = T_w_c.translation();
  const Eigen::Vector3d dir = (T_w_c.linear() * camera.unproject(touch.uv)).normalized();

  if (touch.phase == TouchPhase::kBegin) {
    // A BEGIN while a stroke or grab is open: its END was lost; close it here.
    if (stroke_.active && (stroke_.last - stroke_.start).norm() >= config_.min_segment_length) {
      sendSegment(stroke_.start, stroke_.last, out);
    }
    stroke_.active = false;
    grab_.active = false;
    const auto hit = cast(touch.uv, T_w_c, camera);
    if (!hit) return TouchOutcome::kMissed;
    if (hit->object.valid()) {
      const VirtualObject& vo = objects_.at(hit->object);
      const Eigen::Vector3d n = vo.normal.normalized();
      const auto anchor = hitInfinitePlane(o, dir, n, -n.dot(vo.position), config_.max_distance);
      grab_.active = true;
      grab_.id = vo.id;
      grab_.original = vo;
      grab_.anchor = anchor ? *anchor : hit->p_w;
    } else {
      const Plane& plane = planes_.at(hit->plane);
      stroke_ = Stroke();
      stroke_.active = true;
      stroke_.plane = plane.id;
      stroke_.normal = plane.normal;
      stroke_.offset = plane.offset;
      stroke_.start = stroke_.last = hit->p_w;
      stroke_.r = touch.r;
      stroke_.g = touch.g;
      stroke_.b = touch.b;
      stroke_.width = static_cast<float>(touch.width);
      return TouchOutcome::kStroke;
    }
  }

  if (grab_.active) {
    auto held = objects_.find(grab_.id);
    if (held == objects_.end()) {  // deleted meanwhile
      grab_.active = false;
      return TouchOutcome::kIgnored;
    }
    VirtualObject moved = grab_.original;
    moved.version = held->second.version;
    if (touch.phase != TouchPhase::kBegin) {
      const Eigen::Vector3d n = grab_.original.normal.normalized();
      const auto p =
          hitInfinitePlane(o, dir, n, -n.dot(grab_.original.position), config_.max_distance);
      if (p)
        moveBy(&moved, *p - grab_.anchor);
      else
        moved = held->second;
    }
    held->second = moved;
    moved_here_.insert(moved.id);
    VoRequest req;
    req.request_id = next_request_++;
    req.type = VoRequestType::kManipulate;
    req.object_id = moved.id;
    req.object = moved;
    req.base_version = moved.version;
    manipulating_[req.request_id] = moved;
    capSize(&manipulating_, kMaxUnanswered);
    out->push_back(std::move(req));
    if (touch.phase == TouchPhase::kEnd) grab_.active = false;
    return TouchOutcome::kGrab;
  }

  if (!stroke_.active) return TouchOutcome::kIgnored;
  const auto p = hitInfinitePlane(o, dir, stroke_.normal, stroke_.offset, config_.max_distance);
  if (p) {
    stroke_.travelled += (*p - stroke_.last).norm();
    stroke_.last = *p;
    if (stroke_.travelled >= config_.segment_length &&
        (stroke_.last - stroke_.start).norm() >= config_.min_segment_length) {
      sendSegment(stroke_.start, stroke_.last, out);
      stroke_.start = stroke_.last;
      stroke_.travelled = 0.0;
    }
  }
  if (touch.phase == TouchPhase::kEnd) {
    if ((stroke_.last - stroke_.start).norm() >= config_.min_segment_length) {
      sendSegment(stroke_.start, stroke_.last, out);
    }
    stroke_.active = false;
  }
  return TouchOutcome::kStroke;
}

void DeviceObjects::drawList(const SE3& T_w_c, const PinholeCamera& camera,
                             std::vector<ScreenLine>* lines) const {
  lines->clear();
  auto add = [&](const Eigen::Vector3d& a, const Eigen::Vector3d& b, double width, uint8_t r,
                 uint8_t g, uint8_t bl, bool pending) {
    auto line =
        projectSegment(T_w_c, camera, a, b, width, config_.near_clip, config_.max_thickness_px);
    if (!line) return;
    line->red = r;
    line->green = g;
    line->blue = bl;
    line->pending = pending;
    lines->push_back(*line);
  };
  auto add_object = [&](const VirtualObject& vo, bool pending) {
    if (vo.deleted) return;
    if (vo.kind == VoKind::kLine) {
      add(vo.start, vo.end, vo.width, vo.r, vo.g, vo.b, pending);
      return;
    }
    // ANCHOR: a cross in its plane.
    const Eigen::Vector3d n = vo.normal.normalized();
    Eigen::Vector3d u = n.unitOrthogonal();
    const Eigen::Vector3d v = n.cross(u);
    const double half = std::max(0.05, 2.0 * static_cast<double>(vo.width));
    const double w = std::max(0.01, static_cast<double>(vo.width));
    add(vo.position - half * u, vo.position + half * u, w, vo.r, vo.g, vo.b, pending);
    add(vo.position - half * v, vo.position + half * v, w, vo.r, vo.g, vo.b, pending);
  };
  for (const auto& kv : objects_) add_object(kv.second, false);
  for (const auto& kv : registering_) add_object(kv.second, true);
  if (stroke_.active && (stroke_.last - stroke_.start).norm() > 0.0) {
    add(stroke_.start, stroke_.last, stroke_.width, stroke_.r, stroke_.g, stroke_.b, true);
  }
}

std::optional<VirtualObject> DeviceObjects::object(ObjectId id) const {
  auto it = objects_.find(id);
  if (it == objects_.end()) return std::nullopt;
  return it->second;
}

void DeviceObjects::clear() {
  planes_.clear();
  objects_.clear();
  tombstones_.clear();
  registering_.clear();
  manipulating_.clear();
  moved_here_.clear();
  stroke_ = Stroke();
  grab_ = Grab();
  grid_planes_ = GridPlanes();
  planes_dirty_ = false;
}

}  // namespace ecar
