// Pinhole camera with radial-tangential (plumb bob, k1 k2 p1 p2 [k3]) distortion.
//
// Pixel coordinates: (u, v) with (0, 0) the centre of the top-left pixel, as in
// OpenCV. "Normalised" coordinates are (x/z, y/z) in the optical frame (x right,
// y down, z forward), before distortion.
#pragma once

#include <array>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

namespace ecar {

/// Pinhole intrinsics of the undistorted image (what projections in the SLAM use).
struct Intrinsics {
  double fx = 0, fy = 0, cx = 0, cy = 0;
};

/// Largest image side a camera may have (px): bounds what a hostile or broken
/// camera description can make the server allocate.
constexpr int kMaxCameraSide = 8192;

struct CameraParams {
  int width = 640;
  int height = 480;
  double fx = 525.0, fy = 525.0, cx = 319.5, cy = 239.5;
  /// k1, k2, p1, p2, k3 (radial-tangential). All zero: an ideal pinhole.
  std::array<double, 5> dist{0, 0, 0, 0, 0};
  /// Frames per second of the stream (0 when unknown).
  double fps = 0.0;
};

class PinholeCamera {
 public:
  PinholeCamera() = default;
  /// Throws ecar::Error when a parameter is invalid (non-positive size or focal
  /// length, a side above kMaxCameraSide, non-finite value, a distortion that
  /// folds the image).
  explicit PinholeCamera(const CameraParams& params);

  const CameraParams& params() const { return p_; }
  int width() const { return p_.width; }
  int height() const { return p_.height; }
  bool hasDistortion() const { return has_distortion_; }
  Eigen::Matrix3d K() const;
  Intrinsics intrinsics() const { return {p_.fx, p_.fy, p_.cx, p_.cy}; }
  /// Same size, intrinsics and distortion within `relative_tolerance` (the
  /// distortion coefficients absolutely, at least 1e-9). Empty when they
  /// match; otherwise what differs, for a message.
  std::string difference(const PinholeCamera& other, double relative_tolerance = 1e-9) const;

  /// Where the image's pixels lie once undistorted: the box around the
  /// undistorted border (with distortion, corners move out or in). Keypoint
  /// grids and projection checks use it, not the raw image size.
  double minU() const { return min_u_; }
  double minV() const { return min_v_; }
  double maxU() const { return max_u_; }
  double maxV() const { return max_v_; }

  /// Applies distortion to normalised coordinates.
  Eigen::Vector2d distort(const Eigen::Vector2d& xn) const;
  /// Inverts distort() iteratively (converges for the distortions of real lenses
  /// within the image).
  Eigen::Vector2d undistortNormalized(const Eigen::Vector2d& xd) const;

  /// Camera-frame point to pixel (with distortion). Returns nullopt for points
  /// at or behind the camera (z <= 1e-9).
  std::optional<Eigen::Vector2d> project(const Eigen::Vector3d& p_c) const;
  /// Pixel to the ray (x, y, 1) in the camera frame (distortion removed).
  Eigen::Vector3d unproject(const Eigen::Vector2d& uv) const;
  /// Distorted pixel to the pixel an ideal pinhole with the same K would see.
  Eigen::Vector2d undistortPoint(const Eigen::Vector2d& uv) const;
  void undistortPoints(const std::vector<Eigen::Vector2d>& in,
                       std::vector<Eigen::Vector2d>* out) const;
  bool inImage(const Eigen::Vector2d& uv, double border = 0.0) const;

  /// camera.yaml: width, height, fx, fy, cx, cy, distortion: [k1, k2, p1, p2(, k3)], fps.
  /// Throws ecar::Error naming the file and the key when one is missing or invalid.
  static PinholeCamera loadYaml(const std::string& path);
  void saveYaml(const std::string& path) const;

 private:
  CameraParams p_;
  bool has_distortion_ = false;
  double min_u_ = 0, min_v_ = 0, max_u_ = 0, max_v_ = 0;
};

/// Cameras are shared by every keyframe a device makes (and never change).
using CameraPtr = std::shared_ptr<const PinholeCamera>;

}  // namespace ecar
