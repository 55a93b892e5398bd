// The device's side of virtual objects (VOs): the planes and VOs its local
// graphs brought, touch strokes turned into interactions, and what to draw.
// No ROS: ecar_device converts Touch / LocalGraph / InteractionResult into
// these calls and VoRequest into ecar_msgs/Interaction.
//
//   DeviceObjects objects(config);
//   objects.applyGraph(graph_planes, graph_objects);        // every local graph
//   std::vector<VoRequest> out;
//   objects.touch(touch, T_w_c, camera, &out);              // every Touch; publish `out`
//   objects.applyResult(result);                            // every InteractionResult
//   objects.drawList(T_w_c, camera, &lines);                // every ar_view frame
//
// The drawing application of the paper: a touch that begins on a held plane
// starts a stroke; each MOVE extends it, and every time the stroke has grown
// by segment_length since its last segment, that piece becomes one LINE VO,
// sent as its own REGISTER (END sends the rest). One REGISTER per segment
// rather than one line updated by MANIPULATE: a VO is a single straight
// segment (VoStore), a curved stroke is many; each segment is acknowledged,
// attached to its own cells and reaches other devices independently, and a
// lost or rejected segment loses only that piece, never the stroke.
//
// A touch whose ray hits a held VO before (or within pick_radius of) any plane
// grabs it: BEGIN and every MOVE / END send a MANIPULATE with its id, the VO
// translated along its own plane (through its position, with its normal) by
// the motion of the ray's hit on that plane since BEGIN. The held copy moves at
// once (its version stays until the server's newer one arrives).
//
// Not thread-safe: the owner serialises calls (the Device holds its mutex).
#pragma once

#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <unordered_map>
#include <unordered_set>
#include <vector>

#include <Eigen/Core>

#include "ecar_core/common/camera.h"
#include "ecar_core/common/geometry.h"
#include "ecar_core/common/touch.h"
#include "ecar_core/common/types.h"
#include "ecar_core/structure/grid_caster.h"
#include "ecar_core/structure/grid_map.h"
#include "ecar_core/structure/plane_map.h"
#include "ecar_core/structure/vo_store.h"

namespace ecar {

struct DeviceObjectsConfig {
  /// m: a stroke becomes a new LINE each time it has grown this much (path
  /// length along the plane since its last segment).
  double segment_length = 0.05;
  /// m: the rest of a stroke shorter than this at END is not sent.
  double min_segment_length = 0.005;
  /// m: touch rays hit planes and VOs up to this far from the camera.
  double max_distance = 40.0;
  /// m: a ray passing this close to a VO (beyond half its width) hits it.
  double pick_radius = 0.05;
  /// m: a touch may hit a plane this far outside its boundary.
  double boundary_margin = 0.1;
  /// m: drawn lines are clipped to points at least this far in front of the camera.
  double near_clip = 0.05;
  double max_thickness_px = 40.0;  ///< drawn line thickness at most, px

  /// Throws ecar::Error naming the first invalid key (e.g. "segment_length").
  void validate() const;
};

/// One line to draw on the camera image.
struct ScreenLine {
  Eigen::Vector2d a = Eigen::Vector2d::Zero(), b = Eigen::Vector2d::Zero();  ///< px
  double thickness = 1.0;                                                    ///< px, >= 1
  uint8_t red = 255, green = 255, blue = 255;
  bool pending = false;  ///< not acknowledged yet (a stroke in progress or in flight)
};

/// Projects the segment a_w-b_w (map frame) with the camera at T_w_c, clipped to
/// z >= near_clip in the camera frame. Thickness = focal length * width / depth of
/// the nearer visible end, clamped to [1, max_thickness]. nullopt when the whole
/// segment is behind the near plane. The caller clips to the image.
std::optional<ScreenLine> projectSegment(const SE3& T_w_c, const PinholeCamera& camera,
                                         const Eigen::Vector3d& a_w, const Eigen::Vector3d& b_w,
                                         double width, double near_clip, double max_thickness);

/// Distance from the ray o + s d (s >= 0, d unit) to the segment a-b; *s_ray
/// gets the ray parameter of the closest point.
double raySegmentDistance(const Eigen::Vector3d& o, const Eigen::Vector3d& d,
                          const Eigen::Vector3d& a, const Eigen::Vector3d& b, double* s_ray);

/// What one touch did (DeviceObjects::touch).
enum class TouchOutcome {
  kStroke,   ///< began or went on with a stroke on a held plane
  kGrab,     ///< began or went on moving a held VO
  kMissed,   ///< a BEGIN whose ray hits no held plane or VO within max_distance
  kIgnored,  ///< a MOVE / END with no stroke or grab open
};

class DeviceObjects {
 public:
  /// `owner` names the device in the VOs it registers. Throws ecar::Error when
  /// the config is invalid.
  DeviceObjects(const DeviceObjectsConfig& config, const std::string& owner);
  const DeviceObjectsConfig& config() const { return config_; }

  /// Takes the planes and VOs of one local graph. A plane replaces the held one
  /// with its id when its version is newer (or none is held); a VO likewise; a
  /// deleted VO (tombstone) removes the held one and keeps an older state from
  /// coming back. Planes and VOs not in the graph stay, except the planes in
  /// `removed_planes` (fused away on the server), which go. Returns how many
  /// planes and VOs changed.
  size_t applyGraph(const std::vector<Plane>& planes, const std::vector<VirtualObject>& objects,
                    const std::vector<PlaneId>& removed_planes = {});

  /// Applies the server's answer to one of this device's requests. An accepted
  /// REGISTER makes the sent segment a held VO with the assigned id and version;
  /// an accepted MANIPULATE raises the held version (keeping the sent state) when
  /// it is newer. Returns false for a rejection (or an unknown request id); the
  /// request is forgotten either way. *what gets a short description.
  bool applyResult(const VoResult& result, std::string* what);

  /// Handles one touch with the camera at T_w_c; appends the interactions to
  /// send to *out (request ids counting up from 1). A touch that hits nothing
  /// (BEGIN: kMissed) or continues no stroke or grab (MOVE / END: kIgnored)
  /// sends nothing.
  TouchOutcome touch(const Touch& touch, const SE3& T_w_c, const PinholeCamera& camera,
                     std::vector<VoRequest>* out);

  /// Planes held (from the local graphs), for messages.
  size_t planeCount() const { return planes_.size(); }

  /// The hit of the pixel's ray: a held VO (object set) when the ray passes
  /// within half its width + pick_radius of it before the first plane hit (+
  /// pick_radius), the one nearest to the ray among several; else the nearest
  /// plane (plane set); nullopt when nothing is within max_distance.
  struct Hit {
    ObjectId object;
    PlaneId plane;
    Eigen::Vector3d p_w = Eigen::Vector3d::Zero();
    double distance = 0.0;  ///< along the ray, m
  };
  std::optional<Hit> cast(const Eigen::Vector2d& uv, const SE3& T_w_c,
                          const PinholeCamera& camera) const;

  /// Lines to draw with the camera at T_w_c: every held LINE (ANCHORs as a short
  /// cross), then the segments in flight and the current stroke's tail
  /// (pending). *lines is overwritten (its capacity reused).
  void drawList(const SE3& T_w_c, const PinholeCamera& camera,
                std::vector<ScreenLine>* lines) const;

  /// Drops everything held and in progress (a map epoch change). Request ids go on.
  void clear();

  /// The held VOs (live ones only; a moved VO has its local state), by id.
  const std::map<ObjectId, VirtualObject>& objects() const { return objects_; }
  /// The held planes, by id.
  const std::map<PlaneId, Plane>& planes() const { return planes_; }
  /// A copy of one held VO, nullopt when not held (or deleted).
  std::optional<VirtualObject> object(ObjectId id) const;
  /// Requests kept waiting for their answer at most (the oldest are forgotten).
  static constexpr size_t kMaxUnanswered = 512;
  /// Segments sent as REGISTER and not answered yet.
  size_t numInFlight() const { return registering_.size(); }
  /// A stroke is open (BEGIN on a plane, no END yet).
  bool stroking() const { return stroke_.active; }
  /// A VO is grabbed (BEGIN on it, no END yet).
  bool grabbing() const { return grab_.active; }

 private:
  struct Stroke {
    bool active = false;
    PlaneId plane;
    Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();
    double offset = 0.0;
    Eigen::Vector3d start = Eigen::Vector3d::Zero();  ///< start of the open segment
    Eigen::Vector3d last = Eigen::Vector3d::Zero();   ///< latest hit
    double travelled = 0.0;                           ///< path length since start, m
    uint8_t r = 255, g = 255, b = 255;
    float width = 0.02f;
  };
  struct Grab {
    bool active = false;
    ObjectId id;
    VirtualObject original;                            ///< state at BEGIN
    Eigen::Vector3d anchor = Eigen::Vector3d::Zero();  ///< hit on the VO's plane at BEGIN
  };

  void rebuildPlanes() const;
  /// Hit of the ray through uv on the plane (n, d) of unlimited extent.
  static std::optional<Eigen::Vector3d> hitInfinitePlane(const Eigen::Vector3d& o,
                                                         const Eigen::Vector3d& dir,
                                                         const Eigen::Vector3d& n, double d,
                                                         double max_distance);
  void sendSegment(const Eigen::Vector3d& a, const Eigen::Vector3d& b, std::vector<VoRequest>* out);

  DeviceObjectsConfig config_;
  std::string owner_;
  std::map<PlaneId, Plane> planes_;
  std::map<ObjectId, VirtualObject> objects_;
  std::unordered_map<ObjectId, uint32_t> tombstones_;  ///< id -> deleted version
  std::map<uint32_t, VirtualObject> registering_;      ///< request id -> segment sent
  std::map<uint32_t, VirtualObject> manipulating_;     ///< request id -> state sent
  /// Held VOs moved here and not confirmed: the server's state of the same version wins.
  std::unordered_set<ObjectId> moved_here_;
  uint32_t next_request_ = 1;
  Stroke stroke_;
  Grab grab_;
  mutable GridPlanes grid_planes_;
  mutable bool planes_dirty_ = true;
};

}  // namespace ecar
