// The key light of the ground-truth renderer: Lambertian on the outward normal, fixed in the world, and shadows
// cast by the mesh on itself, on a scene whose shadow can be worked out by hand.
#include <cmath>

#include <gtest/gtest.h>

#include "data/mesh_renderer.h"

namespace sfgs::data {
namespace {

constexpr float kAlbedo = 0.8f;

// Two axis-aligned quads facing +z (towards the camera): a large one at z = 0 and a small one in front of it at
// z = 0.5, over x in [0.2, 0.6], y in [-0.2, 0.2].
TexturedMesh two_quads() {
  const auto quad = [](double x0, double x1, double y0, double y1, double z) {
    return std::vector<double>{x0, y0, z, x1, y0, z, x1, y1, z, x0, y1, z};
  };
  std::vector<double> v = quad(-1, 1, -1, 1, 0);
  const std::vector<double> front = quad(0.2, 0.6, -0.2, 0.2, 0.5);
  v.insert(v.end(), front.begin(), front.end());
  TexturedMesh m;
  m.vertices = at::tensor(v, at::kDouble).view({8, 3});
  // Counter-clockwise seen from +z: outward normals point at the camera.
  m.faces = at::tensor({0, 1, 2, 0, 2, 3, 4, 5, 6, 4, 6, 7}, at::kLong).view({4, 3});
  m.vertex_colours = at::full({8, 3}, kAlbedo);
  return m;
}

// At (0, 0, 5) looking down -z: x right, y down in the image.
Camera camera_in_front() {
  Camera c = Camera::looking_forward(200.0, 200, 200);
  c.world_to_camera = {1, 0, 0, 0, 0, -1, 0, 0, 0, 0, -1, 5, 0, 0, 0, 1};
  return c;
}

// The rendered value at world point (x, y, 0) on the back quad.
float value_at(const MeshImage& image, const Camera& c, double x, double y) {
  const int64_t col = int64_t(std::floor(c.fx * x / 5.0 + c.cx));
  const int64_t row = int64_t(std::floor(c.fy * -y / 5.0 + c.cy));
  return image.image[row][col][0].item<float>();
}

TEST(MeshRenderer, KeyLightShadesByTheOutwardNormalAndCastsShadows) {
  const TexturedMesh mesh = two_quads();
  const Camera camera = camera_in_front();
  MeshShading shading;
  shading.key_light = {1.0, 0.0, 1.0};  // 45 degrees from +x and +z
  const MeshImage lit = render_mesh(mesh, camera, at::ones({3}), shading);
  const double cosine = std::sqrt(0.5);
  // Towards the light from (x, 0, 0) the ray meets z = 0.5 at x + 0.5: points with x in [-0.3, 0.1] lie in the
  // small quad's shadow; x = -0.7 is lit.
  EXPECT_NEAR(value_at(lit, camera, -0.7, 0.0), kAlbedo * (shading.ambient + shading.diffuse * cosine), 1e-4);
  EXPECT_NEAR(value_at(lit, camera, -0.1, 0.0), kAlbedo * shading.ambient, 1e-4) << "in the cast shadow";
  EXPECT_NEAR(value_at(lit, camera, -0.1, 0.5), kAlbedo * (shading.ambient + shading.diffuse * cosine), 1e-4)
      << "beside the shadow";
  // A light behind the surface leaves only the ambient share.
  shading.key_light = {0.0, 0.0, -1.0};
  const MeshImage behind = render_mesh(mesh, camera, at::ones({3}), shading);
  EXPECT_NEAR(value_at(behind, camera, -0.7, 0.0), kAlbedo * shading.ambient, 1e-4);
  // The head light (no key light) has no shadows: both points alike.
  const MeshImage head = render_mesh(mesh, camera, at::ones({3}), MeshShading{});
  EXPECT_NEAR(value_at(head, camera, -0.1, 0.0), value_at(head, camera, -0.7, 0.0), 1e-2);
}

TEST(MeshRenderer, NonFiniteKeyLightIsAnError) {
  MeshShading shading;
  shading.key_light = {NAN, 1.0, 0.0};
  EXPECT_THROW(render_mesh(two_quads(), camera_in_front(), at::ones({3}), shading), c10::Error);
}

}  // namespace
}  // namespace sfgs::data
