#include "data/mesh_renderer.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include <ATen/ATen.h>
#include <ATen/Parallel.h>

#include "body/mesh.h"
#include "ops/splat/constants.h"
#include "data/constants.h"

namespace sfgs::data {
namespace {

constexpr int kBandRows = 8;            // rows per parallel work item: small enough to balance, big enough to amortise
constexpr int64_t kShadeGrain = 16;     // rows per parallel shading task, for the same reason
constexpr float kDefaultAlbedo = 0.7f;  // grey, for meshes with neither texture nor vertex colours

struct ScreenTriangle {
  int64_t face;
  double x[3], y[3], inv_z[3];
  double area;   // positive after orientation is normalised
  int order[3];  // corner k of this triangle is corner order[k] of the face
  int row0, row1, col0, col1;
};

// The mesh in camera space, float64 on the CPU.
struct CameraSpaceMesh {
  at::Tensor points;   // (V, 3)
  at::Tensor faces;    // (F, 3) int64
  at::Tensor normals;  // (V, 3) unit, or zero where undefined
};

// What is visible at each pixel: the nearest face and where on it.
struct Fragments {
  at::Tensor depth;        // (H, W) float32 camera-space z, 0 where uncovered
  at::Tensor face;         // (H, W) int64, -1 where uncovered
  at::Tensor barycentric;  // (H, W, 3) float64 perspective-correct, in face corner order
};

// Top-left fill rule for positively oriented triangles in y-down screen space.
bool top_left(double dx, double dy) { return (dy == 0 && dx > 0) || dy < 0; }

double edge(double ax, double ay, double bx, double by, double px, double py) {
  return (bx - ax) * (py - ay) - (by - ay) * (px - ax);
}

void check_mesh(const TexturedMesh& m, const at::Tensor& background) {
  TORCH_CHECK(m.vertices.defined() && m.vertices.dim() == 2 && m.vertices.size(1) == 3 &&
                  at::isFloatingType(m.vertices.scalar_type()),
              "render_mesh: vertices must be a floating (V, 3) tensor, got ", m.vertices.sizes());
  TORCH_CHECK(
      m.faces.defined() && m.faces.dim() == 2 && m.faces.size(1) == 3 && !at::isFloatingType(m.faces.scalar_type()),
      "render_mesh: faces must be an integer (F, 3) tensor, got ", m.faces.sizes());
  const int64_t v = m.vertices.size(0);
  if (m.faces.numel() > 0)
    TORCH_CHECK(m.faces.min().item<int64_t>() >= 0 && m.faces.max().item<int64_t>() < v,
                "render_mesh: face indices must lie in [0, ", v, ")");
  if (m.uvs.defined()) {
    TORCH_CHECK(m.uvs.dim() == 2 && m.uvs.size(1) == 2, "render_mesh: uvs must be (T, 2), got ", m.uvs.sizes());
    TORCH_CHECK(m.face_uvs.defined() && m.face_uvs.sizes() == m.faces.sizes(),
                "render_mesh: face_uvs must have the shape of faces ", m.faces.sizes());
    if (m.face_uvs.numel() > 0)
      TORCH_CHECK(m.face_uvs.min().item<int64_t>() >= 0 && m.face_uvs.max().item<int64_t>() < m.uvs.size(0),
                  "render_mesh: face_uvs indices must lie in [0, ", m.uvs.size(0), ")");
    TORCH_CHECK(m.texture.defined() && m.texture.dim() == 3 && m.texture.size(2) == 3 && m.texture.size(0) > 0 &&
                    m.texture.size(1) > 0,
                "render_mesh: texture must be (Ht, Wt, 3), got ",
                m.texture.defined() ? m.texture.sizes() : at::IntArrayRef{});
  }
  if (m.vertex_colours.defined())
    TORCH_CHECK(m.vertex_colours.sizes() == m.vertices.sizes(), "render_mesh: vertex_colours must be (V, 3)");
  TORCH_CHECK(background.defined() && background.numel() == 3, "render_mesh: background must have 3 values");
}

// A 4 x 4 row-major rigid transform as a tensor.
at::Tensor matrix_of(const std::array<double, 16>& m) {
  return at::tensor(std::vector<double>(m.begin(), m.end()), at::kDouble).view({4, 4});
}

CameraSpaceMesh to_camera(const TexturedMesh& mesh, const Camera& camera) {
  const at::Tensor view = matrix_of(camera.world_to_camera);
  const at::Tensor rotation = view.slice(0, 0, 3).slice(1, 0, 3);
  const at::Tensor translation = view.slice(0, 0, 3).select(1, 3);
  CameraSpaceMesh out;
  out.points = (mesh.vertices.detach().cpu().to(at::kDouble).matmul(rotation.t()) + translation).contiguous();
  out.faces = mesh.faces.cpu().to(at::kLong).contiguous();
  out.normals = body::vertex_normals(out.points, out.faces).contiguous();  // area-weighted, camera space
  return out;
}

// Projects face f to the screen, positively oriented, with the pixel rows and columns whose centres its bounding
// box holds. False when it is culled: a vertex in front of the near plane, no area, or no pixel centre inside.
bool project_triangle(const double* p, const int64_t* fc, int64_t f, const Camera& camera, ScreenTriangle& t) {
  t.face = f;
  bool in_front = true;
  for (int k = 0; k < 3; ++k) {
    const double* q = p + 3 * fc[3 * f + k];
    in_front &= q[2] >= camera.near_plane;
    t.x[k] = camera.fx * q[0] / q[2] + camera.cx;
    t.y[k] = camera.fy * q[1] / q[2] + camera.cy;
    t.inv_z[k] = 1.0 / q[2];
    t.order[k] = k;
  }
  if (!in_front) return false;
  t.area = edge(t.x[0], t.y[0], t.x[1], t.y[1], t.x[2], t.y[2]);
  if (!(std::abs(t.area) > 0) || !std::isfinite(t.area)) return false;
  if (t.area < 0) {  // make every triangle positively oriented; the mesh is rendered double-sided
    std::swap(t.x[1], t.x[2]);
    std::swap(t.y[1], t.y[2]);
    std::swap(t.inv_z[1], t.inv_z[2]);
    std::swap(t.order[1], t.order[2]);
    t.area = -t.area;
  }
  const auto lo = [](double a, double b, double c) { return std::min({a, b, c}); };
  const auto hi = [](double a, double b, double c) { return std::max({a, b, c}); };
  // Pixel centres i + 0.5 inside [min, max]: i from ceil(min - 0.5) to floor(max - 0.5).
  t.col0 = int(std::max(0.0, std::ceil(lo(t.x[0], t.x[1], t.x[2]) - kPixelCentre)));
  t.col1 = int(std::min(double(camera.width - 1), std::floor(hi(t.x[0], t.x[1], t.x[2]) - kPixelCentre)));
  t.row0 = int(std::max(0.0, std::ceil(lo(t.y[0], t.y[1], t.y[2]) - kPixelCentre)));
  t.row1 = int(std::min(double(camera.height - 1), std::floor(hi(t.y[0], t.y[1], t.y[2]) - kPixelCentre)));
  return t.col0 <= t.col1 && t.row0 <= t.row1;
}

// The triangles that can cover a pixel centre, in face order.
std::vector<ScreenTriangle> project_triangles(const CameraSpaceMesh& mesh, const Camera& camera) {
  const double* p = mesh.points.data_ptr<double>();
  const int64_t* fc = mesh.faces.data_ptr<int64_t>();
  const int64_t n_faces = mesh.faces.size(0);
  std::vector<ScreenTriangle> triangles;
  triangles.reserve(size_t(n_faces));
  for (int64_t f = 0; f < n_faces; ++f) {
    ScreenTriangle t;
    if (project_triangle(p, fc, f, camera, t)) triangles.push_back(t);
  }
  return triangles;
}

// Raw views of the fragment images, written by the bands in parallel (each band its own rows).
struct FragmentPixels {
  float* depth;
  int64_t* face;
  double* barycentric;
};

// Rasterises the triangles listed for the rows r0..r1 with a z-buffer of those rows, writing the nearest surface's
// depth, face and perspective-correct barycentric coordinates. Ties keep the earlier triangle.
void rasterise_band(const std::vector<ScreenTriangle>& triangles, const std::vector<int32_t>& listed, int r0, int r1,
                    int64_t w, std::vector<double>& zbuffer, const FragmentPixels& out) {
  zbuffer.assign(size_t((r1 - r0 + 1) * w), std::numeric_limits<double>::infinity());
  for (int32_t ti : listed) {
    const ScreenTriangle& t = triangles[size_t(ti)];
    const bool tl0 = top_left(t.x[2] - t.x[1], t.y[2] - t.y[1]);  // edge opposite corner 0
    const bool tl1 = top_left(t.x[0] - t.x[2], t.y[0] - t.y[2]);
    const bool tl2 = top_left(t.x[1] - t.x[0], t.y[1] - t.y[0]);
    for (int y = std::max(r0, t.row0); y <= std::min(r1, t.row1); ++y) {
      const double py = y + kPixelCentre;
      for (int x = t.col0; x <= t.col1; ++x) {
        const double px = x + kPixelCentre;
        const double e0 = edge(t.x[1], t.y[1], t.x[2], t.y[2], px, py);
        const double e1 = edge(t.x[2], t.y[2], t.x[0], t.y[0], px, py);
        const double e2 = edge(t.x[0], t.y[0], t.x[1], t.y[1], px, py);
        if (e0 < 0 || e1 < 0 || e2 < 0) continue;
        if ((e0 == 0 && !tl0) || (e1 == 0 && !tl1) || (e2 == 0 && !tl2)) continue;
        double b[3] = {e0 / t.area * t.inv_z[0], e1 / t.area * t.inv_z[1], e2 / t.area * t.inv_z[2]};
        const double inv_z = b[0] + b[1] + b[2];
        const double z = 1.0 / inv_z;
        double& best = zbuffer[size_t((y - r0) * w + x)];
        if (!(z < best)) continue;
        best = z;
        const int64_t pix = int64_t(y) * w + x;
        out.depth[pix] = float(z);
        out.face[pix] = t.face;
        for (int k = 0; k < 3; ++k) out.barycentric[pix * 3 + t.order[k]] = b[k] * z;
      }
    }
  }
}

// Bands of kBandRows rows are rasterised in parallel, each with the triangles whose rows meet it.
Fragments rasterise(const std::vector<ScreenTriangle>& triangles, int64_t h, int64_t w) {
  const int64_t n_bands = (h + kBandRows - 1) / kBandRows;
  std::vector<std::vector<int32_t>> band_triangles(static_cast<size_t>(n_bands));
  for (size_t i = 0; i < triangles.size(); ++i)
    for (int b = triangles[i].row0 / kBandRows; b <= triangles[i].row1 / kBandRows; ++b)
      band_triangles[size_t(b)].push_back(int32_t(i));

  Fragments out;
  out.depth = at::zeros({h, w}, at::kFloat);
  out.face = at::full({h, w}, -1, at::kLong);
  out.barycentric = at::zeros({h, w, 3}, at::kDouble);
  const FragmentPixels pixels = {out.depth.data_ptr<float>(), out.face.data_ptr<int64_t>(),
                                 out.barycentric.data_ptr<double>()};
  at::parallel_for(0, n_bands, 1, [&](int64_t begin, int64_t end) {
    std::vector<double> zbuffer;
    for (int64_t band = begin; band < end; ++band) {
      const int r0 = int(band * kBandRows), r1 = int(std::min<int64_t>(h, (band + 1) * kBandRows)) - 1;
      rasterise_band(triangles, band_triangles[size_t(band)], r0, r1, w, zbuffer, pixels);
    }
  });
  return out;
}

// The mesh's surface colours: a texture sampled at interpolated UVs, or interpolated vertex colours.
struct Albedo {
  bool textured;
  at::Tensor colours;   // (V, 3) float32 without a texture
  at::Tensor uvs;       // (T, 2) float64 with one
  at::Tensor face_uvs;  // (F, 3) int64
  at::Tensor texture;   // (Ht, Wt, 3) float32
};

Albedo albedo_of(const TexturedMesh& mesh, int64_t vertex_count) {
  Albedo a;
  a.colours = mesh.vertex_colours.defined() ? mesh.vertex_colours.cpu().to(at::kFloat).contiguous()
                                            : at::full({vertex_count, 3}, kDefaultAlbedo);
  a.textured = mesh.uvs.defined();
  a.uvs = a.textured ? mesh.uvs.cpu().to(at::kDouble).contiguous() : at::Tensor();
  a.face_uvs = a.textured ? mesh.face_uvs.cpu().to(at::kLong).contiguous() : at::Tensor();
  a.texture = a.textured ? mesh.texture.cpu().to(at::kFloat).contiguous() : at::Tensor();
  return a;
}

// The (th, tw, 3) texture at (u, v), v up; texel centres sit at + 0.5 like pixel centres, edges are clamped.
void sample_bilinear(const float* tex, int64_t th, int64_t tw, double u, double v, float* out) {
  const double x = std::clamp(u * double(tw) - kPixelCentre, 0.0, double(tw - 1));
  const double y = std::clamp((1.0 - v) * double(th) - kPixelCentre, 0.0, double(th - 1));
  const int64_t x0 = int64_t(x), y0 = int64_t(y);
  const int64_t x1 = std::min(x0 + 1, tw - 1), y1 = std::min(y0 + 1, th - 1);
  const double fx = x - double(x0), fy = y - double(y0);
  for (int c = 0; c < 3; ++c) {
    const double top = tex[(y0 * tw + x0) * 3 + c] * (1 - fx) + tex[(y0 * tw + x1) * 3 + c] * fx;
    const double bottom = tex[(y1 * tw + x0) * 3 + c] * (1 - fx) + tex[(y1 * tw + x1) * 3 + c] * fx;
    out[c] = float(top * (1 - fy) + bottom * fy);
  }
}

// Raw views of what shading reads, taken once per image; the texture pointers are null without a texture.
struct SurfaceView {
  const double* points;
  const int64_t* faces;
  const double* normals;
  bool textured;
  const float* colours;
  const double* uvs;
  const int64_t* face_uvs;
  const float* texture;
  int64_t texture_height, texture_width;
};

// The key light as shading sees it: its direction and a shadow map of the mesh rendered from far along it.
struct KeyLight {
  double direction[3];           // unit, towards the light, camera space
  double light_from_camera[12];  // 3 x 4 row-major: camera space to the light camera's space
  double focal, centre;          // of the square shadow map
  const float* depth;            // (kShadowMapSide)^2 nearest depth seen from the light, 0 where uncovered
  double bias;                   // metres
};

// The shadow map's camera: far along the light direction, looking at the mesh's bounding-sphere centre, framing
// the sphere.
Camera light_camera(const at::Tensor& world_vertices, const std::array<double, 3>& towards_light, double& radius) {
  const at::Tensor v = world_vertices.detach().cpu().to(at::kDouble);
  const at::Tensor centre = (std::get<0>(v.min(0)) + std::get<0>(v.max(0))) / 2;
  radius = std::max((v - centre).norm(2, 1).max().item<double>(), kMinSpan);
  const double distance = kShadowLightDistanceRadii * radius;
  const double side = double(kShadowMapSide);
  Camera camera = Camera::looking_forward(side / 2 * (kShadowLightDistanceRadii - 1), kShadowMapSide, kShadowMapSide);
  const at::Tensor z = -at::tensor(std::vector<double>(towards_light.begin(), towards_light.end()), at::kDouble);
  const at::Tensor forward = z / z.norm();
  const at::Tensor up = forward[1].abs().item<double>() > 0.99 ? at::tensor({1.0, 0.0, 0.0}, at::kDouble)
                                                               : at::tensor({0.0, 1.0, 0.0}, at::kDouble);
  at::Tensor x = at::linalg_cross(forward, up);
  x = x / x.norm();
  const at::Tensor y = at::linalg_cross(forward, x);
  const at::Tensor eye = centre - forward * distance;
  const at::Tensor rows = at::stack({x, y, forward});
  const at::Tensor t = -rows.matmul(eye);
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) camera.world_to_camera[size_t(4 * r + c)] = rows[r][c].item<double>();
    camera.world_to_camera[size_t(4 * r + 3)] = t[r].item<double>();
  }
  camera.near_plane = distance - 2 * radius;  // the whole sphere lies beyond it
  return camera;
}

// Shadow map and direction of a key light for `camera`'s view of `mesh`; shading reads `depth` through raw pointers.
KeyLight key_light_for(const TexturedMesh& mesh, const Camera& camera, const std::array<double, 3>& towards_light,
                       at::Tensor& depth) {
  double radius = 0;
  const Camera light = light_camera(mesh.vertices, towards_light, radius);
  depth =
      rasterise(project_triangles(to_camera(mesh, light), light), kShadowMapSide, kShadowMapSide).depth.contiguous();
  const at::Tensor camera_to_world = at::linalg_inv(matrix_of(camera.world_to_camera));
  const at::Tensor light_from_camera = matrix_of(light.world_to_camera).matmul(camera_to_world).contiguous();
  const at::Tensor l = at::tensor(std::vector<double>(towards_light.begin(), towards_light.end()), at::kDouble);
  const at::Tensor in_camera = matrix_of(camera.world_to_camera).slice(0, 0, 3).slice(1, 0, 3).matmul(l / l.norm());
  KeyLight k{};
  for (int c = 0; c < 3; ++c) k.direction[c] = in_camera[c].item<double>();
  for (int i = 0; i < 12; ++i) k.light_from_camera[i] = light_from_camera.data_ptr<double>()[i];
  k.focal = light.fx;
  k.centre = light.cx;
  k.depth = depth.data_ptr<float>();
  k.bias = kShadowBiasRadii * radius;
  return k;
}

// The share of the key light reaching camera-space point q: 3 x 3 percentage-closer filtering of the shadow map.
double lit_fraction(const KeyLight& k, const double* q) {
  double p[3];
  for (int r = 0; r < 3; ++r)
    p[r] = k.light_from_camera[4 * r] * q[0] + k.light_from_camera[4 * r + 1] * q[1] +
           k.light_from_camera[4 * r + 2] * q[2] + k.light_from_camera[4 * r + 3];
  const int64_t u = int64_t(std::floor(k.focal * p[0] / p[2] + k.centre));
  const int64_t v = int64_t(std::floor(k.focal * p[1] / p[2] + k.centre));
  int lit = 0;
  for (int64_t dv = -1; dv <= 1; ++dv)
    for (int64_t du = -1; du <= 1; ++du) {
      const int64_t x = std::clamp<int64_t>(u + du, 0, kShadowMapSide - 1);
      const int64_t y = std::clamp<int64_t>(v + dv, 0, kShadowMapSide - 1);
      const float d = k.depth[y * kShadowMapSide + x];
      lit += (d == 0.0f || p[2] <= double(d) + k.bias) ? 1 : 0;
    }
  return lit / 9.0;
}

SurfaceView view_of(const CameraSpaceMesh& mesh, const Albedo& albedo) {
  return {mesh.points.data_ptr<double>(),
          mesh.faces.data_ptr<int64_t>(),
          mesh.normals.data_ptr<double>(),
          albedo.textured,
          albedo.colours.data_ptr<float>(),
          albedo.textured ? albedo.uvs.data_ptr<double>() : nullptr,
          albedo.textured ? albedo.face_uvs.data_ptr<int64_t>() : nullptr,
          albedo.textured ? albedo.texture.data_ptr<float>() : nullptr,
          albedo.textured ? albedo.texture.size(0) : 0,
          albedo.textured ? albedo.texture.size(1) : 0};
}

// The colour of a pixel showing face f at barycentric coordinates b: albedo times ambient light plus the directional
// light, Lambertian: a head light in the angle between the interpolated normal and the view ray (either side of the
// surface), or the key light (when given) on the outward normal, shadowed.
void shade_pixel(const SurfaceView& s, const MeshShading& shading, const KeyLight* key, int64_t f, const double* b,
                 float* rgb) {
  double n[3] = {0, 0, 0}, q[3] = {0, 0, 0};
  float albedo[3] = {0, 0, 0};
  for (int k = 0; k < 3; ++k) {
    const int64_t v = s.faces[3 * f + k];
    for (int c = 0; c < 3; ++c) {
      n[c] += b[k] * s.normals[3 * v + c];
      q[c] += b[k] * s.points[3 * v + c];
      if (!s.textured) albedo[c] += float(b[k]) * s.colours[3 * v + c];
    }
  }
  if (s.textured) {
    double u = 0, v = 0;
    for (int k = 0; k < 3; ++k) {
      u += b[k] * s.uvs[2 * s.face_uvs[3 * f + k]];
      v += b[k] * s.uvs[2 * s.face_uvs[3 * f + k] + 1];
    }
    sample_bilinear(s.texture, s.texture_height, s.texture_width, u, v, albedo);
  }
  const double n_len = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
  double cosine = 1.0;
  if (key != nullptr) {
    const double facing = n[0] * key->direction[0] + n[1] * key->direction[1] + n[2] * key->direction[2];
    cosine = n_len > 0 && facing > 0 ? facing / n_len * lit_fraction(*key, q) : 0.0;
  } else {
    const double q_len = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2]);
    if (n_len > 0 && q_len > 0) cosine = std::abs(n[0] * q[0] + n[1] * q[1] + n[2] * q[2]) / (n_len * q_len);
  }
  const double light = shading.ambient + shading.diffuse * cosine;
  for (int c = 0; c < 3; ++c) rgb[c] = float(std::min(1.0, albedo[c] * light));
}

// The shaded image: background where no face is visible.
at::Tensor shade(const CameraSpaceMesh& mesh, const Albedo& albedo, const Fragments& fragments,
                 const at::Tensor& background, const MeshShading& shading, const KeyLight* key) {
  const int64_t h = fragments.face.size(0), w = fragments.face.size(1);
  at::Tensor image = background.to(at::kFloat).cpu().view({1, 1, 3}).repeat({h, w, 1}).contiguous();
  float* img = image.data_ptr<float>();
  const int64_t* fid = fragments.face.data_ptr<int64_t>();
  const double* bar = fragments.barycentric.data_ptr<double>();
  const SurfaceView surface = view_of(mesh, albedo);
  at::parallel_for(0, h, kShadeGrain, [&](int64_t begin, int64_t end) {
    for (int64_t y = begin; y < end; ++y)
      for (int64_t x = 0; x < w; ++x) {
        const int64_t pix = y * w + x;
        if (fid[pix] < 0) continue;
        shade_pixel(surface, shading, key, fid[pix], bar + pix * 3, img + pix * 3);
      }
  });
  return image;
}

}  // namespace

MeshImage render_mesh(const TexturedMesh& mesh, const Camera& camera, const at::Tensor& background,
                      const MeshShading& shading) {
  check_mesh(mesh, background);
  const int64_t h = camera.height, w = camera.width;
  TORCH_CHECK(h >= 1 && w >= 1 && h <= kMaxImageSide && w <= kMaxImageSide, "render_mesh: bad image size ", w, " x ",
              h);
  const CameraSpaceMesh in_camera = to_camera(mesh, camera);
  const Fragments fragments = rasterise(project_triangles(in_camera, camera), h, w);
  const bool has_key_light = shading.key_light != std::array<double, 3>{0, 0, 0};
  TORCH_CHECK(
      std::isfinite(shading.key_light[0]) && std::isfinite(shading.key_light[1]) && std::isfinite(shading.key_light[2]),
      "render_mesh: the key light direction must be finite");
  at::Tensor shadow_depth;
  KeyLight key{};
  if (has_key_light) key = key_light_for(mesh, camera, shading.key_light, shadow_depth);
  MeshImage out;
  out.image = shade(in_camera, albedo_of(mesh, in_camera.points.size(0)), fragments, background, shading,
                    has_key_light ? &key : nullptr);
  out.mask = (fragments.face >= 0).to(at::kFloat);
  out.depth = fragments.depth;
  out.face = fragments.face;
  return out;
}

}  // namespace sfgs::data
