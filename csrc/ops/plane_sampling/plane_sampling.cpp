// The fixed-point plane sampling: the reads, validation at the boundary, and its dispatcher ops (ops/registration.h):
// the samplings (CPU and CUDA kernels are grid_sample's) with their autograd nodes, and the reads' gather backward.
#include "ops/plane_sampling/plane_sampling.h"

#include <limits>

#include <string>

#include <ATen/ATen.h>
#include <torch/csrc/autograd/custom_function.h>
#include <torch/library.h>

#include "ops/plane_sampling/constants.h"
#include "common/tensor_description.h"
#include "ops/plane_sampling/backend.h"
#include "ops/registration.h"

namespace sfgs::plane_sampling {
namespace {

using torch::autograd::AutogradContext;
using torch::autograd::variable_list;

// at::grid_sampler's integer modes (torch.nn.functional.grid_sample's 'bilinear' and 'border').
constexpr int64_t kBilinear = 0;
constexpr int64_t kBorderPadding = 1;

// A grid coordinate in [-1, 1] to a pixel position (align_corners: -1 and 1 are the first and last texel centres),
// clipped to the border as grid_sample clips it.
at::Tensor pixel_position(const at::Tensor& coordinate, int64_t size) {
  return ((coordinate + 1) / 2 * double(size - 1)).clamp(0, double(size - 1));
}

void check_planes(const at::Tensor& planes, const char* what) {
  TORCH_CHECK(planes.defined() && planes.dim() == 4 && is_float_or_double(planes), what,
              ": planes must be a float32 or float64 (P, C, H, W) tensor, got ", describe(planes));
}

// The reads' tensors in the ops' order (after the planes and the points they are read at).
struct ReadTensors {
  at::Tensor chunk_rows, chunk_begins, chunk_ends, points, weights;
};

ReadTensors read_tensors(const PlaneReads& r) {
  return {r.chunk_rows, r.chunk_begins, r.chunk_ends, r.points, r.weights};
}

// Shapes, dtypes and devices of the reads, for planes of `dtype` on `device` (meta tensors pass with meta planes).
void check_reads(const ReadTensors& r, at::ScalarType dtype, at::Device device, const char* op) {
  TORCH_CHECK(r.chunk_rows.defined() && r.chunk_rows.dim() == 1, op, ": chunk_rows must be (K), got ",
              describe(r.chunk_rows));
  TORCH_CHECK(r.points.defined() && r.points.dim() == 1, op, ": points must be (E), got ", describe(r.points));
  const int64_t chunks = r.chunk_rows.size(0), reads = r.points.size(0);
  const auto check = [&](const at::Tensor& t, const char* name, int64_t length, at::ScalarType type) {
    check_tensor(t, std::string(op) + ": " + name, {length}, type, device);
  };
  check(r.chunk_rows, "chunk_rows", chunks, at::kInt);
  check(r.chunk_begins, "chunk_begins", chunks, at::kInt);
  check(r.chunk_ends, "chunk_ends", chunks, at::kInt);
  check(r.points, "points", reads, at::kInt);
  check(r.weights, "weights", reads, dtype);
}

// The CPU op reads the reads' indices where they lie and refuses ones plane_reads could not have made (the CUDA
// kernel gives such chunks NaN or skips them instead: plane_sampling_math.h).
void check_read_indices_on_host(const ReadTensors& r, int64_t texels, int64_t points) {
  TORCH_CHECK(values_within(r.chunk_rows, 0, texels), "plane_reads_gradient: chunk_rows must lie in [0, ", texels, ")");
  TORCH_CHECK(values_within(r.points, 0, points), "plane_reads_gradient: points must lie in [0, ", points, ")");
  const int64_t reads = r.points.size(0);
  TORCH_CHECK(values_within(r.chunk_begins, 0, reads + 1) && values_within(r.chunk_ends, 0, reads + 1) &&
                  (r.chunk_begins <= r.chunk_ends).all().item<bool>(),
              "plane_reads_gradient: every chunk must run over reads within [0, ", reads, "], begin before end");
}

template <typename T>
void gradient_as(const ReadTensors& r, const at::Tensor& grad_features, const at::Tensor& grad_planes) {
  PlaneGradientArrays<T> a{};
  a.grad_features = grad_features.data_ptr<T>();
  a.chunk_rows = r.chunk_rows.data_ptr<int32_t>();
  a.chunk_begins = r.chunk_begins.data_ptr<int32_t>();
  a.chunk_ends = r.chunk_ends.data_ptr<int32_t>();
  a.points = r.points.data_ptr<int32_t>();
  a.weights = r.weights.data_ptr<T>();
  a.grad_planes = grad_planes.data_ptr<T>();
  a.chunks = r.chunk_rows.size(0);
  a.planes = grad_planes.size(0);
  a.channels = grad_planes.size(1);
  a.texels = grad_planes.size(2) * grad_planes.size(3);
  a.points_count = grad_features.size(0);
  a.reads = r.points.size(0);
#if defined(SFGS_WITH_CUDA)
  if (grad_planes.is_cuda()) return cuda::gradient(a, grad_planes.device());
#endif
  cpu::gradient(a);
}

// ---- the dispatcher ops (ops/registration.h) ----

constexpr const char* kReadsArguments =
    "Tensor chunk_rows, Tensor chunk_begins, Tensor chunk_ends, Tensor points, Tensor weights";
const std::string kSampleSchema =
    std::string("sample_fixed_planes(Tensor planes, Tensor grid, ") + kReadsArguments + ") -> Tensor";
const std::string kSampleAtTimeSchema =
    std::string("sample_fixed_planes_at_time(Tensor planes, Tensor positions, Tensor time, ") + kReadsArguments +
    ") -> Tensor";
const std::string kGradientSchema = std::string("plane_reads_gradient(Tensor grad, ") + kReadsArguments +
                                    ", int planes, int channels, int height, int width) -> Tensor";
using SampleSignature = at::Tensor(const at::Tensor&, const at::Tensor&, const at::Tensor&, const at::Tensor&,
                                   const at::Tensor&, const at::Tensor&, const at::Tensor&);
using SampleAtTimeSignature = at::Tensor(const at::Tensor&, const at::Tensor&, const at::Tensor&, const at::Tensor&,
                                         const at::Tensor&, const at::Tensor&, const at::Tensor&, const at::Tensor&);
using GradientSignature = at::Tensor(const at::Tensor&, const at::Tensor&, const at::Tensor&, const at::Tensor&,
                                     const at::Tensor&, const at::Tensor&, int64_t, int64_t, int64_t, int64_t);

const c10::TypedOperatorHandle<SampleSignature>& sample_op() {
  static const auto handle = ops::find_op<SampleSignature>("sfgs::sample_fixed_planes");
  return handle;
}
const c10::TypedOperatorHandle<SampleAtTimeSignature>& sample_at_time_op() {
  static const auto handle = ops::find_op<SampleAtTimeSignature>("sfgs::sample_fixed_planes_at_time");
  return handle;
}
const c10::TypedOperatorHandle<GradientSignature>& gradient_op() {
  static const auto handle = ops::find_op<GradientSignature>("sfgs::plane_reads_gradient");
  return handle;
}

void check_sample(const at::Tensor& planes, const at::Tensor& grid, const ReadTensors& r) {
  check_planes(planes, "sample_fixed_planes");
  TORCH_CHECK(grid.defined() && grid.dim() == 3 && grid.size(0) == planes.size(0) && grid.size(2) == 2 &&
                  grid.scalar_type() == planes.scalar_type() && grid.device() == planes.device(),
              "sample_fixed_planes: the grid must be a ", planes.scalar_type(), " (", planes.size(0),
              ", N, 2) tensor on ", planes.device(), ", got ", describe(grid));
  check_reads(r, planes.scalar_type(), planes.device(), "sample_fixed_planes");
}

void check_sample_at_time(const at::Tensor& planes, const at::Tensor& positions, const at::Tensor& time,
                          const ReadTensors& r) {
  check_planes(planes, "sample_fixed_planes_at_time");
  TORCH_CHECK(positions.defined() && positions.dim() == 2 && positions.size(0) == planes.size(0) &&
                  positions.scalar_type() == planes.scalar_type() && positions.device() == planes.device(),
              "sample_fixed_planes_at_time: the positions must be a ", planes.scalar_type(), " (", planes.size(0),
              ", N) tensor on ", planes.device(), ", got ", describe(positions));
  TORCH_CHECK(time.defined() && time.dim() == 0 && time.scalar_type() == planes.scalar_type() &&
                  time.device() == planes.device(),
              "sample_fixed_planes_at_time: the time must be a 0-dim ", planes.scalar_type(), " tensor on ",
              planes.device(), ", got ", describe(time));
  check_reads(r, planes.scalar_type(), planes.device(), "sample_fixed_planes_at_time");
}

// What sample_planes returns for `points` reads of the planes, described: grid_sample's (P, C, 1, N) output seen as
// (N, P C), the strided view the sampling hands on (its consumers read it as it is; a copy would cost a pass).
at::Tensor sampled_like(const at::Tensor& planes, int64_t points) {
  return at::empty({planes.size(0), planes.size(1), 1, points}, planes.options())
      .squeeze(2)
      .permute({2, 0, 1})
      .reshape({points, -1});
}

at::Tensor sample_kernel(const at::Tensor& planes, const at::Tensor& grid, const at::Tensor& chunk_rows,
                         const at::Tensor& chunk_begins, const at::Tensor& chunk_ends, const at::Tensor& points,
                         const at::Tensor& weights) {
  check_sample(planes, grid, {chunk_rows, chunk_begins, chunk_ends, points, weights});
  return sample_planes(planes, grid);
}

at::Tensor sample_meta(const at::Tensor& planes, const at::Tensor& grid, const at::Tensor& chunk_rows,
                       const at::Tensor& chunk_begins, const at::Tensor& chunk_ends, const at::Tensor& points,
                       const at::Tensor& weights) {
  check_sample(planes, grid, {chunk_rows, chunk_begins, chunk_ends, points, weights});
  return sampled_like(planes, grid.size(1));
}

at::Tensor sample_at_time_kernel(const at::Tensor& planes, const at::Tensor& positions, const at::Tensor& time,
                                 const at::Tensor& chunk_rows, const at::Tensor& chunk_begins,
                                 const at::Tensor& chunk_ends, const at::Tensor& points, const at::Tensor& weights) {
  check_sample_at_time(planes, positions, time, {chunk_rows, chunk_begins, chunk_ends, points, weights});
  return sample_planes(planes, time_grid(positions, time));
}

at::Tensor sample_at_time_meta(const at::Tensor& planes, const at::Tensor& positions, const at::Tensor& time,
                               const at::Tensor& chunk_rows, const at::Tensor& chunk_begins,
                               const at::Tensor& chunk_ends, const at::Tensor& points, const at::Tensor& weights) {
  check_sample_at_time(planes, positions, time, {chunk_rows, chunk_begins, chunk_ends, points, weights});
  return sampled_like(planes, positions.size(1));
}

void check_gradient(const at::Tensor& grad, const ReadTensors& r, int64_t planes, int64_t channels, int64_t height,
                    int64_t width) {
  TORCH_CHECK(planes >= 1 && channels >= 1 && height >= 1 && width >= 1,
              "plane_reads_gradient: planes of at least 1 plane, channel and texel expected, got ", planes, " x ",
              channels, " x ", height, " x ", width);
  TORCH_CHECK(grad.defined() && grad.dim() == 2 && grad.size(1) == planes * channels && is_float_or_double(grad),
              "plane_reads_gradient: grad must be a float32 or float64 (N, ", planes * channels, ") tensor, got ",
              describe(grad));
  check_reads(r, grad.scalar_type(), grad.device(), "plane_reads_gradient");
}

at::Tensor gradient_kernel(const at::Tensor& grad, const at::Tensor& chunk_rows, const at::Tensor& chunk_begins,
                           const at::Tensor& chunk_ends, const at::Tensor& points, const at::Tensor& weights,
                           int64_t planes, int64_t channels, int64_t height, int64_t width) {
  const ReadTensors r{chunk_rows, chunk_begins, chunk_ends, points, weights};
  check_gradient(grad, r, planes, channels, height, width);
  if (grad.is_cpu()) check_read_indices_on_host(r, planes * height * width, grad.size(0));
  const at::Tensor grad_features = grad.contiguous();
  at::Tensor grad_planes = at::zeros({planes, channels, height, width}, grad_features.options());
  if (chunk_rows.size(0) == 0) return grad_planes;
  const ReadTensors contiguous{chunk_rows.contiguous(), chunk_begins.contiguous(), chunk_ends.contiguous(),
                               points.contiguous(), weights.contiguous()};
  if (grad_features.scalar_type() == at::kDouble)
    gradient_as<double>(contiguous, grad_features, grad_planes);
  else
    gradient_as<float>(contiguous, grad_features, grad_planes);
  return grad_planes;
}

at::Tensor gradient_meta(const at::Tensor& grad, const at::Tensor& chunk_rows, const at::Tensor& chunk_begins,
                         const at::Tensor& chunk_ends, const at::Tensor& points, const at::Tensor& weights,
                         int64_t planes, int64_t channels, int64_t height, int64_t width) {
  check_gradient(grad, {chunk_rows, chunk_begins, chunk_ends, points, weights}, planes, channels, height, width);
  return at::empty({planes, channels, height, width}, grad.options());
}

// The planes' gradient (P, C, H, W) of the reads' incoming gradients (N, P C): the gather of every texel's reads.
at::Tensor gathered_gradient(const variable_list& reads, const at::Tensor& grad_output, at::IntArrayRef shape) {
  return gradient_op().call(grad_output, reads[0], reads[1], reads[2], reads[3], reads[4], shape[0], shape[1], shape[2],
                            shape[3]);
}

// The sampling's node: the grid (and the reads) are fixed, so the planes alone get a gradient.
class SampleFixedPlanes : public torch::autograd::Function<SampleFixedPlanes> {
 public:
  static at::Tensor forward(AutogradContext* ctx, const at::Tensor& planes, const at::Tensor& grid,
                            const at::Tensor& chunk_rows, const at::Tensor& chunk_begins, const at::Tensor& chunk_ends,
                            const at::Tensor& points, const at::Tensor& weights) {
    TORCH_CHECK(!grid.requires_grad(), "sample_fixed_planes: the grid is fixed; it must not require a gradient");
    ctx->save_for_backward({chunk_rows, chunk_begins, chunk_ends, points, weights});
    ctx->saved_data["shape"] = planes.sizes().vec();
    const at::AutoDispatchBelowADInplaceOrView below_autograd;
    return sample_op().call(planes, grid, chunk_rows, chunk_begins, chunk_ends, points, weights);
  }

  static variable_list backward(AutogradContext* ctx, variable_list grads) {
    const std::vector<int64_t> shape = ctx->saved_data["shape"].toIntVector();
    variable_list out(7);
    out[0] = gathered_gradient(ctx->get_saved_variables(), grads[0], shape);
    return out;
  }
};

// The time planes' node: the forward reads at (position, time); the backward gathers along the positions' line and
// shares the result between the two time rows around the time.
class SampleFixedPlanesAtTime : public torch::autograd::Function<SampleFixedPlanesAtTime> {
 public:
  static at::Tensor forward(AutogradContext* ctx, const at::Tensor& planes, const at::Tensor& positions,
                            const at::Tensor& time, const at::Tensor& chunk_rows, const at::Tensor& chunk_begins,
                            const at::Tensor& chunk_ends, const at::Tensor& points, const at::Tensor& weights) {
    TORCH_CHECK(!positions.requires_grad() && !time.requires_grad(),
                "sample_fixed_planes_at_time: the positions and the time are fixed; they must not require a gradient");
    ctx->save_for_backward({chunk_rows, chunk_begins, chunk_ends, points, weights, time});
    ctx->saved_data["shape"] = planes.sizes().vec();
    const at::AutoDispatchBelowADInplaceOrView below_autograd;
    return sample_at_time_op().call(planes, positions, time, chunk_rows, chunk_begins, chunk_ends, points, weights);
  }

  static variable_list backward(AutogradContext* ctx, variable_list grads) {
    const std::vector<int64_t> shape = ctx->saved_data["shape"].toIntVector();
    const variable_list saved = ctx->get_saved_variables();
    const int64_t rows = shape[2];
    const at::Tensor along_line = gathered_gradient(saved, grads[0], {shape[0], shape[1], 1, shape[3]});
    // The time's two rows and their weights, on the device: grid_sample's border clip and bilinear weights.
    const at::Tensor row = pixel_position(saved[5], rows), first = row.floor();
    const at::Tensor share = (row - first).to(along_line.scalar_type());
    const at::Tensor first_row = first.to(at::kLong).view({1});
    const at::Tensor second_row = (first_row + 1).clamp_max(rows - 1);  // its share is 0 on the last row
    at::Tensor grad_planes = at::zeros({shape[0], shape[1], rows, shape[3]}, along_line.options());
    grad_planes.index_add_(2, first_row, along_line * (1 - share));
    grad_planes.index_add_(2, second_row, along_line * share);
    variable_list out(8);
    out[0] = grad_planes;
    return out;
  }
};

at::Tensor sample_autograd(const at::Tensor& planes, const at::Tensor& grid, const at::Tensor& chunk_rows,
                           const at::Tensor& chunk_begins, const at::Tensor& chunk_ends, const at::Tensor& points,
                           const at::Tensor& weights) {
  return SampleFixedPlanes::apply(planes, grid, chunk_rows, chunk_begins, chunk_ends, points, weights);
}

at::Tensor sample_at_time_autograd(const at::Tensor& planes, const at::Tensor& positions, const at::Tensor& time,
                                   const at::Tensor& chunk_rows, const at::Tensor& chunk_begins,
                                   const at::Tensor& chunk_ends, const at::Tensor& points, const at::Tensor& weights) {
  return SampleFixedPlanesAtTime::apply(planes, positions, time, chunk_rows, chunk_begins, chunk_ends, points, weights);
}

}  // namespace

at::Tensor sample_planes(const at::Tensor& planes, const at::Tensor& grid) {
  const at::Tensor sampled = at::grid_sampler(planes, grid.unsqueeze(1), kBilinear, kBorderPadding,
                                              /*align_corners=*/true);  // (P, C, 1, N)
  return sampled.squeeze(2).permute({2, 0, 1}).reshape({grid.size(1), -1});
}

at::Tensor time_grid(const at::Tensor& positions, const at::Tensor& time) {
  const at::Tensor space = positions.unsqueeze(-1);  // (P, N, 1)
  return at::cat({space, time.expand_as(space)}, -1);
}

PlaneReads plane_reads(const at::Tensor& grid, int64_t height, int64_t width) {
  TORCH_CHECK(grid.defined() && grid.dim() == 3 && grid.size(2) == 2 && is_float_or_double(grid),
              "plane_reads: the grid must be a float32 or float64 (P, N, 2) tensor, got ", describe(grid));
  TORCH_CHECK(height >= 1 && width >= 1, "plane_reads: planes must be at least 1 x 1, got ", height, " x ", width);
  const int64_t p = grid.size(0), n = grid.size(1), texels = height * width;
  TORCH_CHECK(p * texels < std::numeric_limits<int32_t>::max() && 4 * p * n < std::numeric_limits<int32_t>::max(),
              "plane_reads: ", p, " planes of ", height, " x ", width, " read at ", n,
              " points exceed the int32 indices of the reads");
  TORCH_CHECK(at::isfinite(grid).all().item<bool>(), "plane_reads: the grid must be finite");
  const at::Tensor g = grid.detach();
  const at::Tensor x = pixel_position(g.select(2, 0), width), y = pixel_position(g.select(2, 1), height);
  const at::Tensor x0 = x.floor(), y0 = y.floor();
  const at::Tensor fx = x - x0, fy = y - y0;
  // The four corners as grid_sample weighs them; a corner past the last texel (a point on the far border) is not
  // read.
  const at::Tensor corner_x = at::stack({x0, x0 + 1, x0, x0 + 1}), corner_y = at::stack({y0, y0, y0 + 1, y0 + 1});
  const at::Tensor weights = at::stack({(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy});  // (4, P, N)
  const at::Tensor plane_of = at::arange(p, g.options().dtype(at::kLong)).view({1, p, 1}).expand({4, p, n});
  const at::Tensor point_of = at::arange(n, g.options().dtype(at::kLong)).view({1, 1, n}).expand({4, p, n});
  const at::Tensor inside = (corner_x < double(width)) & (corner_y < double(height));
  const at::Tensor rows =
      (plane_of * texels + corner_y.to(at::kLong) * width + corner_x.to(at::kLong)).masked_select(inside);
  const auto [sorted_rows, order] = at::sort(rows, /*stable=*/true, /*dim=*/0, /*descending=*/false);
  PlaneReads r;
  r.planes = p;
  r.height = height;
  r.width = width;
  r.count = n;
  r.points = point_of.masked_select(inside).index_select(0, order).to(at::kInt);
  r.weights = weights.masked_select(inside).index_select(0, order).contiguous();
  // Chunks: each texel's reads cut into runs of at most kPlaneReadChunk.
  const at::Tensor counts = at::bincount(sorted_rows, {}, p * texels);
  const at::Tensor row_ends = counts.cumsum(0), row_begins = row_ends - counts;
  const at::Tensor chunks_per_row = (counts + (kPlaneReadChunk - 1)).div(kPlaneReadChunk, "floor");
  const at::Tensor chunk_row = at::repeat_interleave(at::arange(p * texels, counts.options()), chunks_per_row);
  const at::Tensor first_chunk = chunks_per_row.cumsum(0) - chunks_per_row;
  const at::Tensor within = at::arange(chunk_row.size(0), counts.options()) - first_chunk.index_select(0, chunk_row);
  const at::Tensor begins = row_begins.index_select(0, chunk_row) + within * kPlaneReadChunk;
  r.chunk_rows = chunk_row.to(at::kInt);
  r.chunk_begins = begins.to(at::kInt);
  r.chunk_ends = at::minimum(begins + kPlaneReadChunk, row_ends.index_select(0, chunk_row)).to(at::kInt);
  return r;
}

at::Tensor sample_fixed_planes(const at::Tensor& planes, const at::Tensor& grid, const PlaneReads& reads) {
  check_planes(planes, "sample_fixed_planes");
  TORCH_CHECK(grid.defined() && grid.dim() == 3 && grid.size(0) == planes.size(0) && grid.size(2) == 2 &&
                  grid.scalar_type() == planes.scalar_type() && grid.device() == planes.device(),
              "sample_fixed_planes: the grid must be a ", planes.scalar_type(), " (", planes.size(0),
              ", N, 2) tensor on ", planes.device(), ", got ", describe(grid));
  TORCH_CHECK(!grid.requires_grad(), "sample_fixed_planes: the grid is fixed; it must not require a gradient");
  TORCH_CHECK(reads.planes == planes.size(0) && reads.height == planes.size(2) && reads.width == planes.size(3) &&
                  reads.count == grid.size(1) && reads.weights.defined() &&
                  reads.weights.scalar_type() == planes.scalar_type() && reads.weights.device() == planes.device(),
              "sample_fixed_planes: the reads were made for ", reads.planes, " planes of ", reads.height, " x ",
              reads.width, " at ", reads.count, " points (", describe(reads.weights), "), not for planes ",
              describe(planes), " at ", grid.size(1), " points");
  const ReadTensors r = read_tensors(reads);
  return sample_op().call(planes, grid, r.chunk_rows, r.chunk_begins, r.chunk_ends, r.points, r.weights);
}

at::Tensor sample_fixed_planes_at_time(const at::Tensor& planes, const at::Tensor& positions, const at::Tensor& time,
                                       const PlaneReads& reads) {
  check_planes(planes, "sample_fixed_planes_at_time");
  TORCH_CHECK(positions.defined() && positions.dim() == 2 && positions.size(0) == planes.size(0) &&
                  positions.scalar_type() == planes.scalar_type() && positions.device() == planes.device() &&
                  !positions.requires_grad(),
              "sample_fixed_planes_at_time: the positions must be a fixed ", planes.scalar_type(), " (", planes.size(0),
              ", N) tensor on ", planes.device(), " without a gradient, got ", describe(positions));
  TORCH_CHECK(time.defined() && time.dim() == 0 && time.scalar_type() == planes.scalar_type() &&
                  time.device() == planes.device() && !time.requires_grad(),
              "sample_fixed_planes_at_time: the time must be a 0-dim ", planes.scalar_type(), " tensor on ",
              planes.device(), " without a gradient, got ", describe(time));
  TORCH_CHECK(reads.planes == planes.size(0) && reads.height == 1 && reads.width == planes.size(3) &&
                  reads.count == positions.size(1) && reads.weights.defined() &&
                  reads.weights.scalar_type() == planes.scalar_type() && reads.weights.device() == planes.device(),
              "sample_fixed_planes_at_time: the reads were made for ", reads.planes, " planes of ", reads.height, " x ",
              reads.width, " at ", reads.count, " points, not for one line along the width of planes ",
              describe(planes), " at ", positions.size(1), " points");
  const ReadTensors r = read_tensors(reads);
  return sample_at_time_op().call(planes, positions, time, r.chunk_rows, r.chunk_begins, r.chunk_ends, r.points,
                                  r.weights);
}

TORCH_LIBRARY_FRAGMENT(sfgs, m) {
  m.def(kSampleSchema.c_str());
  m.def(kSampleAtTimeSchema.c_str());
  m.def(kGradientSchema.c_str());
}
TORCH_LIBRARY_IMPL(sfgs, CPU, m) {
  m.impl("sample_fixed_planes", TORCH_FN(sample_kernel));
  m.impl("sample_fixed_planes_at_time", TORCH_FN(sample_at_time_kernel));
  m.impl("plane_reads_gradient", TORCH_FN(gradient_kernel));
}
#if defined(SFGS_WITH_CUDA)
TORCH_LIBRARY_IMPL(sfgs, CUDA, m) {
  m.impl("sample_fixed_planes", TORCH_FN(sample_kernel));
  m.impl("sample_fixed_planes_at_time", TORCH_FN(sample_at_time_kernel));
  m.impl("plane_reads_gradient", TORCH_FN(gradient_kernel));
}
#endif
TORCH_LIBRARY_IMPL(sfgs, Meta, m) {
  m.impl("sample_fixed_planes", TORCH_FN(sample_meta));
  m.impl("sample_fixed_planes_at_time", TORCH_FN(sample_at_time_meta));
  m.impl("plane_reads_gradient", TORCH_FN(gradient_meta));
}
TORCH_LIBRARY_IMPL(sfgs, Autograd, m) {
  m.impl("sample_fixed_planes", TORCH_FN(sample_autograd));
  m.impl("sample_fixed_planes_at_time", TORCH_FN(sample_at_time_autograd));
}

}  // namespace sfgs::plane_sampling
