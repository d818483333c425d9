#pragma once
// Light fixed in the world. Under lighting that does not move, the light a matte surface point receives depends on
// its world normal (and on what shadows it); as a function of the normal it is smooth, within a few percent a
// quadratic one (the nine second-order spherical harmonics; Ramamoorthi and Hanrahan, "An Efficient Representation
// for Irradiance Environment Maps", 2001). The avatar learns shading-free colours (albedo) and multiplies them by
// this one function of the posed normal, shared by every Gaussian: a new pose that turns a surface towards or away
// from the light then gets the light training saw on surfaces of that orientation, where per-Gaussian colours would
// repeat the light of the training poses. docs/avatar.md, "Shading".
#include <cstdint>

#include <torch/nn/module.h>
#include <torch/nn/pimpl.h>

namespace sfgs::model {

class ShadingImpl : public torch::nn::Module {
 public:
  static constexpr int64_t kBasisSize = 9;  // spherical harmonics of order 0, 1 and 2

  // Starts as no shading: a factor of 1 for every normal.
  ShadingImpl();

  // normals (N, 3), unit length, world coordinates -> (N, 3) non-negative factor per colour channel.
  at::Tensor forward(const at::Tensor& normals) const;

  // (N, 3) unit normals -> (N, 9) the basis: 1, y, z, x, xy, yz, 3z^2 - 1, xz, x^2 - y^2 (unnormalised: the
  // coefficients absorb the constants).
  static at::Tensor basis(const at::Tensor& normals);

  const at::Tensor& coefficients() const { return coefficients_; }  // (9, 3) over the basis, per colour channel

 private:
  at::Tensor coefficients_;  // (9, 3)
};
TORCH_MODULE(Shading);

}  // namespace sfgs::model
