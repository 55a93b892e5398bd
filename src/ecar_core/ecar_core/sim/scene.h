// Synthetic indoor worlds: the scene file format (config/scenes/*.yaml, documented
// in config/scenes/README.md) and its in-memory form.
//
// World frame: metres, z up. The free space the devices walk in is the union of
// axis-aligned `spaces` boxes (rooms, corridors); their boundary is the floor
// (bottom faces), the ceiling (top faces) and the walls (side faces). `solids`
// are axis-aligned obstacle boxes inside that space (pillars, cabinets).
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "ecar_core/common/camera.h"
#include "ecar_core/common/touch.h"
#include "ecar_core/io/trajectory.h"

namespace ecar {

struct AlignedBox {
  std::string name;
  Eigen::Vector3d min = Eigen::Vector3d::Zero();
  Eigen::Vector3d max = Eigen::Vector3d::Zero();
  bool contains(const Eigen::Vector3d& p, double margin = 0.0) const {
    return (p.array() > min.array() + margin).all() && (p.array() < max.array() - margin).all();
  }
};

/// Texture parameters of every surface in the scene. Textures are generated
/// from (seed, surface index), so the same seed gives the same world.
struct TextureParams {
  uint32_t seed = 1;
  double texel_size = 0.005;      ///< metres per texel at the finest level
  double shapes_per_m2 = 450.0;   ///< density of random shapes (corners)
  double min_shape_size = 0.015;  ///< metres; sizes are log-uniform in [min, max]
  double max_shape_size = 0.30;
};

enum class TrajectoryType { kWalk, kHalfCircle, kShake };

/// A device's camera path. Which fields apply depends on `type`:
/// - kWalk: along `waypoints` (x, y; z ignored) at `speed`, camera at `height`,
///   looking along the path pitched by `pitch_deg`, with hand-held bob and sway.
/// - kHalfCircle: around `target` (a point on the floor it keeps looking at) at
///   `radius` and `height`, from `start_angle_deg` through `sweep_deg`.
/// - kShake: at `position` looking at `target`, shaken by hand for `duration`.
struct TrajectorySpec {
  TrajectoryType type = TrajectoryType::kWalk;
  std::vector<Eigen::Vector3d> waypoints;
  Eigen::Vector3d target = Eigen::Vector3d::Zero();
  Eigen::Vector3d position = Eigen::Vector3d::Zero();
  double speed = 1.2;                ///< m/s along the path (walk, half circle)
  double height = 1.5;               ///< camera height above z = 0 (walk, half circle), m
  double pitch_deg = -10.0;          ///< walk: camera pitch, negative looks down
  double radius = 1.5;               ///< half circle, m
  double start_angle_deg = 0.0;      ///< half circle: angle of the start around target (from +x)
  double sweep_deg = 180.0;          ///< half circle
  double duration = 10.0;            ///< shake: seconds; walk/half circle: derived
  double bob_amplitude = 0.025;      ///< vertical hand-held bob, m
  double sway_amplitude = 0.02;      ///< lateral sway, m
  double step_frequency = 1.8;       ///< steps per second (bob frequency)
  double jitter_deg = 0.8;           ///< smooth random rotation of the hand, degrees
  double shake_amplitude = 0.04;     ///< shake: translation amplitude, m
  double shake_amplitude_deg = 4.0;  ///< shake: rotation amplitude, degrees
  double shake_frequency = 1.2;      ///< shake: dominant frequency, Hz
  double start_pause = 0.0;          ///< seconds standing still (with hand jitter) before moving
  /// The camera sees only a blank surface (covered, or facing a bare wall)
  /// from `blank_start` for `blank_duration` seconds while the motion goes on
  /// (key `blank: [start_s, duration_s]`); no blank when blank_duration is 0.
  double blank_start = 0.0;
  double blank_duration = 0.0;
};

/// Odometry as a phone's VIO would report it: drifting in position and yaw,
/// never in roll and pitch (gravity keeps those).
struct OdometryNoise {
  double scale_error = 0.01;    ///< relative scale error of travelled distance
  double position_walk = 0.01;  ///< m per sqrt(m travelled), random walk
  double yaw_walk_deg = 0.15;   ///< degrees per sqrt(m travelled), random walk
};

/// One item of a device's `touches:` list (config/scenes/README.md): a single
/// touch event, or a stroke that expands to BEGIN at start_frame, a MOVE on
/// every frame in between and END at end_frame, its point moving linearly from
/// `from` to `to`. Frames are indices into the device's generated frames.
struct TouchScriptItem {
  bool stroke = false;  ///< true: a `stroke:` item; false: one event
  int start_frame = 0;  ///< event: its `frame`; stroke: `start_frame` (BEGIN)
  int end_frame = 0;    ///< event: = start_frame; stroke: `end_frame` (END), > start_frame
  TouchPhase phase = TouchPhase::kBegin;  ///< event only: `phase`
  /// True for world points (`at`, `from`/`to`), projected with each frame's
  /// ground-truth pose; false for pixels (`pixel`, `from_pixel`/`to_pixel`).
  bool in_world = false;
  Eigen::Vector3d from_w = Eigen::Vector3d::Zero();   ///< world point, m (event: `at`)
  Eigen::Vector3d to_w = Eigen::Vector3d::Zero();     ///< world point, m (event: = from_w)
  Eigen::Vector2d from_uv = Eigen::Vector2d::Zero();  ///< pixel (event: `pixel`)
  Eigen::Vector2d to_uv = Eigen::Vector2d::Zero();    ///< pixel (event: = from_uv)
  /// `color: [r, g, b]`, 0-255. Default [255, 64, 32]; a `move` or `end`
  /// event without one takes its stroke's `begin`'s (so does `width`).
  uint8_t r = 255, g = 64, b = 32;
  double width = 0.03;  ///< `width`, stroke width in metres, > 0 (default 0.03)
};

struct DeviceSpec {
  std::string name;
  /// The device's own camera (key `camera:`, as the scene's); none: the scene's.
  std::optional<CameraParams> camera;
  TrajectorySpec trajectory;
  OdometryNoise odometry;
  uint32_t seed = 0;  ///< hand-jitter and odometry-noise seed
  /// Scripted touches, frames strictly increasing from item to item, phases
  /// forming whole strokes (checked by loadScene).
  std::vector<TouchScriptItem> touches;
};

struct Scene {
  std::string name;
  std::string path;  ///< file it was loaded from (for messages)
  std::vector<AlignedBox> spaces;
  std::vector<AlignedBox> solids;
  TextureParams texture;
  CameraParams camera;
  double noise_sigma = 2.0;  ///< image noise, grey levels (standard deviation)
  std::vector<DeviceSpec> devices;

  /// True when p lies in the free space (inside a space, outside every solid),
  /// at least `margin` from any surface.
  bool isFree(const Eigen::Vector3d& p, double margin = 0.0) const;
  const DeviceSpec& device(const std::string& name) const;  ///< throws when unknown
  /// The camera a device sees through: its own, or the scene's.
  const CameraParams& cameraOf(const DeviceSpec& device) const;
};

/// Loads and validates a scene file. Throws ecar::Error naming the file and the
/// key (e.g. "corridor.yaml: devices[1].trajectory: missing key 'waypoints'").
Scene loadScene(const std::string& path);

/// The touch events of `device`'s script (scene.devices), one per scripted
/// frame, in frame order. `frames[i]` is frame i's stamp and ground-truth pose
/// T_w_c; world points are projected with it through the device's camera
/// (Scene::cameraOf).
/// `total_frames` is the length of the device's whole trajectory, of which
/// `frames` may be a prefix (make_dataset --frames): an item at or past
/// total_frames is an error; events past the end of `frames` are dropped, and a
/// stroke the cut leaves open ends there (its MOVE on the last frame becomes
/// END; a BEGIN on the last frame is dropped; otherwise an END on the last
/// frame at the previous event's pixel is added). Throws ecar::Error naming the
/// scene file, the device, the item (touches[k]) and the frame when an item is
/// past the trajectory or a world point is behind the camera or projects
/// outside the image.
std::vector<TouchEvent> scriptTouches(const Scene& scene, const DeviceSpec& device,
                                      const Trajectory& frames, size_t total_frames);

}  // namespace ecar
