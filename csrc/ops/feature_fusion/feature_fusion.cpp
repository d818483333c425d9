// The feature-fusion ops: validation at their boundary and their dispatcher registration (ops/registration.h): CPU
// and CUDA kernels that route to the backend by device, Meta kernels, one autograd node each.
#include "ops/feature_fusion/feature_fusion.h"

#include <ATen/ATen.h>
#include <torch/csrc/autograd/custom_function.h>
#include <torch/library.h>

#include "common/tensor_description.h"
#include "ops/registration.h"
#include "ops/feature_fusion/backend.h"

namespace sfgs::feature_fusion {
namespace {

using torch::autograd::AutogradContext;
using torch::autograd::variable_list;

// The backends: the CPU's loops or the CUDA kernels; `on_meta`: a Meta kernel's check, which takes meta tensors too.
void check_backend(const at::Tensor& t, const char* op, bool on_meta = false) {
  TORCH_CHECK(t.is_cpu() || t.is_cuda() || (on_meta && t.is_meta()), op,
              ": tensors must be on the CPU or a CUDA device, got ", t.device());
  if (t.is_cuda()) TORCH_CHECK(ops::kBuiltWithCuda, op, ": this build has no CUDA backend");
}

template <typename T>
void gated_mix_as(const at::Tensor& logits, const at::Tensor& a, const at::Tensor& b, const at::Tensor& out) {
  const GatedMixArrays<T> arrays{logits.data_ptr<T>(), a.data_ptr<T>(), b.data_ptr<T>(), out.data_ptr<T>(),
                                 out.numel()};
#if defined(SFGS_WITH_CUDA)
  if (out.is_cuda()) return cuda::gated_mix(arrays, out.device());
#endif
  cpu::gated_mix(arrays);
}

template <typename T>
void gated_mix_backward_as(const variable_list& saved, const at::Tensor& grad, const variable_list& grads) {
  const GatedMixGradientArrays<T> arrays{
      saved[0].data_ptr<T>(), saved[1].data_ptr<T>(), saved[2].data_ptr<T>(), grad.data_ptr<T>(),
      grads[0].data_ptr<T>(), grads[1].data_ptr<T>(), grads[2].data_ptr<T>(), grad.numel()};
#if defined(SFGS_WITH_CUDA)
  if (grad.is_cuda()) return cuda::gated_mix_backward(arrays, grad.device());
#endif
  cpu::gated_mix_backward(arrays);
}

template <typename T>
void gather_rows_as(const at::Tensor& first, const at::Tensor& second, int64_t first_rows, const at::Tensor& source,
                    const at::Tensor& out_first, const at::Tensor& out_second, int64_t out_first_rows) {
  const RowGatherArrays<T> arrays{first.data_ptr<T>(),
                                  first.stride(0),
                                  first.stride(1),
                                  second.defined() ? second.data_ptr<T>() : nullptr,
                                  second.defined() ? second.stride(0) : 0,
                                  second.defined() ? second.stride(1) : 0,
                                  first_rows,
                                  source.data_ptr<int64_t>(),
                                  out_first.data_ptr<T>(),
                                  out_second.defined() ? out_second.data_ptr<T>() : nullptr,
                                  out_first_rows,
                                  source.size(0),
                                  out_first.size(1),
                                  first_rows + (second.defined() ? second.size(0) : 0)};
#if defined(SFGS_WITH_CUDA)
  if (out_first.is_cuda()) return cuda::gather_rows(arrays, out_first.device());
#endif
  cpu::gather_rows(arrays);
}

void gather_rows(const at::Tensor& first, const at::Tensor& second, int64_t first_rows, const at::Tensor& source,
                 const at::Tensor& out_first, const at::Tensor& out_second, int64_t out_first_rows) {
  if (out_first.scalar_type() == at::kDouble)
    gather_rows_as<double>(first, second, first_rows, source, out_first, out_second, out_first_rows);
  else
    gather_rows_as<float>(first, second, first_rows, source, out_first, out_second, out_first_rows);
}

void check_mix_gradient(const at::Tensor& grad, const at::Tensor& a) {
  TORCH_CHECK(grad.defined() && grad.sizes() == a.sizes() && grad.scalar_type() == a.scalar_type() &&
                  grad.device() == a.device(),
              "gated_mix_backward: grad must share a's shape ", a.sizes(), ", dtype ", a.scalar_type(), " and device ",
              a.device(), ", got ", describe(grad));
}

void check_mix(const at::Tensor& logits, const at::Tensor& a, const at::Tensor& b, bool on_meta = false) {
  TORCH_CHECK(a.defined() && is_float_or_double(a), "gated_mix: a must be a float or double tensor, got ", describe(a));
  for (const at::Tensor* t : {&logits, &b}) {
    TORCH_CHECK(
        t->defined() && t->sizes() == a.sizes() && t->scalar_type() == a.scalar_type() && t->device() == a.device(),
        "gated_mix: logits, a and b must share a's shape ", a.sizes(), ", dtype ", a.scalar_type(), " and device ",
        a.device(), ", got ", describe(*t));
  }
  check_backend(a, "gated_mix", on_meta);
}

// The order's tensors as the kernels read them: source and inverse int64 (N1 + N2) on the rows' device.
void check_merge(const at::Tensor& first, const at::Tensor& second, const at::Tensor& source, const at::Tensor& inverse,
                 bool on_meta = false) {
  TORCH_CHECK(first.defined() && first.dim() == 2 && is_float_or_double(first),
              "merge_rows: first must be a float or double (N1, C) tensor, got ", describe(first));
  TORCH_CHECK(second.defined() && second.dim() == 2 && second.size(1) == first.size(1) &&
                  second.scalar_type() == first.scalar_type() && second.device() == first.device(),
              "merge_rows: second must be a ", first.scalar_type(), " (N2, ", first.size(1), ") tensor on ",
              first.device(), ", got ", describe(second));
  const int64_t rows = first.size(0) + second.size(0);
  for (const at::Tensor* t : {&source, &inverse}) {
    TORCH_CHECK(t->defined() && t->dim() == 1 && t->size(0) == rows && t->scalar_type() == at::kLong &&
                    t->device() == first.device(),
                "merge_rows: the order must be int64 (", rows, ") tensors on ", first.device(), ", got ", describe(*t));
  }
  check_backend(first, "merge_rows", on_meta);
}

// ---- the dispatcher ops (ops/registration.h) ----

using Gradients3 = std::tuple<at::Tensor, at::Tensor, at::Tensor>;
using Gradients2 = std::tuple<at::Tensor, at::Tensor>;
constexpr const char* kMixSchema = "gated_mix(Tensor logits, Tensor a, Tensor b) -> Tensor";
constexpr const char* kMixBackwardSchema =
    "gated_mix_backward(Tensor grad, Tensor logits, Tensor a, Tensor b) -> (Tensor grad_logits, Tensor grad_a, "
    "Tensor grad_b)";
// source[i]: point i's row in cat(first, second); inverse[j]: the point of that row (MergeOrder).
constexpr const char* kMergeSchema = "merge_rows(Tensor first, Tensor second, Tensor source, Tensor inverse) -> Tensor";
constexpr const char* kMergeBackwardSchema =
    "merge_rows_backward(Tensor grad, Tensor inverse, int first_rows) -> (Tensor grad_first, Tensor grad_second)";
using MixSignature = at::Tensor(const at::Tensor&, const at::Tensor&, const at::Tensor&);
using MixBackwardSignature = Gradients3(const at::Tensor&, const at::Tensor&, const at::Tensor&, const at::Tensor&);
using MergeSignature = at::Tensor(const at::Tensor&, const at::Tensor&, const at::Tensor&, const at::Tensor&);
using MergeBackwardSignature = Gradients2(const at::Tensor&, const at::Tensor&, int64_t);

const c10::TypedOperatorHandle<MixSignature>& mix_op() {
  static const auto handle = ops::find_op<MixSignature>("sfgs::gated_mix");
  return handle;
}
const c10::TypedOperatorHandle<MixBackwardSignature>& mix_backward_op() {
  static const auto handle = ops::find_op<MixBackwardSignature>("sfgs::gated_mix_backward");
  return handle;
}
const c10::TypedOperatorHandle<MergeSignature>& merge_op() {
  static const auto handle = ops::find_op<MergeSignature>("sfgs::merge_rows");
  return handle;
}
const c10::TypedOperatorHandle<MergeBackwardSignature>& merge_backward_op() {
  static const auto handle = ops::find_op<MergeBackwardSignature>("sfgs::merge_rows_backward");
  return handle;
}

at::Tensor mix_kernel(const at::Tensor& logits, const at::Tensor& a, const at::Tensor& b) {
  check_mix(logits, a, b);
  const at::Tensor l = logits.contiguous(), x = a.contiguous(), y = b.contiguous(), out = at::empty_like(x);
  if (x.scalar_type() == at::kDouble)
    gated_mix_as<double>(l, x, y, out);
  else
    gated_mix_as<float>(l, x, y, out);
  return out;
}

at::Tensor mix_meta(const at::Tensor& logits, const at::Tensor& a, const at::Tensor& b) {
  check_mix(logits, a, b, /*on_meta=*/true);
  return at::empty_like(a, at::MemoryFormat::Contiguous);
}

Gradients3 mix_backward_kernel(const at::Tensor& grad, const at::Tensor& logits, const at::Tensor& a,
                               const at::Tensor& b) {
  check_mix(logits, a, b);
  check_mix_gradient(grad, a);
  const variable_list saved = {logits.contiguous(), a.contiguous(), b.contiguous()};
  const at::Tensor g = grad.contiguous();
  const variable_list out = {at::empty_like(saved[0]), at::empty_like(saved[1]), at::empty_like(saved[2])};
  if (g.scalar_type() == at::kDouble)
    gated_mix_backward_as<double>(saved, g, out);
  else
    gated_mix_backward_as<float>(saved, g, out);
  return {out[0], out[1], out[2]};
}

Gradients3 mix_backward_meta(const at::Tensor& grad, const at::Tensor& logits, const at::Tensor& a,
                             const at::Tensor& b) {
  check_mix(logits, a, b, /*on_meta=*/true);
  check_mix_gradient(grad, a);
  const auto like = [](const at::Tensor& t) { return at::empty_like(t, at::MemoryFormat::Contiguous); };
  return {like(logits), like(a), like(b)};
}

at::Tensor merge_kernel(const at::Tensor& first, const at::Tensor& second, const at::Tensor& source,
                        const at::Tensor& inverse) {
  check_merge(first, second, source, inverse);
  // Strided rows are read as they come: the planes' samples are a transposed view, which a copy would cost a pass.
  const int64_t rows = source.size(0);
  const at::Tensor out = at::empty({rows, first.size(1)}, first.options());
  gather_rows(first, second, first.size(0), source.contiguous(), out, at::Tensor(), rows);
  return out;
}

at::Tensor merge_meta(const at::Tensor& first, const at::Tensor& second, const at::Tensor& source,
                      const at::Tensor& inverse) {
  check_merge(first, second, source, inverse, /*on_meta=*/true);
  return at::empty({source.size(0), first.size(1)}, first.options());
}

void check_merge_backward(const at::Tensor& grad, const at::Tensor& inverse, int64_t first_rows, bool on_meta = false) {
  TORCH_CHECK(grad.defined() && grad.dim() == 2 && is_float_or_double(grad),
              "merge_rows_backward: grad must be a float or double (N, C) tensor, got ", describe(grad));
  TORCH_CHECK(inverse.dim() == 1 && inverse.size(0) == grad.size(0) && inverse.scalar_type() == at::kLong &&
                  inverse.device() == grad.device(),
              "merge_rows_backward: inverse must be int64 (", grad.size(0), ") on ", grad.device(), ", got ",
              describe(inverse));
  TORCH_CHECK(first_rows >= 0 && first_rows <= grad.size(0), "merge_rows_backward: first_rows must be in 0..",
              grad.size(0), ", got ", first_rows);
  check_backend(grad, "merge_rows_backward", on_meta);
}

Gradients2 merge_backward_kernel(const at::Tensor& grad, const at::Tensor& inverse, int64_t first_rows) {
  check_merge_backward(grad, inverse, first_rows);
  const int64_t rows = inverse.size(0);
  const at::Tensor g = grad.contiguous();
  const at::Tensor grad_first = at::empty({first_rows, g.size(1)}, g.options());
  const at::Tensor grad_second = at::empty({rows - first_rows, g.size(1)}, g.options());
  gather_rows(g, at::Tensor(), rows, inverse.contiguous(), grad_first, grad_second, first_rows);
  return {grad_first, grad_second};
}

Gradients2 merge_backward_meta(const at::Tensor& grad, const at::Tensor& inverse, int64_t first_rows) {
  check_merge_backward(grad, inverse, first_rows, /*on_meta=*/true);
  return {at::empty({first_rows, grad.size(1)}, grad.options()),
          at::empty({inverse.size(0) - first_rows, grad.size(1)}, grad.options())};
}

// The mix's one node: logits, a and b in, the mix out; the backward recomputes the sigmoid.
class GatedMixFunction : public torch::autograd::Function<GatedMixFunction> {
 public:
  static at::Tensor forward(AutogradContext* ctx, const at::Tensor& logits, const at::Tensor& a, const at::Tensor& b) {
    ctx->save_for_backward({logits, a, b});
    const at::AutoDispatchBelowADInplaceOrView below_autograd;
    return mix_op().call(logits, a, b);
  }

  static variable_list backward(AutogradContext* ctx, variable_list grads) {
    const variable_list saved = ctx->get_saved_variables();
    // grads[0] is materialised: zeros where the output had no gradient.
    const auto [logits, a, b] = mix_backward_op().call(grads[0], saved[0], saved[1], saved[2]);
    return {logits, a, b};
  }
};

// The merge's one node: the two subsets' rows in (any strides), the merged rows out (contiguous); source and inverse
// (int64, no gradient) gather the rows forward and the gradient's rows backward.
class MergeRowsFunction : public torch::autograd::Function<MergeRowsFunction> {
 public:
  static at::Tensor forward(AutogradContext* ctx, const at::Tensor& first, const at::Tensor& second,
                            const at::Tensor& source, const at::Tensor& inverse) {
    ctx->save_for_backward({inverse});
    ctx->saved_data["first_rows"] = first.size(0);
    const at::AutoDispatchBelowADInplaceOrView below_autograd;
    return merge_op().call(first, second, source, inverse);
  }

  static variable_list backward(AutogradContext* ctx, variable_list grads) {
    const auto [first, second] =
        merge_backward_op().call(grads[0], ctx->get_saved_variables()[0], ctx->saved_data["first_rows"].toInt());
    return {first, second, at::Tensor(), at::Tensor()};
  }
};

at::Tensor mix_autograd(const at::Tensor& logits, const at::Tensor& a, const at::Tensor& b) {
  return GatedMixFunction::apply(logits, a, b);
}

at::Tensor merge_autograd(const at::Tensor& first, const at::Tensor& second, const at::Tensor& source,
                          const at::Tensor& inverse) {
  return MergeRowsFunction::apply(first, second, source, inverse);
}

}  // namespace

at::Tensor gated_mix(const at::Tensor& logits, const at::Tensor& a, const at::Tensor& b) {
  check_mix(logits, a, b);
  return mix_op().call(logits, a, b);
}

at::Tensor gated_mix_reference(const at::Tensor& logits, const at::Tensor& a, const at::Tensor& b) {
  const at::Tensor alpha = at::sigmoid(logits);
  return (1 - alpha) * a + alpha * b;
}

MergeOrder MergeOrder::of(const at::Tensor& first_points, const at::Tensor& second_points) {
  for (const at::Tensor* t : {&first_points, &second_points}) {
    TORCH_CHECK(t->defined() && t->dim() == 1 && t->scalar_type() == at::kLong,
                "MergeOrder: the subsets' points must be int64 (K) tensors, got ", describe(*t));
  }
  const at::Tensor points = at::cat({first_points, second_points}).cpu().contiguous();  // row -> point
  const int64_t n = points.size(0);
  at::Tensor source = at::full({n}, -1, at::kLong);  // point -> row
  const int64_t* point = points.data_ptr<int64_t>();
  int64_t* row_of = source.data_ptr<int64_t>();
  for (int64_t row = 0; row < n; ++row) {
    TORCH_CHECK(point[row] >= 0 && point[row] < n, "MergeOrder: point ", point[row], " is outside 0..", n - 1,
                " (the two subsets must hold every point once)");
    TORCH_CHECK(row_of[point[row]] < 0, "MergeOrder: point ", point[row], " is in the subsets twice");
    row_of[point[row]] = row;
  }
  // n distinct points in 0..n-1: every point has its row.
  return {source, points, first_points.size(0)};
}

MergeOrder MergeOrder::to(at::Device device) const { return {source.to(device), inverse.to(device), first_rows}; }

at::Tensor merge_rows(const at::Tensor& first, const at::Tensor& second, const MergeOrder& order) {
  check_merge(first, second, order.source, order.inverse);
  TORCH_CHECK(order.first_rows == first.size(0), "merge_rows: the order was made for ", order.first_rows,
              " rows of the first subset, got ", first.size(0));
  return merge_op().call(first, second, order.source, order.inverse);
}

at::Tensor merge_rows_reference(const at::Tensor& first, const at::Tensor& second, const MergeOrder& order) {
  return at::cat({first, second}).index_select(0, order.source);
}

TORCH_LIBRARY_FRAGMENT(sfgs, m) {
  m.def(kMixSchema);
  m.def(kMixBackwardSchema);
  m.def(kMergeSchema);
  m.def(kMergeBackwardSchema);
}
TORCH_LIBRARY_IMPL(sfgs, CPU, m) {
  m.impl("gated_mix", TORCH_FN(mix_kernel));
  m.impl("gated_mix_backward", TORCH_FN(mix_backward_kernel));
  m.impl("merge_rows", TORCH_FN(merge_kernel));
  m.impl("merge_rows_backward", TORCH_FN(merge_backward_kernel));
}
#if defined(SFGS_WITH_CUDA)
TORCH_LIBRARY_IMPL(sfgs, CUDA, m) {
  m.impl("gated_mix", TORCH_FN(mix_kernel));
  m.impl("gated_mix_backward", TORCH_FN(mix_backward_kernel));
  m.impl("merge_rows", TORCH_FN(merge_kernel));
  m.impl("merge_rows_backward", TORCH_FN(merge_backward_kernel));
}
#endif
TORCH_LIBRARY_IMPL(sfgs, Meta, m) {
  m.impl("gated_mix", TORCH_FN(mix_meta));
  m.impl("gated_mix_backward", TORCH_FN(mix_backward_meta));
  m.impl("merge_rows", TORCH_FN(merge_meta));
  m.impl("merge_rows_backward", TORCH_FN(merge_backward_meta));
}
TORCH_LIBRARY_IMPL(sfgs, Autograd, m) {
  m.impl("gated_mix", TORCH_FN(mix_autograd));
  m.impl("merge_rows", TORCH_FN(merge_autograd));
}

}  // namespace sfgs::feature_fusion
