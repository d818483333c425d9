// The ground-truth triangle rasteriser on scenes with exact answers: pixel coverage of a square (top-left rule),
// a cube's silhouette, and perspective-correct texturing of a tilted quad.
#include <cmath>

#include <gtest/gtest.h>

#include "data/mesh_renderer.h"

namespace sfgs::data {
namespace {

constexpr int kTexels = 64;

// A texture whose bilinear samples equal (u, v, 0.5) wherever the sample is not clamped at the border.
at::Tensor uv_texture() {
  const at::Tensor u = (at::arange(kTexels, at::kFloat) + 0.5f) / kTexels;
  const at::Tensor v = 1.0f - (at::arange(kTexels, at::kFloat) + 0.5f) / kTexels;
  return at::stack({u.unsqueeze(0).expand({kTexels, kTexels}), v.unsqueeze(1).expand({kTexels, kTexels}),
                    at::full({kTexels, kTexels}, 0.5f)},
                   2)
      .contiguous();
}

// Unit square in the plane through `centre`, spanned by `right` and `down`, textured u along right, v against down.
TexturedMesh textured_square(at::Tensor centre, at::Tensor right, at::Tensor down) {
  TexturedMesh m;
  m.vertices = at::stack({centre - 0.5 * right - 0.5 * down, centre + 0.5 * right - 0.5 * down,
                          centre + 0.5 * right + 0.5 * down, centre - 0.5 * right + 0.5 * down});
  m.faces = at::tensor({0, 1, 2, 0, 2, 3}, at::kLong).view({2, 3});
  m.uvs = at::tensor({0.0, 1.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0}, at::kDouble).view({4, 2});
  m.face_uvs = m.faces.clone();
  m.texture = uv_texture();
  return m;
}

MeshShading flat() {
  MeshShading s;
  s.ambient = 1.0;
  s.diffuse = 0.0;
  return s;
}

TEST(MeshRenderer, SquareCoversExactlyItsPixelCentres) {
  const Camera camera = Camera::looking_forward(40.0, 41, 41);  // the square spans x, y in [10.5, 30.5]
  const TexturedMesh square =
      textured_square(at::tensor({0.0, 0.0, 2.0}, at::kDouble), at::tensor({1.0, 0.0, 0.0}, at::kDouble),
                      at::tensor({0.0, 1.0, 0.0}, at::kDouble));
  const MeshImage r = render_mesh(square, camera, at::zeros({3}), flat());
  // Centres 10.5 .. 29.5 in each axis: the left/top edges through centres are included, right/bottom excluded, and
  // the diagonal shared by both triangles is covered once (no gap, no double count shows as face -1).
  EXPECT_EQ(r.mask.sum().item<double>(), 400.0);
  EXPECT_EQ(r.mask[10][10].item<float>(), 1.0f);
  EXPECT_EQ(r.mask[30][30].item<float>(), 0.0f);
  EXPECT_EQ(r.mask[9][15].item<float>(), 0.0f);
  EXPECT_NEAR(r.depth[20][20].item<float>(), 2.0f, 1e-6);
  // Texture: pixel centre x maps to u = (x + 0.5 - 10.5) / 20 (fronto-parallel: affine).
  for (int y = 12; y < 29; y += 4)
    for (int x = 12; x < 29; x += 4) {
      EXPECT_NEAR(r.image[y][x][0].item<float>(), (x + 0.5 - 10.5) / 20.0, 1e-5) << x << "," << y;
      EXPECT_NEAR(r.image[y][x][1].item<float>(), 1.0 - (y + 0.5 - 10.5) / 20.0, 1e-5) << x << "," << y;
    }
}

TEST(MeshRenderer, TiltedQuadIsTexturedPerspectiveCorrectly) {
  const double angle = 0.9;  // strong tilt about the vertical axis: affine interpolation would be visibly wrong
  const at::Tensor right = at::tensor({std::cos(angle), 0.0, std::sin(angle)}, at::kDouble);
  const at::Tensor centre = at::tensor({0.0, 0.0, 2.0}, at::kDouble);
  const Camera camera = Camera::looking_forward(60.0, 61, 61);
  const MeshImage r = render_mesh(textured_square(centre, right, at::tensor({0.0, 1.0, 0.0}, at::kDouble)), camera,
                                  at::zeros({3}), flat());
  int checked = 0;
  for (int y = 0; y < 61; ++y)
    for (int x = 0; x < 61; ++x) {
      if (r.mask[y][x].item<float>() == 0) continue;
      // Ray through the pixel centre meets the plane (p - centre) . normal = 0; u = (p - centre) . right + 0.5.
      const double dx = (x + 0.5 - camera.cx) / camera.fx, dy = (y + 0.5 - camera.cy) / camera.fy;
      const double nx = -std::sin(angle), nz = std::cos(angle);  // normal in the xz plane
      const double t = (2.0 * nz) / (dx * nx + nz);
      const double u = (t * dx) * std::cos(angle) + (t - 2.0) * std::sin(angle) + 0.5;
      if (u < 1.0 / kTexels || u > 1.0 - 1.0 / kTexels) continue;  // border texels are clamped
      EXPECT_NEAR(r.image[y][x][0].item<float>(), u, 2e-5) << x << "," << y;
      EXPECT_NEAR(r.depth[y][x].item<float>(), t, 1e-5);
      ++checked;
    }
  EXPECT_GT(checked, 200);
}

TEST(MeshRenderer, CubeSilhouetteIsItsFrontFace) {
  // Axis-aligned unit cube centred 4 m ahead: the silhouette is the front face, 100 * 0.5 / 3.5 px half-wide, whose
  // pixel centres 86.5 .. 113.5 give 28 x 28 covered pixels.
  const at::Tensor corners = at::tensor({-0.5, -0.5, 3.5, 0.5, -0.5, 3.5, 0.5, 0.5, 3.5, -0.5, 0.5, 3.5,
                                         -0.5, -0.5, 4.5, 0.5, -0.5, 4.5, 0.5, 0.5, 4.5, -0.5, 0.5, 4.5},
                                        at::kDouble)
                                 .view({8, 3});
  TexturedMesh cube;
  cube.vertices = corners;
  cube.faces = at::tensor({0, 1, 2, 0, 2, 3, 4, 6, 5, 4, 7, 6, 0, 4, 5, 0, 5, 1,
                           1, 5, 6, 1, 6, 2, 2, 6, 7, 2, 7, 3, 3, 7, 4, 3, 4, 0},
                          at::kLong)
                   .view({12, 3});
  const MeshImage r = render_mesh(cube, Camera::looking_forward(100.0, 200, 200), at::ones({3}));
  EXPECT_EQ(r.mask.sum().item<double>(), 28.0 * 28.0);
  EXPECT_LE((r.depth.masked_select(r.mask > 0) - 3.5).abs().max().item<float>(), 1e-5f);
  EXPECT_TRUE(r.face.masked_select(r.mask > 0).lt(2).all().item<bool>()) << "only the two front triangles show";
  EXPECT_EQ(r.image[0][0][0].item<float>(), 1.0f) << "background";
}

TEST(MeshRenderer, BadMeshesAreErrors) {
  TexturedMesh m;
  m.vertices = at::zeros({3, 3});
  m.faces = at::tensor({0, 1, 3}, at::kLong).view({1, 3});
  EXPECT_THROW(render_mesh(m, Camera::looking_forward(10, 8, 8), at::zeros({3})), c10::Error);
  m.faces = at::tensor({0.0, 1.0, 2.0}).view({1, 3});
  EXPECT_THROW(render_mesh(m, Camera::looking_forward(10, 8, 8), at::zeros({3})), c10::Error);
}

}  // namespace
}  // namespace sfgs::data
