// The feature-fusion ops: validation at their boundary, the backend by device, and one autograd node each.
#include "ops/feature_fusion/feature_fusion.h"

#include <ATen/ATen.h>
#include <torch/csrc/autograd/custom_function.h>

#include "common/tensor_description.h"
#include "ops/feature_fusion/backend.h"

namespace sfgs::feature_fusion {
namespace {

using torch::autograd::AutogradContext;
using torch::autograd::variable_list;

// The backends: the CPU's loops or the CUDA kernels.
void check_backend(const at::Tensor& t, const char* op) {
  TORCH_CHECK(t.is_cpu() || t.is_cuda(), op, ": tensors must be on the CPU or a CUDA device, got ", t.device());
  if (t.is_cuda()) TORCH_CHECK(cuda::available(), op, ": this build has no CUDA backend");
}

template <typename T>
void gated_mix_as(const at::Tensor& logits, const at::Tensor& a, const at::Tensor& b, const at::Tensor& out) {
  const GatedMixArrays<T> arrays{logits.data_ptr<T>(), a.data_ptr<T>(), b.data_ptr<T>(), out.data_ptr<T>(),
                                 out.numel()};
  if (out.is_cuda())
    cuda::gated_mix(arrays, out.device());
  else
    cpu::gated_mix(arrays);
}

template <typename T>
void gated_mix_backward_as(const variable_list& saved, const at::Tensor& grad, const variable_list& grads) {
  const GatedMixGradientArrays<T> arrays{
      saved[0].data_ptr<T>(), saved[1].data_ptr<T>(), saved[2].data_ptr<T>(), grad.data_ptr<T>(),
      grads[0].data_ptr<T>(), grads[1].data_ptr<T>(), grads[2].data_ptr<T>(), grad.numel()};
  if (grad.is_cuda())
    cuda::gated_mix_backward(arrays, grad.device());
  else
    cpu::gated_mix_backward(arrays);
}

// One node: logits, a and b in (contiguous), the mix out; the backward recomputes the sigmoid.
class GatedMixFunction : public torch::autograd::Function<GatedMixFunction> {
 public:
  static at::Tensor forward(AutogradContext* ctx, const at::Tensor& logits, const at::Tensor& a, const at::Tensor& b) {
    const at::Tensor out = at::empty_like(a);
    if (a.scalar_type() == at::kDouble)
      gated_mix_as<double>(logits, a, b, out);
    else
      gated_mix_as<float>(logits, a, b, out);
    ctx->save_for_backward({logits, a, b});
    return out;
  }

  static variable_list backward(AutogradContext* ctx, variable_list grads) {
    const variable_list saved = ctx->get_saved_variables();
    const at::Tensor grad = grads[0].contiguous();  // materialised: zeros where the output had no gradient
    const variable_list out = {at::empty_like(saved[0]), at::empty_like(saved[1]), at::empty_like(saved[2])};
    if (grad.scalar_type() == at::kDouble)
      gated_mix_backward_as<double>(saved, grad, out);
    else
      gated_mix_backward_as<float>(saved, grad, out);
    return out;
  }
};

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
                                  out_first.size(1)};
  if (out_first.is_cuda())
    cuda::gather_rows(arrays, out_first.device());
  else
    cpu::gather_rows(arrays);
}

void gather_rows(const at::Tensor& first, const at::Tensor& second, int64_t first_rows, const at::Tensor& source,
                 const at::Tensor& out_first, const at::Tensor& out_second, int64_t out_first_rows) {
  if (out_first.scalar_type() == at::kDouble)
    gather_rows_as<double>(first, second, first_rows, source, out_first, out_second, out_first_rows);
  else
    gather_rows_as<float>(first, second, first_rows, source, out_first, out_second, out_first_rows);
}

// One node: the two subsets' rows in (any strides), the merged rows out (contiguous); source and inverse (int64, no
// gradient) gather the rows forward and the gradient's rows backward.
class MergeRowsFunction : public torch::autograd::Function<MergeRowsFunction> {
 public:
  static at::Tensor forward(AutogradContext* ctx, const at::Tensor& first, const at::Tensor& second,
                            const at::Tensor& source, const at::Tensor& inverse) {
    const int64_t rows = source.size(0);
    const at::Tensor out = at::empty({rows, first.size(1)}, first.options());
    gather_rows(first, second, first.size(0), source, out, at::Tensor(), rows);
    ctx->save_for_backward({inverse});
    ctx->saved_data["first_rows"] = first.size(0);
    return out;
  }

  static variable_list backward(AutogradContext* ctx, variable_list grads) {
    const at::Tensor inverse = ctx->get_saved_variables()[0];
    const int64_t first_rows = ctx->saved_data["first_rows"].toInt(), rows = inverse.size(0);
    const at::Tensor grad = grads[0].contiguous();
    const at::Tensor grad_first = at::empty({first_rows, grad.size(1)}, grad.options());
    const at::Tensor grad_second = at::empty({rows - first_rows, grad.size(1)}, grad.options());
    gather_rows(grad, at::Tensor(), rows, inverse, grad_first, grad_second, first_rows);
    return {grad_first, grad_second, at::Tensor(), at::Tensor()};
  }
};

}  // namespace

at::Tensor gated_mix(const at::Tensor& logits, const at::Tensor& a, const at::Tensor& b) {
  TORCH_CHECK(a.defined() && is_float_or_double(a), "gated_mix: a must be a float or double tensor, got ", describe(a));
  for (const at::Tensor* t : {&logits, &b}) {
    TORCH_CHECK(
        t->defined() && t->sizes() == a.sizes() && t->scalar_type() == a.scalar_type() && t->device() == a.device(),
        "gated_mix: logits, a and b must share a's shape ", a.sizes(), ", dtype ", a.scalar_type(), " and device ",
        a.device(), ", got ", describe(*t));
  }
  check_backend(a, "gated_mix");
  return GatedMixFunction::apply(logits.contiguous(), a.contiguous(), b.contiguous());
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
  TORCH_CHECK(first.defined() && first.dim() == 2 && is_float_or_double(first),
              "merge_rows: first must be a float or double (N1, C) tensor, got ", describe(first));
  TORCH_CHECK(second.defined() && second.dim() == 2 && second.size(1) == first.size(1) &&
                  second.scalar_type() == first.scalar_type() && second.device() == first.device(),
              "merge_rows: second must be a ", first.scalar_type(), " (N2, ", first.size(1), ") tensor on ",
              first.device(), ", got ", describe(second));
  const int64_t rows = first.size(0) + second.size(0);
  for (const at::Tensor* t : {&order.source, &order.inverse}) {
    TORCH_CHECK(t->defined() && t->dim() == 1 && t->size(0) == rows && t->scalar_type() == at::kLong &&
                    t->device() == first.device(),
                "merge_rows: the order must be int64 (", rows, ") tensors on ", first.device(), ", got ", describe(*t));
  }
  TORCH_CHECK(order.first_rows == first.size(0), "merge_rows: the order was made for ", order.first_rows,
              " rows of the first subset, got ", first.size(0));
  check_backend(first, "merge_rows");
  // Strided rows are read as they come: the planes' samples are a transposed view, which a copy would cost a pass.
  return MergeRowsFunction::apply(first, second, order.source, order.inverse);
}

at::Tensor merge_rows_reference(const at::Tensor& first, const at::Tensor& second, const MergeOrder& order) {
  return at::cat({first, second}).index_select(0, order.source);
}

}  // namespace sfgs::feature_fusion
