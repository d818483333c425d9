#include "test_avatar_utils.h"

#include <string>

#include <ATen/CPUGeneratorImpl.h>
#include <ATen/Functions.h>
#include <ATen/TensorOperators.h>
#include <gtest/gtest.h>
#include <torch/csrc/autograd/grad_mode.h>

#include "body/skeleton.h"
#include "test_body_utils.h"

namespace sfgs::testing {

const model::AvatarBody& procedural_avatar_body() {
  static const model::AvatarBody body = [] {
    const body::ProceduralBody& p = procedural_body();
    model::AvatarBody b;
    b.smplx = p.smplx;
    b.has_mano = true;
    b.mano_left = p.mano_left;
    b.mano_right = p.mano_right;
    b.hand_vertex_ids = p.hand_vertex_ids;
    b.face_vertex_ids = p.face_vertex_ids;
    return b;
  }();
  return body;
}

at::Tensor subject_betas() { return at::tensor({0.8, -0.5, 0.3, 0.6, -0.2, 0.1, 0.4, -0.3, 0.2, -0.1}, at::kFloat); }

model::AvatarConfig small_config() {
  model::AvatarConfig c;
  c.subdivision_levels = 0;
  c.plane_channels = 4;
  c.plane_resolution = 16;
  c.time_resolution = 4;
  c.face_plane_resolution = 16;
  c.hidden_width = 16;
  c.joint_embedding_size = 4;
  return c;
}

body::SmplxPose test_pose(int64_t seed, double angle, bool hands) {
  at::Generator generator = at::detail::createCPUGenerator(static_cast<uint64_t>(seed));
  const auto uniform = [&](at::IntArrayRef shape, double bound) {
    return at::empty(shape, at::kFloat).uniform_(-bound, bound, generator);
  };
  body::SmplxPose p;
  p.global_orient = uniform({3}, angle);
  p.body_pose = uniform({body::kSmplxBodyJointCount, 3}, angle);
  p.jaw_pose = uniform({3}, angle);
  p.leye_pose = uniform({3}, angle);
  p.reye_pose = uniform({3}, angle);
  if (hands) {
    p.left_hand_pose = uniform({body::kHandJointCount, 3}, angle);
    p.right_hand_pose = uniform({body::kHandJointCount, 3}, angle);
  }
  p.expression = uniform({10}, 1.0);
  p.transl = uniform({3}, 0.5);
  return p;
}

void randomise_parameters(model::AvatarImpl& avatar, double std, int64_t seed) {
  at::Generator generator = at::detail::createCPUGenerator(static_cast<uint64_t>(seed));
  at::NoGradGuard no_grad;
  for (auto& p : avatar.named_parameters()) {
    p.value().normal_(0.0, std, generator);
    // The shared light (model/shading.h) gets a constant share of 1, as it starts: random coefficients around 0
    // would darken most colours to nothing and hide what the other modules do to them.
    if (p.key() == "shading.coefficients") p.value()[0] += 1.0;
  }
}

void copy_parameters(const model::AvatarImpl& from, model::AvatarImpl& to) {
  const auto source = from.named_parameters();
  at::NoGradGuard no_grad;
  for (auto& p : to.named_parameters()) {
    const at::Tensor* match = source.find(p.key());
    ASSERT_NE(match, nullptr) << p.key();
    p.value().copy_(*match);
  }
}

double max_abs_difference(const at::Tensor& a, const at::Tensor& b) { return (a - b).abs().max().item<double>(); }

}  // namespace sfgs::testing
