#include "data/mesh_renderer.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include <ATen/ATen.h>
#include <ATen/Parallel.h>

#include "body/mesh.h"
#include "common/constants.h"

namespace sfgs::data {
namespace {

constexpr int kBandRows = 8;            // rows per parallel work item: small enough to balance, big enough to amortise
constexpr int64_t kShadeGrain = 16;     // rows per parallel shading task, for the same reason
constexpr float kDefaultAlbedo = 0.7f;  // grey, for meshes with neither texture nor vertex colours

struct ScreenTriangle {
  int64_t face;
  double x[3], y[3], inv_z[3];
  double area;  // positive after orientation is normalised
  int order[3]; // corner k of this triangle is corner order[k] of the face
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
  TORCH_CHECK(m.faces.defined() && m.faces.dim() == 2 && m.faces.size(1) == 3 &&
                  !at::isFloatingType(m.faces.scalar_type()),
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

CameraSpaceMesh to_camera(const TexturedMesh& mesh, const Camera& camera) {
  const auto f64 = at::TensorOptions().dtype(at::kDouble);
  const at::Tensor view =
      at::tensor(std::vector<double>(camera.world_to_camera.begin(), camera.world_to_camera.end()), f64).view({4, 4});
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

// The colour of a pixel showing face f at barycentric coordinates b: albedo times ambient light plus a head light,
// Lambertian in the angle between the interpolated normal and the view ray (either side of the surface).
void shade_pixel(const SurfaceView& s, const MeshShading& shading, int64_t f, const double* b, float* rgb) {
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
  const double q_len = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2]);
  const double cosine =
      n_len > 0 && q_len > 0 ? std::abs(n[0] * q[0] + n[1] * q[1] + n[2] * q[2]) / (n_len * q_len) : 1.0;
  const double light = shading.ambient + shading.diffuse * cosine;
  for (int c = 0; c < 3; ++c) rgb[c] = float(std::min(1.0, albedo[c] * light));
}

// The shaded image: background where no face is visible.
at::Tensor shade(const CameraSpaceMesh& mesh, const Albedo& albedo, const Fragments& fragments,
                 const at::Tensor& background, const MeshShading& shading) {
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
        shade_pixel(surface, shading, fid[pix], bar + pix * 3, img + pix * 3);
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
  MeshImage out;
  out.image = shade(in_camera, albedo_of(mesh, in_camera.points.size(0)), fragments, background, shading);
  out.mask = (fragments.face >= 0).to(at::kFloat);
  out.depth = fragments.depth;
  out.face = fragments.face;
  return out;
}

}  // namespace sfgs::data
