// The dispatcher operator sfgs::render_gaussians (op.h): its schema, its CPU, CUDA and Meta kernels, and its
// Autograd kernel, the op's one autograd node, which redispatches below autograd for the forward pass.
//
// The schema returns only the four outputs, so that the Meta kernel can describe everything the op returns (its
// shapes follow from the arguments) and tracing with fake tensors works. What backward needs besides the inputs and
// outputs is the backend's typed ForwardContext: intersection lists whose sizes depend on the data. The backend
// kernel hands it to the Autograd kernel that redispatched to it through a ContextCapture, a slot that kernel opens
// on its own thread around the call; the node keeps it in its saved data as a capsule.
#include "ops/splat/op.h"

#include <algorithm>
#include <type_traits>
#include <utility>
#include <variant>
#include <vector>

#include <ATen/ATen.h>
#include <ATen/core/dispatch/Dispatcher.h>
#include <torch/csrc/autograd/custom_function.h>
#include <torch/library.h>

#include "common/tensor_description.h"
#include "ops/registration.h"
#include "ops/splat/validation.h"
#include "ops/splat/constants.h"

namespace sfgs::splat {
namespace {

using ops::optional_tensor;
using ops::OptionalTensor;
using torch::autograd::AutogradContext;
using torch::autograd::variable_list;

// Every kernel of the op has the schema's parameters, in its order.
#define SFGS_OP_PARAMETERS                                                                                             \
  const at::Tensor &means, const OptionalTensor &scales, const OptionalTensor &rotations,                              \
      const OptionalTensor &covariances, const at::Tensor &opacities, const at::Tensor &features,                      \
      const at::Tensor &background, c10::ArrayRef<double> world_to_camera, double fx, double fy, double cx, double cy, \
      int64_t width, int64_t height, double near_plane, double far_plane, double low_pass_variance, bool antialiased,  \
      bool deterministic
#define SFGS_OP_NON_TENSOR_ARGUMENTS \
  world_to_camera, fx, fy, cx, cy, width, height, near_plane, far_plane, low_pass_variance, antialiased, deterministic

constexpr const char* kSchema =
    "render_gaussians(Tensor means, Tensor? scales, Tensor? rotations, Tensor? covariances, Tensor opacities, "
    "Tensor features, Tensor background, float[] world_to_camera, float fx, float fy, float cx, float cy, int width, "
    "int height, float near_plane, float far_plane, float low_pass_variance, bool antialiased, bool deterministic) "
    "-> (Tensor image, Tensor alpha, Tensor depth, Tensor radii)";

// The op's arguments, checked (validation.h) and in the backends' types.
struct Arguments {
  SplatInputs inputs;
  Camera camera;
  BackendSettings settings;
};

Arguments checked_arguments(SFGS_OP_PARAMETERS, bool on_backend_device) {
  TORCH_CHECK(world_to_camera.size() == 16,
              "sfgs::render: world_to_camera must have 16 entries (row-major 4 x 4), got ", world_to_camera.size());
  Arguments a;
  std::copy(world_to_camera.begin(), world_to_camera.end(), a.camera.world_to_camera.begin());
  a.camera.fx = fx;
  a.camera.fy = fy;
  a.camera.cx = cx;
  a.camera.cy = cy;
  a.camera.width = width;
  a.camera.height = height;
  a.camera.near_plane = near_plane;
  a.camera.far_plane = far_plane;
  check_camera(a.camera);
  a.inputs = validated_inputs(SplatInputs{means, scales.value_or(at::Tensor()), rotations.value_or(at::Tensor()),
                                          covariances.value_or(at::Tensor()), opacities, features, background},
                              on_backend_device);
  a.settings = BackendSettings{ProjectionSettings{low_pass_variance, antialiased}, deterministic};
  return a;
}

RenderOutputs as_tuple(const ForwardOutputs& out) { return {out.image, out.alpha, out.depth, out.radii}; }

// What the autograd node keeps besides the tensors it saves for backward.
struct SavedState : torch::CustomClassHolder {
  Camera camera;
  BackendSettings settings;
  std::variant<cpu::ForwardContext, cuda::ForwardContext> backend;

  template <typename Context>
  SavedState(const Arguments& a, Context&& context)
      : camera(a.camera), settings(a.settings), backend(std::forward<Context>(context)) {}
};

// Opened by the Autograd kernel around its redispatch; the backend kernel below offers its context, and the innermost
// open capture keeps the first offer. Without an open capture (a call below autograd from elsewhere, or inference)
// the context is dropped with the call.
class ContextCapture {
 public:
  ContextCapture() : outer_(innermost_) { innermost_ = this; }
  ~ContextCapture() { innermost_ = outer_; }
  ContextCapture(const ContextCapture&) = delete;
  ContextCapture& operator=(const ContextCapture&) = delete;

  template <typename Context> static void offer(const Arguments& a, Context&& context) {
    if (innermost_ != nullptr && !innermost_->state_)
      innermost_->state_ = c10::make_intrusive<SavedState>(a, std::forward<Context>(context));
  }
  // Null when no backend kernel ran (a forward on meta or fake tensors).
  c10::intrusive_ptr<SavedState> take() { return std::move(state_); }

 private:
  static thread_local ContextCapture* innermost_;
  ContextCapture* outer_;
  c10::intrusive_ptr<SavedState> state_;
};
thread_local ContextCapture* ContextCapture::innermost_ = nullptr;

// Opened by render_gaussians around its call: the CUDA kernel below the dispatcher reads the caller's budget from it.
// Nested calls (none today) would each see their own.
class BudgetScope {
 public:
  explicit BudgetScope(const BinningBudget* budget) : outer_(current_) { current_ = budget; }
  ~BudgetScope() { current_ = outer_; }
  BudgetScope(const BudgetScope&) = delete;
  BudgetScope& operator=(const BudgetScope&) = delete;
  static const BinningBudget* current() { return current_; }

 private:
  static thread_local const BinningBudget* current_;
  const BinningBudget* outer_;
};
thread_local const BinningBudget* BudgetScope::current_ = nullptr;

void check_budget(const BinningBudget& budget) {
  TORCH_CHECK(budget.intersections >= 0 && budget.longest_tile >= 0,
              "sfgs::render: the binning budget must be non-negative, got ", budget.intersections,
              " intersections and a longest tile of ", budget.longest_tile);
  TORCH_CHECK(budget.counts.defined() && budget.counts.is_cuda() && budget.counts.scalar_type() == at::kLong &&
                  budget.counts.is_contiguous() && budget.counts.numel() == BinningBudget::kCounts,
              "sfgs::render: the binning budget's counts must be a contiguous CUDA int64 tensor of ",
              BinningBudget::kCounts, " values, got ", describe(budget.counts));
}

RenderOutputs cpu_kernel(SFGS_OP_PARAMETERS) {
  const Arguments a = checked_arguments(means, scales, rotations, covariances, opacities, features, background,
                                        SFGS_OP_NON_TENSOR_ARGUMENTS, true);
  cpu::Forward f = cpu::forward(a.inputs, a.camera, a.settings);
  ContextCapture::offer(a, std::move(f.context));
  return as_tuple(f.outputs);
}

#if defined(SFGS_WITH_CUDA)
RenderOutputs cuda_kernel(SFGS_OP_PARAMETERS) {
  const Arguments a = checked_arguments(means, scales, rotations, covariances, opacities, features, background,
                                        SFGS_OP_NON_TENSOR_ARGUMENTS, true);
  cuda::Forward f = cuda::forward(a.inputs, a.camera, a.settings, BudgetScope::current());
  ContextCapture::offer(a, std::move(f.context));
  return as_tuple(f.outputs);
}
#endif

RenderOutputs meta_kernel(SFGS_OP_PARAMETERS) {
  const Arguments a = checked_arguments(means, scales, rotations, covariances, opacities, features, background,
                                        SFGS_OP_NON_TENSOR_ARGUMENTS, false);
  const at::TensorOptions real = a.inputs.means.options();
  const int64_t h = a.camera.height, w = a.camera.width;
  return {at::empty({h, w, a.inputs.features.size(1)}, real), at::empty({h, w}, real), at::empty({h, w}, real),
          at::empty({a.inputs.means.size(0), 2}, real.dtype(at::kInt))};
}

const c10::TypedOperatorHandle<RenderOutputs(SFGS_OP_PARAMETERS)>& op() {
  static const auto handle = c10::Dispatcher::singleton()
                                 .findSchemaOrThrow("sfgs::render_gaussians", "")
                                 .typed<RenderOutputs(SFGS_OP_PARAMETERS)>();
  return handle;
}

// The schema's non-tensor arguments, as the autograd node passes them on to the redispatch.
struct NonTensorArguments {
  std::vector<double> world_to_camera;
  double fx, fy, cx, cy;
  int64_t width, height;
  double near_plane, far_plane, low_pass_variance;
  bool antialiased, deterministic;
};

// The tensors the node saves for backward (version-checked): the differentiable inputs as given, and the outputs.
struct SavedTensors {
  SplatInputs inputs;
  at::Tensor image, alpha, depth;

  variable_list list() const {
    return {inputs.means,
            inputs.scales,
            inputs.rotations,
            inputs.covariances,
            inputs.opacities,
            inputs.features,
            inputs.background,
            image,
            alpha,
            depth};
  }
  static SavedTensors from(const variable_list& v) {
    return SavedTensors{SplatInputs{v[0], v[1], v[2], v[3], v[4], v[5], v[6]}, v[7], v[8], v[9]};
  }
};

constexpr const char* kStateKey = "state";

class SplatFunction : public torch::autograd::Function<SplatFunction> {
 public:
  // The unused parameterisation arrives as nullopt: autograd then treats it as a non-tensor argument.
  static variable_list forward(AutogradContext* ctx, const at::Tensor& means, const OptionalTensor& scales,
                               const OptionalTensor& rotations, const OptionalTensor& covariances,
                               const at::Tensor& opacities, const at::Tensor& features, const at::Tensor& background,
                               const NonTensorArguments& a) {
    ContextCapture capture;
    RenderOutputs out;
    {
      const at::AutoDispatchBelowADInplaceOrView below_autograd;
      out = op().call(means, scales, rotations, covariances, opacities, features, background, a.world_to_camera, a.fx,
                      a.fy, a.cx, a.cy, a.width, a.height, a.near_plane, a.far_plane, a.low_pass_variance,
                      a.antialiased, a.deterministic);
    }
    const auto& [image, alpha, depth, radii] = out;
    const SavedTensors saved{SplatInputs{means, scales.value_or(at::Tensor()), rotations.value_or(at::Tensor()),
                                         covariances.value_or(at::Tensor()), opacities, features, background},
                             image, alpha, depth};
    ctx->save_for_backward(saved.list());
    if (c10::intrusive_ptr<SavedState> state = capture.take())
      ctx->saved_data[kStateKey] = c10::IValue::make_capsule(std::move(state));
    ctx->mark_non_differentiable({radii});
    // Outputs nobody differentiates (often depth and alpha) arrive as undefined gradients, not zero-filled tensors.
    ctx->set_materialize_grads(false);
    return {image, alpha, depth, radii};
  }

  static variable_list backward(AutogradContext* ctx, variable_list grad_outputs) {
    TORCH_CHECK(ctx->saved_data.count(kStateKey) > 0,
                "sfgs::render: backward needs the intersection lists of a forward pass that ran on the CPU or CUDA "
                "backend; this graph's forward ran on meta or fake tensors");
    const c10::intrusive_ptr<torch::CustomClassHolder> holder = ctx->saved_data[kStateKey].toCapsule();
    const SavedState& state = static_cast<const SavedState&>(*holder);
    const SavedTensors saved = SavedTensors::from(ctx->get_saved_variables());
    const SplatInputs in = validated_inputs(saved.inputs, true);
    OutputGradients grads{grad_outputs[0], grad_outputs[1], at::Tensor()};
    if (grad_outputs[2].defined()) {
      // depth = depth_sum / alpha where alpha > 0: d/d depth_sum = 1 / alpha, d/d alpha = -depth / alpha.
      const at::Tensor per_alpha =
          at::where(saved.alpha > 0, grad_outputs[2] / saved.alpha.clamp_min(kMinAlpha), at::zeros_like(saved.alpha));
      grads.depth_sum = per_alpha;
      grads.alpha = grads.alpha.defined() ? grads.alpha - per_alpha * saved.depth : -per_alpha * saved.depth;
    }
    const InputGradients g = std::visit(
        [&](const auto& context) -> InputGradients {
          if constexpr (std::is_same_v<std::decay_t<decltype(context)>, cpu::ForwardContext>) {
            return cpu::backward(in, state.camera, state.settings, context, grads);
          } else {
#if defined(SFGS_WITH_CUDA)
            return cuda::backward(in, state.camera, state.settings, saved.image, context, grads);
#else
            TORCH_CHECK(false, "sfgs::render: a CUDA forward context in a build without CUDA");
#endif
          }
        },
        state.backend);
    // Opacities may have come as (N, 1).
    return {g.means,    g.scales,     g.rotations, g.covariances, g.opacities.view(saved.inputs.opacities.sizes()),
            g.features, g.background, at::Tensor()};
  }
};

RenderOutputs autograd_kernel(SFGS_OP_PARAMETERS) {
  const variable_list out =
      SplatFunction::apply(means, scales, rotations, covariances, opacities, features, background,
                           NonTensorArguments{world_to_camera.vec(), fx, fy, cx, cy, width, height, near_plane,
                                              far_plane, low_pass_variance, antialiased, deterministic});
  return {out[0], out[1], out[2], out[3]};
}

#undef SFGS_OP_PARAMETERS
#undef SFGS_OP_NON_TENSOR_ARGUMENTS

}  // namespace

TORCH_LIBRARY(sfgs, m) { m.def(kSchema); }

TORCH_LIBRARY_IMPL(sfgs, CPU, m) { m.impl("render_gaussians", TORCH_FN(cpu_kernel)); }
#if defined(SFGS_WITH_CUDA)
TORCH_LIBRARY_IMPL(sfgs, CUDA, m) { m.impl("render_gaussians", TORCH_FN(cuda_kernel)); }
#endif
TORCH_LIBRARY_IMPL(sfgs, Meta, m) { m.impl("render_gaussians", TORCH_FN(meta_kernel)); }
TORCH_LIBRARY_IMPL(sfgs, Autograd, m) { m.impl("render_gaussians", TORCH_FN(autograd_kernel)); }

RenderOutputs render_gaussians(const SplatInputs& t, const Camera& camera, double low_pass_variance, bool antialiased,
                               bool deterministic, const BinningBudget* budget) {
  if (budget != nullptr) check_budget(*budget);
  const BudgetScope scope(budget);
  return op().call(t.means, optional_tensor(t.scales), optional_tensor(t.rotations), optional_tensor(t.covariances),
                   t.opacities, t.features, t.background, camera.world_to_camera, camera.fx, camera.fy, camera.cx,
                   camera.cy, camera.width, camera.height, camera.near_plane, camera.far_plane, low_pass_variance,
                   antialiased, deterministic);
}

}  // namespace sfgs::splat
