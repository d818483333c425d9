// The dispatcher operator sfgs::render_gaussians (csrc/ops/splat/op.h): its kernels, one autograd node per render, the
// Meta kernel's description of the outputs, and inputs the op prepares itself (non-contiguous, (N, 1) opacities).
#include <string>

#include <ATen/core/dispatch/Dispatcher.h>
#include <c10/core/InferenceMode.h>
#include <gtest/gtest.h>
#include <torch/csrc/autograd/autograd.h>
#include <torch/csrc/autograd/function.h>

#include "op_check.h"
#include "splat_test_utils.h"
#include "ops/splat/constants.h"

namespace sfgs::testing {
namespace {

c10::OperatorHandle render_gaussians_op() { return registered_op("sfgs::render_gaussians"); }

// A CUDA kernel only in a build with the CUDA backend.
TEST(SplatOp, HasCpuMetaAndAutogradKernelsAndCudaWhereBuilt) { expect_backend_kernels("sfgs::render_gaussians", true); }

std::vector<at::Tensor> with_grad(TestScene& s) {
  std::vector<at::Tensor> leaves;
  for (auto& [name, t] : differentiable_inputs(s)) {
    *t = t->detach().requires_grad_(true);
    leaves.push_back(*t);
  }
  return leaves;
}

// render() adds no autograd node of its own: every output hangs off the op's node, whose inputs are the leaves.
TEST(SplatOp, RenderIsOneAutogradNode) {
  TestScene s = random_scene(SceneSpec{}, 4);
  const std::vector<at::Tensor> leaves = with_grad(s);
  const RenderResult r = render(s.gaussians, s.background, s.camera);
  const auto node = r.image.grad_fn();
  ASSERT_NE(node, nullptr);
  EXPECT_EQ(r.alpha.grad_fn(), node);
  EXPECT_EQ(r.depth.grad_fn(), node);
  EXPECT_EQ(r.radii.grad_fn(), nullptr);
  size_t leaf_edges = 0;
  for (const torch::autograd::Edge& edge : node->next_edges()) {
    if (!edge.is_valid()) continue;
    EXPECT_NE(edge.function->name().find("AccumulateGrad"), std::string::npos) << edge.function->name();
    ++leaf_edges;
  }
  EXPECT_EQ(leaf_edges, leaves.size());
}

// The Meta kernel checks the arguments and describes the outputs without computing them (tracing with fake tensors).
TEST(SplatOp, MetaKernelDescribesTheOutputs) {
  TestScene s = random_scene(SceneSpec{}, 5);
  const auto meta = [](const at::Tensor& t) { return t.to(at::kMeta); };
  const Camera& c = s.camera;
  const auto call = [&](const at::Tensor& background) {
    return render_gaussians_op()
        .typed<std::tuple<at::Tensor, at::Tensor, at::Tensor, at::Tensor>(
            const at::Tensor&, const c10::optional<at::Tensor>&, const c10::optional<at::Tensor>&,
            const c10::optional<at::Tensor>&, const at::Tensor&, const at::Tensor&, const at::Tensor&,
            c10::ArrayRef<double>, double, double, double, double, int64_t, int64_t, double, double, double, bool,
            bool)>()
        .call(meta(s.gaussians.means), meta(s.gaussians.scales), meta(s.gaussians.rotations), c10::nullopt,
              meta(s.gaussians.opacities), meta(s.gaussians.features), background, c.world_to_camera, c.fx, c.fy, c.cx,
              c.cy, c.width, c.height, c.near_plane, c.far_plane, kLowPassVariancePx2, false, false);
  };
  const auto [image, alpha, depth, radii] = call(meta(s.background));
  EXPECT_TRUE(image.is_meta());
  EXPECT_EQ(image.sizes(), at::IntArrayRef({29, 37, 3}));
  EXPECT_EQ(alpha.sizes(), at::IntArrayRef({29, 37}));
  EXPECT_EQ(depth.sizes(), at::IntArrayRef({29, 37}));
  EXPECT_EQ(radii.sizes(), at::IntArrayRef({10, 2}));
  EXPECT_EQ(image.scalar_type(), at::kDouble);
  EXPECT_EQ(radii.scalar_type(), at::kInt);
  EXPECT_THROW(call(meta(s.background.narrow(0, 0, 2))), c10::Error);
}

// Below autograd (inference mode) the CPU kernel runs alone and renders the same image.
TEST(SplatOp, InferenceModeRendersTheSameImage) {
  const TestScene s = random_scene(SceneSpec{}, 6);
  const RenderResult expected = render(s.gaussians, s.background, s.camera);
  const c10::InferenceMode inference;
  const RenderResult r = render(s.gaussians, s.background, s.camera);
  EXPECT_TRUE(at::equal(r.image, expected.image));
  EXPECT_TRUE(at::equal(r.depth, expected.depth));
  EXPECT_TRUE(at::equal(r.radii, expected.radii));
}

// The op makes its inputs contiguous and takes (N, 1) opacities itself; their gradients come back in their shapes,
// bit-identical to those of contiguous (N) inputs.
TEST(SplatOp, NonContiguousInputsAndColumnOpacities) {
  TestScene plain = random_scene(SceneSpec{}, 7);
  TestScene strided = plain;
  strided.gaussians.means = plain.gaussians.means.t().contiguous().t();
  strided.gaussians.opacities = plain.gaussians.opacities.unsqueeze(1);
  const std::vector<at::Tensor> plain_leaves = with_grad(plain), strided_leaves = with_grad(strided);
  ASSERT_FALSE(strided.gaussians.means.is_contiguous());
  const LossWeights w = random_weights(plain.camera.height, plain.camera.width, 3, 8, at::kDouble);
  const auto grads = [&](TestScene& s, const std::vector<at::Tensor>& leaves) {
    const RenderResult r = render(s.gaussians, s.background, s.camera);
    return torch::autograd::grad({weighted_loss(r.image, r.alpha, r.depth, w)}, leaves);
  };
  const std::vector<at::Tensor> expected = grads(plain, plain_leaves), got = grads(strided, strided_leaves);
  ASSERT_EQ(expected.size(), got.size());
  for (size_t i = 0; i < got.size(); ++i) {
    EXPECT_EQ(got[i].sizes(), strided_leaves[i].sizes());
    EXPECT_TRUE(at::equal(got[i].reshape(expected[i].sizes()), expected[i])) << "input " << i;
  }
}

}  // namespace
}  // namespace sfgs::testing
