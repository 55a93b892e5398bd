#include "ecar_core/sim/motion.h"

#include <cmath>
#include <functional>
#include <random>

#include "ecar_core/common/error.h"

namespace ecar {
namespace {

constexpr double kDeg = M_PI / 180.0;

// Smooth band-limited noise in [-1, 1]: a few sinusoids with random
// frequencies and phases. Deterministic for a seed, differentiable, and free
// of the periodicity a single sinusoid would give.
class SmoothNoise {
 public:
  SmoothNoise(std::mt19937& rng, double min_hz, double max_hz, int terms = 4) {
    std::uniform_real_distribution<double> f(min_hz, max_hz), ph(0, 2 * M_PI);
    for (int i = 0; i < terms; ++i) waves_.push_back({f(rng), ph(rng)});
  }
  double operator()(double t) const {
    double s = 0;
    for (const auto& w : waves_) s += std::sin(2 * M_PI * w.hz * t + w.phase);
    return s / std::sqrt(0.5 * waves_.size()) * (1.0 / 1.8);  // ~unit peak
  }

 private:
  struct Wave {
    double hz, phase;
  };
  std::vector<Wave> waves_;
};

// Camera orientation from yaw (about +z, 0 = looking along +x), pitch (up
// positive) and roll, in the optical convention.
Eigen::Matrix3d cameraRotation(double yaw, double pitch, double roll) {
  const Eigen::Vector3d forward(std::cos(pitch) * std::cos(yaw), std::cos(pitch) * std::sin(yaw),
                                std::sin(pitch));
  Eigen::Matrix3d R = lookAt(Eigen::Vector3d::Zero(), forward).linear();
  return R * Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitZ()).toRotationMatrix();
}

struct PathPoint {
  Eigen::Vector2d p;
  double s;  // arc length
};

// Position at arc length s along a polyline.
Eigen::Vector2d alongPolyline(const std::vector<PathPoint>& path, double s) {
  if (s <= 0) return path.front().p;
  for (size_t i = 1; i < path.size(); ++i) {
    if (s <= path[i].s) {
      const double a = (s - path[i - 1].s) / std::max(1e-12, path[i].s - path[i - 1].s);
      return (1 - a) * path[i - 1].p + a * path[i].p;
    }
  }
  return path.back().p;
}

// Distance walked at time t with smooth start and stop (1 s ramps).
double walkedDistance(double t, double speed, double length) {
  const double ramp = std::min(1.0, 0.5 * length / speed);
  const double total = length / speed + ramp;  // cruise plus two half-speed ramps
  if (t <= 0) return 0;
  if (t >= total) return length;
  // Velocity ramps linearly 0 -> speed over `ramp` seconds at both ends.
  if (t < ramp) return 0.5 * speed * t * t / ramp;
  const double s_ramp = 0.5 * speed * ramp;
  if (t < total - ramp) return s_ramp + speed * (t - ramp);
  const double tr = total - t;
  return length - 0.5 * speed * tr * tr / ramp;
}

double walkDuration(double speed, double length) {
  const double ramp = std::min(1.0, 0.5 * length / speed);
  return length / speed + ramp;
}

}  // namespace

Eigen::Vector3d gravityInCamera(const SE3& T_w_c) {
  return T_w_c.linear().transpose() * Eigen::Vector3d(0, 0, kGravity);
}

std::vector<MotionSample> generateMotion(const Scene& scene, const DeviceSpec& device, double fps,
                                         int max_frames) {
  if (!(fps > 0)) throw Error("motion: fps must be positive");
  const TrajectorySpec& spec = device.trajectory;
  std::mt19937 rng(device.seed * 7919u + 17u);
  SmoothNoise jitter_yaw(rng, 0.15, 0.9), jitter_pitch(rng, 0.15, 0.9), jitter_roll(rng, 0.1, 0.7);
  SmoothNoise wobble_x(rng, 0.2, 1.2), wobble_y(rng, 0.2, 1.2), wobble_z(rng, 0.2, 1.2);
  const double jitter = spec.jitter_deg * kDeg;

  // Pose at time t (seconds since the start, including the start pause).
  std::function<SE3(double)> pose_at;
  double duration = 0;
  std::vector<PathPoint> path;
  switch (spec.type) {
    case TrajectoryType::kWalk: {
      double s = 0;
      for (size_t i = 0; i < spec.waypoints.size(); ++i) {
        const Eigen::Vector2d p = spec.waypoints[i].head<2>();
        if (i > 0) s += (p - path.back().p).norm();
        path.push_back({p, s});
      }
      const double length = s;
      if (length < 0.1) throw Error("device '" + device.name + "': walk path shorter than 10 cm");
      duration = walkDuration(spec.speed, length) + spec.start_pause;
      pose_at = [&, length](double t) {
        const double tm = std::max(0.0, t - spec.start_pause);
        const double dist = walkedDistance(tm, spec.speed, length);
        const Eigen::Vector2d p = alongPolyline(path, dist);
        // Look ahead along the path: turns at corners are smooth.
        const Eigen::Vector2d ahead = alongPolyline(path, std::min(length, dist + 1.0));
        const Eigen::Vector2d behind = alongPolyline(path, std::max(0.0, dist - 0.3));
        Eigen::Vector2d dir = ahead - behind;
        if (dir.norm() < 1e-6) dir = path.back().p - path.front().p;
        const double yaw = std::atan2(dir.y(), dir.x());
        // Bob at the step frequency, sway at half of it; both fade in with speed.
        const double moving = std::min(1.0, std::min(tm, 1.0));
        const double phase = 2 * M_PI * spec.step_frequency * tm;
        const Eigen::Vector2d lateral(-std::sin(yaw), std::cos(yaw));
        Eigen::Vector3d pos(p.x(), p.y(), spec.height);
        pos.z() += moving * spec.bob_amplitude * std::sin(phase);
        pos.head<2>() += moving * spec.sway_amplitude * std::sin(0.5 * phase) * lateral;
        pos += 0.005 * Eigen::Vector3d(wobble_x(t), wobble_y(t), wobble_z(t));
        SE3 T = SE3::Identity();
        T.linear() = cameraRotation(yaw + jitter * jitter_yaw(t),
                                    spec.pitch_deg * kDeg + jitter * jitter_pitch(t),
                                    0.5 * jitter * jitter_roll(t));
        T.translation() = pos;
        return T;
      };
      break;
    }
    case TrajectoryType::kHalfCircle: {
      const double sweep = spec.sweep_deg * kDeg;
      const double arc = std::fabs(sweep) * spec.radius;
      duration = walkDuration(spec.speed, arc) + spec.start_pause;
      pose_at = [&, sweep, arc](double t) {
        const double tm = std::max(0.0, t - spec.start_pause);
        const double frac = walkedDistance(tm, spec.speed, arc) / arc;
        const double a = spec.start_angle_deg * kDeg + frac * sweep;
        Eigen::Vector3d eye(spec.target.x() + spec.radius * std::cos(a),
                            spec.target.y() + spec.radius * std::sin(a), spec.height);
        eye += 0.01 * Eigen::Vector3d(wobble_x(t), wobble_y(t), wobble_z(t));
        SE3 T = lookAt(eye, spec.target);
        T.linear() = T.linear() * expSO3(jitter * Eigen::Vector3d(jitter_pitch(t), jitter_yaw(t),
                                                                  0.5 * jitter_roll(t)));
        return T;
      };
      break;
    }
    case TrajectoryType::kShake: {
      duration = spec.duration + spec.start_pause;
      SmoothNoise sx(rng, 0.5 * spec.shake_frequency, 1.5 * spec.shake_frequency);
      SmoothNoise sy(rng, 0.5 * spec.shake_frequency, 1.5 * spec.shake_frequency);
      SmoothNoise sz(rng, 0.5 * spec.shake_frequency, 1.5 * spec.shake_frequency);
      SmoothNoise rx(rng, 0.5 * spec.shake_frequency, 1.5 * spec.shake_frequency);
      SmoothNoise ry(rng, 0.5 * spec.shake_frequency, 1.5 * spec.shake_frequency);
      SmoothNoise rz(rng, 0.5 * spec.shake_frequency, 1.5 * spec.shake_frequency);
      pose_at = [&, sx, sy, sz, rx, ry, rz](double t) {
        const double tm = std::max(0.0, t - spec.start_pause);
        const double fade = std::min(1.0, tm / 0.5);
        const Eigen::Vector3d eye =
            spec.position + fade * spec.shake_amplitude * Eigen::Vector3d(sx(tm), sy(tm), sz(tm));
        SE3 T = lookAt(eye, spec.target);
        const double ra = fade * spec.shake_amplitude_deg * kDeg;
        T.linear() = T.linear() * expSO3(Eigen::Vector3d(ra * rx(tm) + jitter * jitter_pitch(t),
                                                         ra * ry(tm) + jitter * jitter_yaw(t),
                                                         0.5 * ra * rz(tm)));
        return T;
      };
      break;
    }
  }

  int n = static_cast<int>(std::floor(duration * fps)) + 1;
  if (max_frames > 0) n = std::min(n, max_frames);
  std::vector<MotionSample> samples(n);
  const double dt = 1.0 / fps;

  // Odometry: integrates the true increments with scale error, position noise
  // and yaw drift proportional to the distance travelled.
  std::normal_distribution<double> unit_normal(0.0, 1.0);
  const OdometryNoise& on = device.odometry;
  const SE3 T0 = pose_at(0.0);
  // Gravity-aligned odometry frame at the first pose (yaw of the first view).
  SE3 T_w_o = SE3::Identity();
  {
    const Eigen::Vector3d f = T0.linear().col(2);
    const double yaw0 = std::atan2(f.y(), f.x());
    T_w_o.linear() = Eigen::AngleAxisd(yaw0, Eigen::Vector3d::UnitZ()).toRotationMatrix();
    T_w_o.translation() = T0.translation();
  }
  double yaw_drift = 0;
  Eigen::Vector3d pos_o = Eigen::Vector3d::Zero();
  for (int i = 0; i < n; ++i) {
    const double t = i * dt;
    MotionSample& m = samples[i];
    m.timestamp = t;
    m.T_w_c = pose_at(t);
    m.blank = spec.blank_duration > 0 && t >= spec.blank_start &&
              t < spec.blank_start + spec.blank_duration;
    if (!scene.isFree(m.T_w_c.translation(), 0.05)) {
      throw Error(scene.path + ": device '" + device.name + "' leaves the free space at t=" +
                  std::to_string(t) + " s (position " + std::to_string(m.T_w_c.translation().x()) +
                  ", " + std::to_string(m.T_w_c.translation().y()) + ", " +
                  std::to_string(m.T_w_c.translation().z()) + ")");
    }
    m.gravity_c = gravityInCamera(m.T_w_c);
    // Gyro: angular rate from the central difference of orientations.
    const SE3 Ta = pose_at(t - 0.5 * dt), Tb = pose_at(t + 0.5 * dt);
    m.gyro_c = logSO3(Ta.linear().transpose() * Tb.linear()) / dt;
    if (i == 0) {
      m.T_o_c = T_w_o.inverse() * m.T_w_c;
      pos_o = m.T_o_c.translation();
    } else {
      const Eigen::Vector3d step_w = m.T_w_c.translation() - samples[i - 1].T_w_c.translation();
      const double step = step_w.norm();
      yaw_drift += on.yaw_walk_deg * kDeg * std::sqrt(step) * unit_normal(rng);
      const Eigen::Matrix3d R_drift =
          Eigen::AngleAxisd(yaw_drift, Eigen::Vector3d::UnitZ()).toRotationMatrix();
      const Eigen::Vector3d noise(unit_normal(rng), unit_normal(rng), 0.3 * unit_normal(rng));
      pos_o += R_drift * (T_w_o.linear().transpose() * step_w) * (1.0 + on.scale_error) +
               on.position_walk * std::sqrt(step) * noise;
      m.T_o_c.linear() = R_drift * T_w_o.linear().transpose() * m.T_w_c.linear();
      m.T_o_c.translation() = pos_o;
    }
  }
  return samples;
}

}  // namespace ecar
