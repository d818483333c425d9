#pragma once
// The procedural body's UV layout: every triangle unwrapped in its chart (cylinders by angle and height, planes by
// projection), the charts shelf-packed into the unit square at one common scale.
#include <cstdint>
#include <vector>

#include <ATen/core/Tensor.h>

#include "body/procedural/cage.h"

namespace sfgs::body::procedural {

struct UvLayout {
  at::Tensor uvs;       // (T, 2) float64 in [0, 1]
  at::Tensor uv_faces;  // (F, 3) int64 rows of uvs per triangle corner
};

// UVs for the triangles `faces` (F, 3) of the mesh at `positions` (V, 3); face_charts[t] indexes `charts`.
// A vertex gets one UV row per chart it lies in, and more where a cylinder's seam or axis passes through it.
UvLayout make_uvs(const at::Tensor& positions, const at::Tensor& faces, const std::vector<int64_t>& face_charts,
                  const std::vector<Chart>& charts);

}  // namespace sfgs::body::procedural
