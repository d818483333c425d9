// The fixed-point plane sampling: the reads, validation at the boundary, and the one autograd node.
#include "ops/plane_sampling/plane_sampling.h"

#include <limits>

#include <ATen/ATen.h>
#include <torch/csrc/autograd/custom_function.h>

#include "common/constants.h"
#include "common/tensor_description.h"
#include "ops/plane_sampling/backend.h"

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

template <typename T>
void gradient_as(const PlaneReads& r, const at::Tensor& grad_features, const at::Tensor& grad_planes) {
  PlaneGradientArrays<T> a{};
  a.grad_features = grad_features.data_ptr<T>();
  a.chunk_rows = r.chunk_rows.data_ptr<int32_t>();
  a.chunk_begins = r.chunk_begins.data_ptr<int32_t>();
  a.chunk_ends = r.chunk_ends.data_ptr<int32_t>();
  a.points = r.points.data_ptr<int32_t>();
  a.weights = r.weights.data_ptr<T>();
  a.grad_planes = grad_planes.data_ptr<T>();
  a.chunks = r.chunk_rows.size(0);
  a.planes = r.planes;
  a.channels = grad_planes.size(1);
  a.texels = r.height * r.width;
  if (grad_planes.is_cuda())
    cuda::gradient(a, grad_planes.device());
  else
    cpu::gradient(a);
}

// The planes' gradient (P, C, H, W) of the reads' incoming gradients (N, P C): the gather of every texel's reads.
at::Tensor gathered_gradient(const PlaneReads& reads, const at::Tensor& grad_output, int64_t channels) {
  const at::Tensor grad_features = grad_output.contiguous();
  at::Tensor grad_planes = at::zeros({reads.planes, channels, reads.height, reads.width}, grad_features.options());
  if (reads.chunk_rows.size(0) > 0) {
    if (grad_features.scalar_type() == at::kDouble)
      gradient_as<double>(reads, grad_features, grad_planes);
    else
      gradient_as<float>(reads, grad_features, grad_planes);
  }
  return grad_planes;
}

// What the backward needs of the forward, typed: the reads as saved tensors in a fixed order, and the planes' shape.
struct SavedReads {
  static variable_list list(const PlaneReads& r) {
    return {r.chunk_rows, r.chunk_begins, r.chunk_ends, r.points, r.weights};
  }
  static PlaneReads from(const variable_list& v, int64_t planes, int64_t height, int64_t width, int64_t count) {
    return PlaneReads{v[0], v[1], v[2], v[3], v[4], planes, height, width, count};
  }
};

class SampleFixedPlanes : public torch::autograd::Function<SampleFixedPlanes> {
 public:
  static at::Tensor forward(AutogradContext* ctx, const at::Tensor& planes, const at::Tensor& grid,
                            const PlaneReads& reads) {
    ctx->save_for_backward(SavedReads::list(reads));
    ctx->saved_data["shape"] =
        std::vector<int64_t>{planes.size(0), planes.size(1), planes.size(2), planes.size(3), reads.count};
    return sample_planes(planes, grid);
  }

  static variable_list backward(AutogradContext* ctx, variable_list grads) {
    const std::vector<int64_t> shape = ctx->saved_data["shape"].toIntVector();
    const PlaneReads reads = SavedReads::from(ctx->get_saved_variables(), shape[0], shape[2], shape[3], shape[4]);
    return {gathered_gradient(reads, grads[0], shape[1]), at::Tensor(), at::Tensor()};
  }
};

// The time planes' node: the forward reads at (position, time); the backward gathers along the positions' line and
// shares the result between the two time rows around the time.
class SampleFixedPlanesAtTime : public torch::autograd::Function<SampleFixedPlanesAtTime> {
 public:
  static at::Tensor forward(AutogradContext* ctx, const at::Tensor& planes, const at::Tensor& positions,
                            const at::Tensor& time, const PlaneReads& reads) {
    variable_list saved = SavedReads::list(reads);
    saved.push_back(time);
    ctx->save_for_backward(saved);
    ctx->saved_data["shape"] =
        std::vector<int64_t>{planes.size(0), planes.size(1), planes.size(2), planes.size(3), reads.count};
    return sample_planes(planes, time_grid(positions, time));
  }

  static variable_list backward(AutogradContext* ctx, variable_list grads) {
    const std::vector<int64_t> shape = ctx->saved_data["shape"].toIntVector();
    const variable_list saved = ctx->get_saved_variables();
    const PlaneReads reads = SavedReads::from(saved, shape[0], 1, shape[3], shape[4]);
    const at::Tensor along_line = gathered_gradient(reads, grads[0], shape[1]);  // (P, C, 1, W)
    // The time's two rows and their weights, on the device: grid_sample's border clip and bilinear weights.
    const int64_t rows = shape[2];
    const at::Tensor row = pixel_position(saved.back(), rows), first = row.floor();
    const at::Tensor share = (row - first).to(along_line.scalar_type());
    const at::Tensor first_row = first.to(at::kLong).view({1});
    const at::Tensor second_row = (first_row + 1).clamp_max(rows - 1);  // its share is 0 on the last row
    at::Tensor grad_planes = at::zeros({shape[0], shape[1], rows, shape[3]}, along_line.options());
    grad_planes.index_add_(2, first_row, along_line * (1 - share));
    grad_planes.index_add_(2, second_row, along_line * share);
    return {grad_planes, at::Tensor(), at::Tensor(), at::Tensor()};
  }
};

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
  return SampleFixedPlanes::apply(planes, grid, reads);
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
  return SampleFixedPlanesAtTime::apply(planes, positions, time, reads);
}

}  // namespace sfgs::plane_sampling
