#include "ecar_core/common/camera.h"

#include <cmath>
#include <fstream>
#include <limits>
#include <sstream>

#include <Eigen/LU>

#include <yaml-cpp/yaml.h>

#include "ecar_core/common/error.h"

namespace ecar {

PinholeCamera::PinholeCamera(const CameraParams& params) : p_(params) {
  if (p_.width <= 0 || p_.height <= 0 || p_.width > kMaxCameraSide || p_.height > kMaxCameraSide) {
    throw Error("camera: width and height must be in 1.." + std::to_string(kMaxCameraSide) +
                " (got " + std::to_string(p_.width) + "x" + std::to_string(p_.height) + ")");
  }
  if (!(p_.fx > 0) || !(p_.fy > 0) || !std::isfinite(p_.fx) || !std::isfinite(p_.fy)) {
    throw Error("camera: fx and fy must be positive and finite");
  }
  if (!std::isfinite(p_.cx) || !std::isfinite(p_.cy)) throw Error("camera: cx, cy not finite");
  for (double d : p_.dist) {
    if (!std::isfinite(d)) throw Error("camera: distortion coefficient not finite");
    if (d != 0.0) has_distortion_ = true;
  }
  // The undistorted border: 16 samples per side. Where undistortion diverges
  // (a distortion that folds the image within its own border) the camera is
  // refused rather than tracked with keypoints thrown anywhere.
  min_u_ = min_v_ = 0.0;
  max_u_ = p_.width;
  max_v_ = p_.height;
  if (has_distortion_) {
    min_u_ = min_v_ = std::numeric_limits<double>::infinity();
    max_u_ = max_v_ = -std::numeric_limits<double>::infinity();
    constexpr int kSamples = 16;
    const double w = p_.width - 1.0, h = p_.height - 1.0;
    for (int i = 0; i <= kSamples; ++i) {
      const double s = static_cast<double>(i) / kSamples;
      for (const Eigen::Vector2d& uv : {Eigen::Vector2d(s * w, 0), Eigen::Vector2d(s * w, h),
                                        Eigen::Vector2d(0, s * h), Eigen::Vector2d(w, s * h)}) {
        const Eigen::Vector2d u = undistortPoint(uv);
        if (!u.allFinite() || (distort(unproject(uv).head<2>()) -
                               Eigen::Vector2d((uv.x() - p_.cx) / p_.fx, (uv.y() - p_.cy) / p_.fy))
                                      .norm() > 1e-6) {
          throw Error("camera: the distortion cannot be inverted at pixel (" +
                      std::to_string(uv.x()) + ", " + std::to_string(uv.y()) +
                      "); it folds the image");
        }
        min_u_ = std::min(min_u_, u.x());
        min_v_ = std::min(min_v_, u.y());
        max_u_ = std::max(max_u_, u.x() + 1.0);
        max_v_ = std::max(max_v_, u.y() + 1.0);
      }
    }
    const double side = 4.0 * std::max(p_.width, p_.height);
    if (min_u_ < -side || min_v_ < -side || max_u_ > side || max_v_ > side) {
      throw Error(
          "camera: the undistorted image spans more than 4 times the image size; the "
          "distortion coefficients are not a lens's");
    }
  }
}

std::string PinholeCamera::difference(const PinholeCamera& other, double relative_tolerance) const {
  const CameraParams& a = p_;
  const CameraParams& b = other.p_;
  std::ostringstream os;
  if (a.width != b.width || a.height != b.height) {
    os << "image size " << b.width << "x" << b.height << " is not " << a.width << "x" << a.height;
    return os.str();
  }
  const auto off = [relative_tolerance](double x, double y) {
    return std::abs(x - y) > relative_tolerance * std::abs(y);
  };
  if (off(b.fx, a.fx) || off(b.fy, a.fy) || off(b.cx, a.cx) || off(b.cy, a.cy)) {
    os << "intrinsics fx " << b.fx << " fy " << b.fy << " cx " << b.cx << " cy " << b.cy
       << " are not fx " << a.fx << " fy " << a.fy << " cx " << a.cx << " cy " << a.cy;
    return os.str();
  }
  for (size_t i = 0; i < a.dist.size(); ++i) {
    if (std::abs(a.dist[i] - b.dist[i]) > std::max(relative_tolerance, 1e-9)) {
      os << "distortion coefficient " << i << " (" << b.dist[i] << ") is not " << a.dist[i];
      return os.str();
    }
  }
  return {};
}

Eigen::Matrix3d PinholeCamera::K() const {
  Eigen::Matrix3d K;
  K << p_.fx, 0, p_.cx, 0, p_.fy, p_.cy, 0, 0, 1;
  return K;
}

Eigen::Vector2d PinholeCamera::distort(const Eigen::Vector2d& xn) const {
  if (!has_distortion_) return xn;
  const double k1 = p_.dist[0], k2 = p_.dist[1], p1 = p_.dist[2], p2 = p_.dist[3], k3 = p_.dist[4];
  const double x = xn.x(), y = xn.y();
  const double r2 = x * x + y * y;
  const double radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
  return {x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
          y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y};
}

Eigen::Vector2d PinholeCamera::undistortNormalized(const Eigen::Vector2d& xd) const {
  if (!has_distortion_) return xd;
  // Gauss-Newton on distort(x) = xd with a numeric Jacobian; a few iterations
  // reach 1e-12 for real lenses.
  Eigen::Vector2d x = xd;
  for (int it = 0; it < 20; ++it) {
    const Eigen::Vector2d r = distort(x) - xd;
    if (r.squaredNorm() < 1e-24) break;
    const double h = 1e-7;
    Eigen::Matrix2d J;
    J.col(0) = (distort(x + Eigen::Vector2d(h, 0)) - distort(x - Eigen::Vector2d(h, 0))) / (2 * h);
    J.col(1) = (distort(x + Eigen::Vector2d(0, h)) - distort(x - Eigen::Vector2d(0, h))) / (2 * h);
    x -= J.inverse() * r;
  }
  return x;
}

std::optional<Eigen::Vector2d> PinholeCamera::project(const Eigen::Vector3d& p_c) const {
  if (!(p_c.z() > 1e-9)) return std::nullopt;
  const Eigen::Vector2d xd = distort(p_c.head<2>() / p_c.z());
  return Eigen::Vector2d(p_.fx * xd.x() + p_.cx, p_.fy * xd.y() + p_.cy);
}

Eigen::Vector3d PinholeCamera::unproject(const Eigen::Vector2d& uv) const {
  const Eigen::Vector2d xd((uv.x() - p_.cx) / p_.fx, (uv.y() - p_.cy) / p_.fy);
  const Eigen::Vector2d xn = undistortNormalized(xd);
  return {xn.x(), xn.y(), 1.0};
}

Eigen::Vector2d PinholeCamera::undistortPoint(const Eigen::Vector2d& uv) const {
  if (!has_distortion_) return uv;
  const Eigen::Vector3d ray = unproject(uv);
  return {p_.fx * ray.x() + p_.cx, p_.fy * ray.y() + p_.cy};
}

void PinholeCamera::undistortPoints(const std::vector<Eigen::Vector2d>& in,
                                    std::vector<Eigen::Vector2d>* out) const {
  out->resize(in.size());
  for (size_t i = 0; i < in.size(); ++i) (*out)[i] = undistortPoint(in[i]);
}

bool PinholeCamera::inImage(const Eigen::Vector2d& uv, double border) const {
  return uv.x() >= border - 0.5 && uv.y() >= border - 0.5 && uv.x() < p_.width - 0.5 - border &&
         uv.y() < p_.height - 0.5 - border;
}

namespace {
template <typename T>
T requireKey(const YAML::Node& node, const std::string& key, const std::string& path) {
  if (!node[key]) throw Error(path + ": missing key '" + key + "'");
  try {
    return node[key].as<T>();
  } catch (const YAML::Exception& e) {
    throw Error(path + ": key '" + key + "' has an invalid value (" + e.msg + ")");
  }
}
}  // namespace

PinholeCamera PinholeCamera::loadYaml(const std::string& path) {
  YAML::Node root;
  try {
    root = YAML::LoadFile(path);
  } catch (const YAML::BadFile&) {
    throw Error(path + ": cannot open camera file");
  } catch (const YAML::Exception& e) {
    throw Error(path + ": not valid YAML (" + e.msg + ")");
  }
  if (!root.IsMap()) throw Error(path + ": camera file must be a YAML map");
  CameraParams p;
  p.width = requireKey<int>(root, "width", path);
  p.height = requireKey<int>(root, "height", path);
  p.fx = requireKey<double>(root, "fx", path);
  p.fy = requireKey<double>(root, "fy", path);
  p.cx = requireKey<double>(root, "cx", path);
  p.cy = requireKey<double>(root, "cy", path);
  if (root["distortion"]) {
    const auto d = requireKey<std::vector<double>>(root, "distortion", path);
    if (d.size() != 4 && d.size() != 5) {
      throw Error(path + ": key 'distortion' must have 4 or 5 values (k1 k2 p1 p2 [k3])");
    }
    for (size_t i = 0; i < d.size(); ++i) p.dist[i] = d[i];
  }
  if (root["fps"]) p.fps = requireKey<double>(root, "fps", path);
  try {
    return PinholeCamera(p);
  } catch (const Error& e) {
    throw Error(path + ": " + e.what());
  }
}

void PinholeCamera::saveYaml(const std::string& path) const {
  std::ofstream out(path);
  if (!out) throw Error(path + ": cannot write camera file");
  out.precision(12);
  out << "# Pinhole camera, radial-tangential distortion (k1 k2 p1 p2 k3); pixels, optical frame.\n"
      << "width: " << p_.width << "\nheight: " << p_.height << "\nfx: " << p_.fx
      << "\nfy: " << p_.fy << "\ncx: " << p_.cx << "\ncy: " << p_.cy << "\ndistortion: ["
      << p_.dist[0] << ", " << p_.dist[1] << ", " << p_.dist[2] << ", " << p_.dist[3] << ", "
      << p_.dist[4] << "]\nfps: " << p_.fps << "\n";
}

}  // namespace ecar
