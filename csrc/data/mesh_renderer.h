#pragma once
// A CPU triangle rasteriser for ground-truth synthetic videos: z-buffer, perspective-correct UV texturing and
// Lambertian shading. It is deliberately independent of the Gaussian splatting op, so an avatar is never judged by
// the renderer it was trained with.
#include <array>

#include <ATen/core/Tensor.h>

#include "ops/splat/splat.h"

namespace sfgs::data {

struct TexturedMesh {
  at::Tensor vertices;        // (V, 3) world positions, float32 or float64
  at::Tensor faces;           // (F, 3) int64 vertex indices
  at::Tensor uvs;             // (T, 2) texture coordinates, v pointing up (OBJ convention); may be undefined
  at::Tensor face_uvs;        // (F, 3) int64 indices into uvs (seams have their own uv rows); with uvs
  at::Tensor texture;         // (Ht, Wt, 3) float in [0, 1]; with uvs
  at::Tensor vertex_colours;  // (V, 3) used when there is no texture; may be undefined (then grey)
};

struct MeshShading {
  double ambient = 0.35;  // share of light that reaches every surface
  double diffuse = 0.65;  // share of the directional light, scaled by the cosine below
  // Where the directional light comes from. Zero: a head light at the camera, scaled by |cos| of the normal to the
  // view ray (either side of the surface). Otherwise a key light fixed in the world (this direction towards the
  // light, world coordinates, any length): scaled by the cosine to the outward normal (0 facing away) and shadowed
  // by the mesh itself through a shadow map, so the shading changes with the pose and is not part of the albedo.
  std::array<double, 3> key_light{0, 0, 0};
};

struct MeshImage {
  at::Tensor image;  // (H, W, 3) float32 shaded colour, background where uncovered
  at::Tensor mask;   // (H, W) float32: 1 where a triangle covers the pixel centre
  at::Tensor depth;  // (H, W) float32 camera-space z of the visible surface, 0 where uncovered
  at::Tensor face;   // (H, W) int64 index of the visible face, -1 where uncovered
};

// Rasterises the mesh at pixel centres (i + 0.5, j + 0.5) with the top-left fill rule, so meshes that share edges
// cover each pixel exactly once. Triangles with a vertex in front of the near plane are skipped.
MeshImage render_mesh(const TexturedMesh& mesh, const Camera& camera, const at::Tensor& background,
                      const MeshShading& shading = {});

}  // namespace sfgs::data
