#include "ecar_core/sim/renderer.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>

#include "ecar_core/common/error.h"

namespace ecar {

const char* toString(SurfaceLabel label) {
  switch (label) {
    case SurfaceLabel::kFloor:
      return "floor";
    case SurfaceLabel::kWall:
      return "wall";
    case SurfaceLabel::kCeiling:
      return "ceiling";
    case SurfaceLabel::kObject:
      return "object";
    default:
      return "none";
  }
}

namespace {

constexpr float kInf = std::numeric_limits<float>::infinity();

// log2 to about 0.01: enough to choose and blend mip levels.
inline float fastLog2(float x) {
  uint32_t bits;
  std::memcpy(&bits, &x, sizeof bits);
  const float exponent = static_cast<float>(static_cast<int>((bits >> 23) & 255) - 128);
  bits = (bits & 0x7FFFFFu) | 0x3F800000u;
  float m;
  std::memcpy(&m, &bits, sizeof m);
  return exponent + (-0.34484843f * m + 2.02466578f) * m - 0.67487759f;
}

inline uint32_t hashPixel(uint32_t x, uint32_t y, uint32_t seed) {
  uint32_t h = (x * 0x8da6b343u) ^ (y * 0xd8163841u) ^ (seed * 0xcb1ab31fu);
  h ^= h >> 15;
  h *= 0x2c1b3c6du;
  h ^= h >> 12;
  h *= 0x297a2d39u;
  h ^= h >> 15;
  return h;
}

// Triangular noise with unit standard deviation.
inline float pixelNoise(uint32_t x, uint32_t y, uint32_t seed) {
  const uint32_t h = hashPixel(x, y, seed);
  const float u1 = static_cast<float>(h & 0xFFFFu) * (1.0f / 65536.0f);
  const float u2 = static_cast<float>(h >> 16) * (1.0f / 65536.0f);
  return (u1 + u2 - 1.0f) * 2.4494897f;
}

struct LevelView {
  const uint8_t* gray;
  const uint8_t* bgra;
  int w, h;
  size_t gray_step, bgra_step;
};

// Bilinear footprint at a mip level: integer corner and weights, clamped.
struct Bilinear {
  int x0, y0, x1, y1;
  float fx, fy;
};

// s, t in texels of the level; clamped so that both corners are inside.
inline Bilinear bilinearAt(const LevelView& L, float s, float t) {
  Bilinear b;
  const float x = std::clamp(s - 0.5f, 0.0f, static_cast<float>(L.w) - 1.001f);
  const float y = std::clamp(t - 0.5f, 0.0f, static_cast<float>(L.h) - 1.001f);
  b.x0 = static_cast<int>(x);
  b.y0 = static_cast<int>(y);
  b.fx = x - static_cast<float>(b.x0);
  b.fy = y - static_cast<float>(b.y0);
  b.x1 = b.x0 + 1;
  b.y1 = b.y0 + 1;
  return b;
}

inline float sampleGray(const LevelView& L, float s, float t) {
  const Bilinear b = bilinearAt(L, s, t);
  const uint8_t* r0 = L.gray + b.y0 * L.gray_step;
  const uint8_t* r1 = L.gray + b.y1 * L.gray_step;
  const float top = r0[b.x0] + b.fx * (static_cast<float>(r0[b.x1]) - r0[b.x0]);
  const float bot = r1[b.x0] + b.fx * (static_cast<float>(r1[b.x1]) - r1[b.x0]);
  return top + b.fy * (bot - top);
}

// Lerp of two packed BGRA texels with an 8-bit weight, two channels at a time.
inline uint32_t lerpPacked(uint32_t a, uint32_t b, uint32_t w) {
  const uint32_t iw = 256 - w;
  const uint32_t rb = (((a & 0x00FF00FFu) * iw + (b & 0x00FF00FFu) * w) >> 8) & 0x00FF00FFu;
  const uint32_t ga =
      ((((a >> 8) & 0x00FF00FFu) * iw + ((b >> 8) & 0x00FF00FFu) * w) >> 8) & 0x00FF00FFu;
  return rb | (ga << 8);
}

inline uint32_t sampleColor(const LevelView& L, float s, float t) {
  const Bilinear b = bilinearAt(L, s, t);
  const uint32_t* r0 = reinterpret_cast<const uint32_t*>(L.bgra + b.y0 * L.bgra_step);
  const uint32_t* r1 = reinterpret_cast<const uint32_t*>(L.bgra + b.y1 * L.bgra_step);
  const uint32_t wx = static_cast<uint32_t>(b.fx * 256.0f);
  const uint32_t wy = static_cast<uint32_t>(b.fy * 256.0f);
  return lerpPacked(lerpPacked(r0[b.x0], r0[b.x1], wx), lerpPacked(r1[b.x0], r1[b.x1], wx), wy);
}

SurfaceLabel spaceFaceLabel(int axis, int side) {
  if (axis == 2) return side == 0 ? SurfaceLabel::kFloor : SurfaceLabel::kCeiling;
  return SurfaceLabel::kWall;
}

void textureAxes(int axis, int* s_axis, int* t_axis) {
  if (axis == 2) {
    *s_axis = 0;
    *t_axis = 1;
  } else {
    *s_axis = axis == 0 ? 1 : 0;
    *t_axis = 2;
  }
}

}  // namespace

struct Renderer::SurfaceView {
  int s_axis, t_axis, axis;
  float s0, t0, inv_texel;
  int levels;
  uint8_t label;
  LevelView level[24];
};

Renderer::~Renderer() = default;
Renderer::Renderer(Renderer&&) noexcept = default;
Renderer& Renderer::operator=(Renderer&&) noexcept = default;

Renderer::Renderer(const Scene& scene, const std::optional<PinholeCamera>& camera)
    : scene_(scene), camera_(camera ? *camera : PinholeCamera(scene.camera)) {
  // Surfaces: 6 faces per box, index = box * 6 + axis * 2 + side (side 0 = min face).
  auto addBoxFaces = [&](const AlignedBox& box, bool solid, uint32_t box_seed) {
    for (int axis = 0; axis < 3; ++axis) {
      for (int side = 0; side < 2; ++side) {
        Surface s;
        s.axis = axis;
        s.coordinate = side == 0 ? box.min[axis] : box.max[axis];
        s.normal = Eigen::Vector3d::Zero();
        // Spaces are seen from inside, solids from outside.
        s.normal[axis] = (side == 0) != solid ? 1.0 : -1.0;
        textureAxes(axis, &s.s_axis, &s.t_axis);
        s.s0 = box.min[s.s_axis];
        s.t0 = box.min[s.t_axis];
        s.label = solid ? SurfaceLabel::kObject : spaceFaceLabel(axis, side);
        cv::Vec3f tint;
        switch (s.label) {
          case SurfaceLabel::kFloor:
            tint = {0.45f, 0.65f, 0.9f};  // warm (BGR)
            break;
          case SurfaceLabel::kCeiling:
            tint = {0.95f, 0.95f, 0.92f};
            break;
          case SurfaceLabel::kWall:
            tint = {0.8f, 0.85f, 0.7f};
            break;
          default:
            tint = {0.9f, 0.5f, 0.4f};
        }
        const double w = box.max[s.s_axis] - box.min[s.s_axis];
        const double h = box.max[s.t_axis] - box.min[s.t_axis];
        s.texture = generateTexture(w, h, scene.texture, box_seed * 6 + axis * 2 + side, tint);
        surfaces_.push_back(std::move(s));
      }
    }
  };
  uint32_t box_seed = 0;
  for (const auto& b : scene.spaces) addBoxFaces(b, false, box_seed++);
  for (const auto& b : scene.solids) addBoxFaces(b, true, box_seed++);
  auto toF = [](const AlignedBox& b) {
    BoxF f;
    for (int a = 0; a < 3; ++a) {
      f.min[a] = static_cast<float>(b.min[a]);
      f.max[a] = static_cast<float>(b.max[a]);
    }
    return f;
  };
  for (const auto& b : scene.spaces) spaces_f_.push_back(toF(b));
  for (const auto& b : scene.solids) solids_f_.push_back(toF(b));

  const float focal = static_cast<float>(std::sqrt(camera_.params().fx * camera_.params().fy));
  // Flat views of the surfaces (pointers and constants for the pixel loop).
  views_.resize(surfaces_.size());
  for (size_t i = 0; i < surfaces_.size(); ++i) {
    const Surface& s = surfaces_[i];
    SurfaceView& v = views_[i];
    v.axis = s.axis;
    v.s_axis = s.s_axis;
    v.t_axis = s.t_axis;
    v.s0 = static_cast<float>(s.s0);
    v.t0 = static_cast<float>(s.t0);
    v.inv_texel = static_cast<float>(1.0 / s.texture.texel_size);
    v.levels = std::min<int>(24, static_cast<int>(s.texture.gray.size()));
    v.label = static_cast<uint8_t>(s.label);
    for (int l = 0; l < v.levels; ++l) {
      const cv::Mat& g = s.texture.gray[l];
      const cv::Mat& c = s.texture.bgra[l];
      v.level[l] = {g.data, c.data, g.cols, g.rows, g.step[0], c.step[0]};
    }
  }
  log2_inv_f_texel_ = std::log2(1.0f / (focal * static_cast<float>(scene.texture.texel_size)));
  tex_s0_.resize(views_.size());
  tex_t0_.resize(views_.size());
  for (size_t i = 0; i < views_.size(); ++i) {
    tex_s0_[i] = views_[i].s0;
    tex_t0_[i] = views_[i].t0;
  }
  max_lod_.resize(views_.size());
  for (size_t i = 0; i < views_.size(); ++i) max_lod_[i] = static_cast<float>(views_[i].levels - 1);
  const size_t n = static_cast<size_t>(camera_.width()) * camera_.height();
  ray_x_.resize(n);
  ray_y_.resize(n);
  for (int v = 0; v < camera_.height(); ++v) {
    for (int u = 0; u < camera_.width(); ++u) {
      const Eigen::Vector3d r = camera_.unproject(Eigen::Vector2d(u, v));
      ray_x_[static_cast<size_t>(v) * camera_.width() + u] = static_cast<float>(r.x());
      ray_y_[static_cast<size_t>(v) * camera_.width() + u] = static_cast<float>(r.y());
    }
  }
}

struct Renderer::RowScratch {
  std::vector<float> t, s, tt, lod, dx, dy, dz, noise;
  std::vector<int32_t> surface, level;
  void resize(int w) {
    for (auto* v : {&t, &s, &tt, &lod, &dx, &dy, &dz, &noise}) v->resize(w);
    surface.resize(w);
    level.resize(w);
  }
};

void Renderer::render(const SE3& T_w_c, const RenderOptions& options, RenderOutput* out) const {
  if (!isFinite(T_w_c)) throw Error("renderer: camera pose is not finite");
  const int W = camera_.width(), H = camera_.height();
  out->image.create(H, W, options.color ? CV_8UC3 : CV_8UC1);
  if (options.depth) out->depth.create(H, W, CV_32FC1);
  if (options.labels) out->labels.create(H, W, CV_8UC1);

  float R[9], o[3];
  for (int i = 0; i < 3; ++i) {
    o[i] = static_cast<float>(T_w_c.translation()[i]);
    for (int j = 0; j < 3; ++j) R[3 * i + j] = static_cast<float>(T_w_c.linear()(i, j));
  }
  // The walk out of the union of spaces starts in the space holding the camera.
  int start_box = -1;
  for (size_t b = 0; b < scene_.spaces.size(); ++b) {
    if (scene_.spaces[b].contains(T_w_c.translation())) {
      start_box = static_cast<int>(b);
      break;
    }
  }
  for (const auto& s : scene_.solids) {
    if (s.contains(T_w_c.translation())) start_box = -1;
  }
  if (start_box < 0) {  // inside a wall or a solid: nothing to see
    out->image.setTo(0);
    if (options.depth) out->depth.setTo(0);
    if (options.labels) out->labels.setTo(0);
    return;
  }
  const float sigma = options.noise_sigma;
  if (options.blank) {
    constexpr float kBlankGrey = 140.0f;
    const int channels = out->image.channels();
    for (int v = 0; v < H; ++v) {
      uint8_t* img = out->image.ptr<uint8_t>(v);
      for (int u = 0; u < W; ++u) {
        const float n = sigma > 0.0f
                            ? sigma * pixelNoise(static_cast<uint32_t>(u), static_cast<uint32_t>(v),
                                                 options.noise_seed)
                            : 0.0f;
        const uint8_t g = static_cast<uint8_t>(std::clamp(kBlankGrey + n + 0.5f, 0.0f, 255.0f));
        for (int k = 0; k < channels; ++k) img[channels * u + k] = g;
      }
    }
    if (options.depth) out->depth.setTo(0);
    if (options.labels) out->labels.setTo(0);
    return;
  }
  const bool fast = spaces_f_.size() == 1;
  thread_local RowScratch row;
  row.resize(W);
  const float aniso = options.anisotropy_power;

  for (int v = 0; v < H; ++v) {
    if (fast) {
      rowGeometryFast(R, o, v, &row);
    } else {
      rowGeometryGeneral(R, o, start_box, v, &row);
    }
    // Mip level from the pixel footprint: isotropic part t |d| / f, stretched
    // by (1 / cos(incidence))^aniso. Vectorises.
    const float* dxp = row.dx.data();
    const float* dyp = row.dy.data();
    const float* dzp = row.dz.data();
    const float* tp = row.t.data();
    const int32_t* sp = row.surface.data();
    float* lodp = row.lod.data();
    for (int u = 0; u < W; ++u) {
      const float dd = dxp[u] * dxp[u] + dyp[u] * dyp[u] + dzp[u] * dzp[u];
      const int axis = (sp[u] % 6) >> 1;
      const float da = std::fabs(axis == 0 ? dxp[u] : (axis == 1 ? dyp[u] : dzp[u]));
      const float log_dd = fastLog2(dd);
      lodp[u] = fastLog2(tp[u]) + 0.5f * log_dd + log2_inv_f_texel_ +
                aniso * (0.5f * log_dd - fastLog2(da));
    }
    if (options.depth) std::memcpy(out->depth.ptr<float>(v), tp, sizeof(float) * W);
    float* noise = row.noise.data();
    if (sigma > 0.0f) {
      for (int u = 0; u < W; ++u) {
        noise[u] = sigma * pixelNoise(static_cast<uint32_t>(u), static_cast<uint32_t>(v),
                                      options.noise_seed);
      }
    } else {
      std::fill(row.noise.begin(), row.noise.end(), 0.0f);
    }
    // Finest mip level and blend weight per pixel, clamped to the surface's
    // pyramid; s, tt become coordinates at that level.
    float* sp_ = row.s.data();
    float* tt_ = row.tt.data();
    int32_t* lvl = row.level.data();
    for (int u = 0; u < W; ++u) {
      const float lod = std::clamp(lodp[u], 0.0f, max_lod_[sp[u]]);
      const int l0 = static_cast<int>(lod);
      lodp[u] = lod - static_cast<float>(l0);  // now the weight of the coarser level
      lvl[u] = l0;
      // 2^-l0 from its exponent bits.
      const int32_t bits = (127 - l0) << 23;
      float scale;
      std::memcpy(&scale, &bits, sizeof scale);
      sp_[u] *= scale;
      tt_[u] *= scale;
    }
    uint8_t* labels = options.labels ? out->labels.ptr<uint8_t>(v) : nullptr;
    if (labels) {
      for (int u = 0; u < W; ++u) labels[u] = views_[sp[u]].label;
    }
    if (options.color) {
      fetchRow<true>(row, out->image.ptr<uint8_t>(v));
    } else {
      fetchRow<false>(row, out->image.ptr<uint8_t>(v));
    }
  }
}

// Texture fetch of one row: trilinear from each pixel's surface pyramid.
template <bool kColor>
void Renderer::fetchRow(const RowScratch& row, uint8_t* img) const {
  const int W = camera_.width();
  for (int u = 0; u < W; ++u) {
    const SurfaceView& S = views_[row.surface[u]];
    const int l0 = row.level[u];
    const int l1 = std::min(l0 + 1, S.levels - 1);
    const float w1 = row.lod[u];
    const float s = row.s[u], tt = row.tt[u];
    constexpr float sc0 = 1.0f, sc1 = 0.5f;
    const float offset = row.noise[u] + 0.5f;
    if constexpr (kColor) {
      const uint32_t c0 = sampleColor(S.level[l0], s * sc0, tt * sc0);
      const uint32_t c1 = sampleColor(S.level[l1], s * sc1, tt * sc1);
      const uint32_t c = lerpPacked(c0, c1, static_cast<uint32_t>(w1 * 256.0f));
      for (int k = 0; k < 3; ++k) {
        const float val = static_cast<float>((c >> (8 * k)) & 0xFFu) + offset;
        img[3 * u + k] = static_cast<uint8_t>(std::clamp(val, 0.0f, 255.0f));
      }
    } else {
      const float g0 = sampleGray(S.level[l0], s * sc0, tt * sc0);
      const float g1 = sampleGray(S.level[l1], s * sc1, tt * sc1);
      const float val = g0 + w1 * (g1 - g0) + offset;
      img[u] = static_cast<uint8_t>(std::clamp(val, 0.0f, 255.0f));
    }
  }
}

// One space box (a corridor, a room) and any solids: branch-free per pixel,
// so the compiler vectorises it.
void Renderer::rowGeometryFast(const float* R, const float* o, int v, RowScratch* row) const {
  const int W = camera_.width();
  const BoxF& B = spaces_f_[0];
  const float* rx = &ray_x_[static_cast<size_t>(v) * W];
  const float* ry = &ray_y_[static_cast<size_t>(v) * W];
  float* tp = row->t.data();
  float* sp = row->s.data();
  float* ttp = row->tt.data();
  float* dxp = row->dx.data();
  float* dyp = row->dy.data();
  float* dzp = row->dz.data();
  int32_t* surf = row->surface.data();
  const float inv_texel = views_[0].inv_texel;
  // Locals, so the compiler knows no store in the loop changes them.
  const float r0 = R[0], r1 = R[1], r2 = R[2], r3 = R[3], r4 = R[4], r5 = R[5], r6 = R[6],
              r7 = R[7], r8 = R[8];
  const float ox = o[0], oy = o[1], oz = o[2];
  const float min_x = B.min[0], min_y = B.min[1], min_z = B.min[2];
  const float max_x = B.max[0], max_y = B.max[1], max_z = B.max[2];
  for (int u = 0; u < W; ++u) {
    const float dx = r0 * rx[u] + r1 * ry[u] + r2;
    const float dy = r3 * rx[u] + r4 * ry[u] + r5;
    const float dz = r6 * rx[u] + r7 * ry[u] + r8;
    const float tx = ((dx > 0.0f ? max_x : min_x) - ox) / dx;
    const float ty = ((dy > 0.0f ? max_y : min_y) - oy) / dy;
    const float tz = ((dz > 0.0f ? max_z : min_z) - oz) / dz;
    const bool x_first = tx <= ty && tx <= tz;
    const bool y_first = !x_first && ty <= tz;
    const float t = x_first ? tx : (y_first ? ty : tz);
    const int axis = x_first ? 0 : (y_first ? 1 : 2);
    const float d_axis = x_first ? dx : (y_first ? dy : dz);
    surf[u] = axis * 2 + (d_axis > 0.0f ? 1 : 0);
    tp[u] = t;
    dxp[u] = dx;
    dyp[u] = dy;
    dzp[u] = dz;
  }
  // Solids in front of the walls: a slab test per solid, also branch-free.
  for (size_t b = 0; b < solids_f_.size(); ++b) {
    const BoxF& S = solids_f_[b];
    const int base = static_cast<int>((spaces_f_.size() + b) * 6);
    const float sx0 = S.min[0] - ox, sx1 = S.max[0] - ox, sy0 = S.min[1] - oy, sy1 = S.max[1] - oy,
                sz0 = S.min[2] - oz, sz1 = S.max[2] - oz;
    for (int u = 0; u < W; ++u) {
      const float ix = 1.0f / dxp[u], iy = 1.0f / dyp[u], iz = 1.0f / dzp[u];
      const float ax = sx0 * ix, bx = sx1 * ix, ay = sy0 * iy, by = sy1 * iy, az = sz0 * iz,
                  bz = sz1 * iz;
      const float nx = std::min(ax, bx), ny = std::min(ay, by), nz = std::min(az, bz);
      const float t_far = std::min(std::max(ax, bx), std::min(std::max(ay, by), std::max(az, bz)));
      const bool x_near = nx >= ny && nx >= nz;
      const bool y_near = !x_near && ny >= nz;
      const float t_near = x_near ? nx : (y_near ? ny : nz);
      const int axis = x_near ? 0 : (y_near ? 1 : 2);
      const float d_axis = x_near ? dxp[u] : (y_near ? dyp[u] : dzp[u]);
      // Entering through the min face when moving up the axis.
      const int face = axis * 2 + (d_axis > 0.0f ? 0 : 1);
      const bool hit = t_near <= t_far && t_near > 0.0f && t_near < tp[u];
      tp[u] = hit ? t_near : tp[u];
      surf[u] = hit ? base + face : surf[u];
    }
  }
  // Texture coordinates on each pixel's surface.
  const float* s0 = tex_s0_.data();
  const float* t0 = tex_t0_.data();
  for (int u = 0; u < W; ++u) {
    const float t = tp[u];
    const float px = ox + t * dxp[u], py = oy + t * dyp[u], pz = oz + t * dzp[u];
    const int axis = (surf[u] % 6) >> 1;
    // Texture axes: x faces use (y, z), y faces (x, z), z faces (x, y).
    sp[u] = ((axis == 0 ? py : px) - s0[surf[u]]) * inv_texel;
    ttp[u] = ((axis == 2 ? py : pz) - t0[surf[u]]) * inv_texel;
  }
}

// Any number of spaces and solids: the same outputs, one ray cast per pixel.
void Renderer::rowGeometryGeneral(const float* R, const float* o, int start_box, int v,
                                  RowScratch* row) const {
  const int W = camera_.width();
  const float* rx = &ray_x_[static_cast<size_t>(v) * W];
  const float* ry = &ray_y_[static_cast<size_t>(v) * W];
  const size_t solid_base = spaces_f_.size() * 6;
  for (int u = 0; u < W; ++u) {
    const float d[3] = {R[0] * rx[u] + R[1] * ry[u] + R[2], R[3] * rx[u] + R[4] * ry[u] + R[5],
                        R[6] * rx[u] + R[7] * ry[u] + R[8]};
    const float inv[3] = {1.0f / d[0], 1.0f / d[1], 1.0f / d[2]};
    int box = start_box;
    float t = kInf;
    int face = 0;
    for (size_t iter = 0; iter <= spaces_f_.size(); ++iter) {
      const BoxF& B = spaces_f_[box];
      float exit_t = kInf;
      for (int a = 0; a < 3; ++a) {
        const int side = d[a] > 0.0f ? 1 : 0;
        const float ta = ((side ? B.max[a] : B.min[a]) - o[a]) * inv[a];
        if (ta < exit_t) {
          exit_t = ta;
          face = a * 2 + side;
        }
      }
      t = exit_t;
      // Continue into another space that contains the exit point, if any.
      const float te = t * 1.0001f + 1e-4f;
      const float p[3] = {o[0] + te * d[0], o[1] + te * d[1], o[2] + te * d[2]};
      int next = -1;
      for (size_t b = 0; b < spaces_f_.size(); ++b) {
        const BoxF& N = spaces_f_[b];
        if (p[0] > N.min[0] && p[0] < N.max[0] && p[1] > N.min[1] && p[1] < N.max[1] &&
            p[2] > N.min[2] && p[2] < N.max[2]) {
          next = static_cast<int>(b);
          break;
        }
      }
      if (next < 0) break;
      box = next;
    }
    int surface = box * 6 + face;
    for (size_t b = 0; b < solids_f_.size(); ++b) {
      const BoxF& B = solids_f_[b];
      float t_near = -kInf, t_far = kInf;
      int near_face = 0;
      for (int a = 0; a < 3; ++a) {
        float t0 = (B.min[a] - o[a]) * inv[a], t1 = (B.max[a] - o[a]) * inv[a];
        int side = 0;
        if (t0 > t1) {
          std::swap(t0, t1);
          side = 1;
        }
        if (t0 > t_near) {
          t_near = t0;
          near_face = a * 2 + side;
        }
        t_far = std::min(t_far, t1);
      }
      if (t_near <= t_far && t_near > 0.0f && t_near < t) {
        t = t_near;
        surface = static_cast<int>(solid_base + b * 6) + near_face;
      }
    }
    const SurfaceView& S = views_[surface];
    row->surface[u] = surface;
    row->t[u] = t;
    row->s[u] = (o[S.s_axis] + t * d[S.s_axis] - S.s0) * S.inv_texel;
    row->tt[u] = (o[S.t_axis] + t * d[S.t_axis] - S.t0) * S.inv_texel;
    row->dx[u] = d[0];
    row->dy[u] = d[1];
    row->dz[u] = d[2];
  }
}

}  // namespace ecar
