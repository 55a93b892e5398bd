#include "ecar_core/sim/texture.h"

#include <algorithm>
#include <cmath>
#include <random>

#include <opencv2/imgproc.hpp>

#include "ecar_core/common/error.h"

namespace ecar {
namespace {

cv::Scalar randomColor(std::mt19937& rng, const cv::Vec3f& tint) {
  std::uniform_real_distribution<float> brightness(0.06f, 0.96f), chroma(-0.18f, 0.18f);
  const float b = brightness(rng);
  cv::Scalar c;
  for (int k = 0; k < 3; ++k) {
    const float v = b * (0.55f + 0.45f * tint[k]) + chroma(rng) * b;
    c[k] = std::clamp(v, 0.0f, 1.0f) * 255.0f;
  }
  return c;
}

// One random shape of size `size` texels centred at `centre`.
void drawShape(cv::Mat& img, std::mt19937& rng, const cv::Point2f& centre, float size,
               const cv::Scalar& color) {
  std::uniform_real_distribution<float> unit(0.0f, 1.0f);
  const float angle = unit(rng) * static_cast<float>(CV_PI);
  const float aspect = 0.35f + 0.65f * unit(rng);
  const int kind = static_cast<int>(unit(rng) * 4.0f);
  constexpr int kShift = 4;  // sub-texel precision for anti-aliased edges
  constexpr float kScale = 1 << kShift;
  auto fixed = [&](float x, float y) {
    return cv::Point(cvRound(x * kScale), cvRound(y * kScale));
  };
  const float ca = std::cos(angle), sa = std::sin(angle);
  switch (kind) {
    case 0: {  // rotated rectangle
      const float hw = 0.5f * size, hh = 0.5f * size * aspect;
      cv::Point pts[4];
      const float sx[4] = {-hw, hw, hw, -hw}, sy[4] = {-hh, -hh, hh, hh};
      for (int i = 0; i < 4; ++i) {
        pts[i] = fixed(centre.x + ca * sx[i] - sa * sy[i], centre.y + sa * sx[i] + ca * sy[i]);
      }
      cv::fillConvexPoly(img, pts, 4, color, cv::LINE_AA, kShift);
      break;
    }
    case 1: {  // triangle
      cv::Point pts[3];
      for (int i = 0; i < 3; ++i) {
        const float a = angle + static_cast<float>(i) * 2.1f + 0.6f * unit(rng);
        const float r = 0.5f * size * (0.5f + 0.5f * unit(rng));
        pts[i] = fixed(centre.x + r * std::cos(a), centre.y + r * std::sin(a));
      }
      cv::fillConvexPoly(img, pts, 3, color, cv::LINE_AA, kShift);
      break;
    }
    case 2: {  // ellipse sector: round edges plus two straight corners
      const float start = unit(rng) * 360.0f;
      cv::ellipse(img, fixed(centre.x, centre.y),
                  cv::Size(cvRound(0.5f * size * kScale), cvRound(0.5f * size * aspect * kScale)),
                  angle * 180.0 / CV_PI, start, start + 200.0f + 120.0f * unit(rng), color,
                  cv::FILLED, cv::LINE_AA, kShift);
      break;
    }
    default: {  // stroke (thick segment) with a bend: L-corners
      const float len = size, thick = std::max(1.5f, 0.12f * size * aspect);
      const cv::Point2f a(centre.x - 0.5f * len * ca, centre.y - 0.5f * len * sa);
      const cv::Point2f b(centre.x + 0.5f * len * ca * 0.3f, centre.y + 0.5f * len * sa * 0.3f);
      const cv::Point2f c(b.x - 0.5f * len * sa, b.y + 0.5f * len * ca);
      cv::line(img, fixed(a.x, a.y), fixed(b.x, b.y), color, cvRound(thick), cv::LINE_AA, kShift);
      cv::line(img, fixed(b.x, b.y), fixed(c.x, c.y), color, cvRound(thick), cv::LINE_AA, kShift);
      break;
    }
  }
}

}  // namespace

TexturePyramid generateTexture(double width_m, double height_m, const TextureParams& params,
                               uint32_t surface_seed, const cv::Vec3f& tint) {
  const int w = std::max(8, static_cast<int>(std::ceil(width_m / params.texel_size)));
  const int h = std::max(8, static_cast<int>(std::ceil(height_m / params.texel_size)));
  if (static_cast<double>(w) * h > 4e8) {
    throw Error("texture: a surface of " + std::to_string(width_m) + " x " +
                std::to_string(height_m) + " m needs too many texels; raise texture.texel_size");
  }
  std::mt19937 rng(params.seed * 2654435761u ^ (surface_seed + 0x9e3779b9u));

  // Smooth base: coarse random colours blown up with cubic interpolation.
  const double blotch = 0.35;  // metres per coarse cell
  cv::Mat coarse(std::max(2, static_cast<int>(height_m / blotch) + 2),
                 std::max(2, static_cast<int>(width_m / blotch) + 2), CV_8UC3);
  for (int y = 0; y < coarse.rows; ++y) {
    for (int x = 0; x < coarse.cols; ++x) {
      const cv::Scalar c = randomColor(rng, tint);
      const cv::Scalar m = 0.5 * c + cv::Scalar(64, 64, 64) * 0.5 + cv::Scalar(60, 60, 60);
      coarse.at<cv::Vec3b>(y, x) =
          cv::Vec3b(cv::saturate_cast<uchar>(m[0]), cv::saturate_cast<uchar>(m[1]),
                    cv::saturate_cast<uchar>(m[2]));
    }
  }
  cv::Mat color;
  cv::resize(coarse, color, cv::Size(w, h), 0, 0, cv::INTER_CUBIC);

  // Random shapes, large first so that small ones stay visible on top.
  const double area = width_m * height_m;
  const int count = static_cast<int>(area * params.shapes_per_m2);
  std::uniform_real_distribution<float> unit(0.0f, 1.0f);
  std::vector<float> sizes(count);
  const float lmin = std::log(static_cast<float>(params.min_shape_size / params.texel_size));
  const float lmax = std::log(static_cast<float>(params.max_shape_size / params.texel_size));
  for (float& s : sizes) s = std::exp(lmin + (lmax - lmin) * unit(rng));
  std::sort(sizes.begin(), sizes.end(), std::greater<float>());
  for (const float size : sizes) {
    const cv::Point2f centre(unit(rng) * w, unit(rng) * h);
    drawShape(color, rng, centre, size, randomColor(rng, tint));
  }

  TexturePyramid tex;
  tex.texel_size = params.texel_size;
  cv::Mat gray, bgra;
  cv::cvtColor(color, gray, cv::COLOR_BGR2GRAY);
  cv::cvtColor(color, bgra, cv::COLOR_BGR2BGRA);
  tex.gray.push_back(gray);
  tex.bgra.push_back(bgra);
  while (tex.gray.back().cols > 4 && tex.gray.back().rows > 4) {
    cv::Mat g, c;
    cv::pyrDown(tex.gray.back(), g);
    cv::pyrDown(tex.bgra.back(), c);
    tex.gray.push_back(g);
    tex.bgra.push_back(c);
  }
  return tex;
}

}  // namespace ecar
