#pragma once
// The procedural body's eyeballs: two spheres in the eye sockets, skinned to the eye joints.
#include <vector>

#include <ATen/core/Tensor.h>

#include "body/procedural/cage.h"
#include "body/procedural/catmull_clark.h"

namespace sfgs::body::procedural {

// Two eyeballs: cubes smoothed like the body, then projected onto spheres that sit in the eye sockets of the
// smoothed body surface `body` (V, 3). `charts` receives their UV charts, numbered from 0.
Smoothed make_eyes(const at::Tensor& body, std::vector<Chart>& charts);

}  // namespace sfgs::body::procedural
