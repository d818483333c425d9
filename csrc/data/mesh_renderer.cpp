#include "data/mesh_renderer.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include <ATen/ATen.h>
#include <ATen/Parallel.h>

namespace sfgs::data {
namespace {

constexpr int kBandRows = 8;  // rows per parallel work item: small enough to balance, large enough to amortise

struct ScreenTriangle {
  int64_t face;
  double x[3], y[3], inv_z[3];
  double area;  // positive after orientation is normalised
  int order[3]; // corner k of this triangle is corner order[k] of the face
  int row0, row1, col0, col1;
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
  TORCH_CHECK(m.faces.defined() && m.faces.dim() == 2 && m.faces.size(1) == 3 && !at::isFloatingType(m.faces.scalar_type()),
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

// Area-weighted vertex normals in camera space.
at::Tensor vertex_normals(const at::Tensor& points, const at::Tensor& faces) {
  const at::Tensor a = points.index_select(0, faces.select(1, 0));
  const at::Tensor b = points.index_select(0, faces.select(1, 1));
  const at::Tensor c = points.index_select(0, faces.select(1, 2));
  const at::Tensor face_normal = at::cross(b - a, c - a, 1);
  at::Tensor normals = at::zeros_like(points);
  for (int k = 0; k < 3; ++k) normals.index_add_(0, faces.select(1, k), face_normal);
  return normals / normals.norm(2, 1, true).clamp_min(1e-20);
}

void sample_bilinear(const float* tex, int64_t th, int64_t tw, double u, double v, float* out) {
  const double x = std::clamp(u * double(tw) - 0.5, 0.0, double(tw - 1));
  const double y = std::clamp((1.0 - v) * double(th) - 0.5, 0.0, double(th - 1));
  const int64_t x0 = int64_t(x), y0 = int64_t(y);
  const int64_t x1 = std::min(x0 + 1, tw - 1), y1 = std::min(y0 + 1, th - 1);
  const double fx = x - double(x0), fy = y - double(y0);
  for (int c = 0; c < 3; ++c) {
    const double top = tex[(y0 * tw + x0) * 3 + c] * (1 - fx) + tex[(y0 * tw + x1) * 3 + c] * fx;
    const double bottom = tex[(y1 * tw + x0) * 3 + c] * (1 - fx) + tex[(y1 * tw + x1) * 3 + c] * fx;
    out[c] = float(top * (1 - fy) + bottom * fy);
  }
}

}  // namespace

MeshImage render_mesh(const TexturedMesh& mesh, const Camera& camera, const at::Tensor& background,
                      const MeshShading& shading) {
  check_mesh(mesh, background);
  const int64_t h = camera.height, w = camera.width;
  TORCH_CHECK(h >= 1 && w >= 1 && h <= kMaxImageSide && w <= kMaxImageSide, "render_mesh: bad image size ", w, " x ", h);
  const auto f64 = at::TensorOptions().dtype(at::kDouble);
  const at::Tensor view = at::tensor(std::vector<double>(camera.world_to_camera.begin(), camera.world_to_camera.end()), f64).view({4, 4});
  const at::Tensor rotation = view.slice(0, 0, 3).slice(1, 0, 3);
  const at::Tensor points = (mesh.vertices.detach().cpu().to(at::kDouble).matmul(rotation.t()) + view.slice(0, 0, 3).select(1, 3)).contiguous();
  const at::Tensor faces = mesh.faces.cpu().to(at::kLong).contiguous();
  const at::Tensor normals = vertex_normals(points, faces).contiguous();
  const double* p = points.data_ptr<double>();
  const int64_t* fc = faces.data_ptr<int64_t>();
  const int64_t n_faces = faces.size(0);

  std::vector<ScreenTriangle> triangles;
  triangles.reserve(size_t(n_faces));
  for (int64_t f = 0; f < n_faces; ++f) {
    ScreenTriangle t;
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
    if (!in_front) continue;
    t.area = edge(t.x[0], t.y[0], t.x[1], t.y[1], t.x[2], t.y[2]);
    if (!(std::abs(t.area) > 0) || !std::isfinite(t.area)) continue;
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
    t.col1 = int(std::min(double(w - 1), std::floor(hi(t.x[0], t.x[1], t.x[2]) - kPixelCentre)));
    t.row0 = int(std::max(0.0, std::ceil(lo(t.y[0], t.y[1], t.y[2]) - kPixelCentre)));
    t.row1 = int(std::min(double(h - 1), std::floor(hi(t.y[0], t.y[1], t.y[2]) - kPixelCentre)));
    if (t.col0 > t.col1 || t.row0 > t.row1) continue;
    triangles.push_back(t);
  }

  const int64_t n_bands = (h + kBandRows - 1) / kBandRows;
  std::vector<std::vector<int32_t>> band_triangles(static_cast<size_t>(n_bands));
  for (size_t i = 0; i < triangles.size(); ++i)
    for (int b = triangles[i].row0 / kBandRows; b <= triangles[i].row1 / kBandRows; ++b)
      band_triangles[size_t(b)].push_back(int32_t(i));

  at::Tensor depth = at::zeros({h, w}, at::kFloat);
  at::Tensor face_index = at::full({h, w}, -1, at::kLong);
  at::Tensor barycentric = at::zeros({h, w, 3}, at::kDouble);  // perspective-correct, in face corner order
  float* dep = depth.data_ptr<float>();
  int64_t* fid = face_index.data_ptr<int64_t>();
  double* bar = barycentric.data_ptr<double>();

  at::parallel_for(0, n_bands, 1, [&](int64_t begin, int64_t end) {
    std::vector<double> zbuffer;
    for (int64_t band = begin; band < end; ++band) {
      const int r0 = int(band * kBandRows), r1 = int(std::min<int64_t>(h, (band + 1) * kBandRows)) - 1;
      zbuffer.assign(size_t((r1 - r0 + 1) * w), std::numeric_limits<double>::infinity());
      for (int32_t ti : band_triangles[size_t(band)]) {
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
            dep[pix] = float(z);
            fid[pix] = t.face;
            for (int k = 0; k < 3; ++k) bar[pix * 3 + t.order[k]] = b[k] * z;
          }
        }
      }
    }
  });

  // Shading: albedo from the texture (perspective-correct UV) or vertex colours, Lambert with a head light.
  MeshImage out;
  out.image = background.to(at::kFloat).cpu().view({1, 1, 3}).repeat({h, w, 1}).contiguous();
  float* img = out.image.data_ptr<float>();
  const at::Tensor colours = mesh.vertex_colours.defined() ? mesh.vertex_colours.cpu().to(at::kFloat).contiguous()
                                                           : at::full({points.size(0), 3}, 0.7f);
  const bool textured = mesh.uvs.defined();
  const at::Tensor uvs = textured ? mesh.uvs.cpu().to(at::kDouble).contiguous() : at::Tensor();
  const at::Tensor face_uvs = textured ? mesh.face_uvs.cpu().to(at::kLong).contiguous() : at::Tensor();
  const at::Tensor texture = textured ? mesh.texture.cpu().to(at::kFloat).contiguous() : at::Tensor();
  const double* nrm = normals.data_ptr<double>();
  const float* col = colours.data_ptr<float>();
  at::parallel_for(0, h, 16, [&](int64_t begin, int64_t end) {
    for (int64_t y = begin; y < end; ++y)
      for (int64_t x = 0; x < w; ++x) {
        const int64_t pix = y * w + x;
        const int64_t f = fid[pix];
        if (f < 0) continue;
        const double* b = bar + pix * 3;
        double n[3] = {0, 0, 0}, q[3] = {0, 0, 0};
        float albedo[3] = {0, 0, 0};
        for (int k = 0; k < 3; ++k) {
          const int64_t v = fc[3 * f + k];
          for (int c = 0; c < 3; ++c) {
            n[c] += b[k] * nrm[3 * v + c];
            q[c] += b[k] * p[3 * v + c];
            if (!textured) albedo[c] += float(b[k]) * col[3 * v + c];
          }
        }
        if (textured) {
          const double* uv = uvs.data_ptr<double>();
          const int64_t* fu = face_uvs.data_ptr<int64_t>();
          double u = 0, v = 0;
          for (int k = 0; k < 3; ++k) {
            u += b[k] * uv[2 * fu[3 * f + k]];
            v += b[k] * uv[2 * fu[3 * f + k] + 1];
          }
          sample_bilinear(texture.data_ptr<float>(), texture.size(0), texture.size(1), u, v, albedo);
        }
        const double n_len = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        const double q_len = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2]);
        const double cosine = n_len > 0 && q_len > 0 ? std::abs(n[0] * q[0] + n[1] * q[1] + n[2] * q[2]) / (n_len * q_len) : 1.0;
        const double light = shading.ambient + shading.diffuse * cosine;
        for (int c = 0; c < 3; ++c) img[pix * 3 + c] = float(std::min(1.0, albedo[c] * light));
      }
  });
  out.mask = (face_index >= 0).to(at::kFloat);
  out.depth = depth;
  out.face = face_index;
  return out;
}

}  // namespace sfgs::data
