#include "body/procedural/eyes.h"

#include <array>

#include <ATen/Functions.h>
#include <ATen/TensorOperators.h>

namespace sfgs::body::procedural {
namespace {

constexpr double kEyeRadius = 0.0115;
constexpr double kEyeHeight = 1.632;  // above the floor
constexpr double kEyeHalfSpacing = 0.033;
// The eye socket is found among the body vertices within this distance (metres) of the eye's x and height.
constexpr double kSocketSearchDistance = 0.01;
// The eyeball's centre sits this many radii behind the frontmost surface of the socket.
constexpr double kEyeSinkRadii = 0.8;

// A cube of side 2 kEyeRadius around the left eye's centre, mirrored to the right, each with its own chart.
Cage eye_cubes(const Vec3& centre) {
  Cage cage;
  for (int side : {1, -1}) {
    const int64_t chart = cage.chart(side, {true, centre, {0, 1, 0}, {0, 0, 1}, {1, 0, 0}});
    const JointWeights w = {{J::kLeftEye, 1}};
    std::array<int64_t, 8> corner;
    for (int i = 0; i < 8; ++i) {
      const Vec3 offset = {i & 1 ? 1.0 : -1.0, i & 2 ? 1.0 : -1.0, i & 4 ? 1.0 : -1.0};
      corner[i] = cage.add(side, centre + kEyeRadius * offset, w);
    }
    for (const auto& quad : std::vector<std::array<int, 4>>{
             {0, 1, 3, 2}, {4, 6, 7, 5}, {0, 4, 5, 1}, {2, 3, 7, 6}, {0, 2, 6, 4}, {1, 5, 7, 3}})
      cage.face({corner[quad[0]], corner[quad[1]], corner[quad[2]], corner[quad[3]]}, chart);
  }
  return cage;
}

}  // namespace

Smoothed make_eyes(const at::Tensor& body, std::vector<Chart>& charts) {
  const double y_eye = kEyeHeight + kFloorY;
  const at::Tensor x = body.select(1, 0), y = body.select(1, 1), z = body.select(1, 2);
  const at::Tensor near =
      ((x - kEyeHalfSpacing).abs() < kSocketSearchDistance) & ((y - y_eye).abs() < kSocketSearchDistance) & (z > 0);
  const double surface = z.masked_select(near).max().item<double>();
  const Vec3 centre = {kEyeHalfSpacing, y_eye, surface - kEyeSinkRadii * kEyeRadius};
  const Cage cage = eye_cubes(centre);
  charts = cage.charts();
  Smoothed eyes = smooth(cage);
  // Each smoothed vertex is pushed onto the sphere around its own eye's centre.
  const at::Tensor side = (eyes.positions.select(1, 0) > 0).to(at::kDouble).unsqueeze(1) * 2 - 1;
  const at::Tensor c = at::tensor(std::vector<double>{centre[0], centre[1], centre[2]}, at::kDouble).unsqueeze(0) *
                       at::cat({side, at::ones_like(side), at::ones_like(side)}, 1);
  const at::Tensor d = eyes.positions - c;
  eyes.positions = c + kEyeRadius * d / d.norm(2, 1, /*keepdim=*/true);
  return eyes;
}

}  // namespace sfgs::body::procedural
