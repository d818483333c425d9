// CUDA column sum of the linear layer: the torch side of column_sum_kernels.h, queued on the device's current
// stream.
#include <ATen/ATen.h>
#include <ATen/cuda/CUDAContext.h>
#include <c10/cuda/CUDAGuard.h>

#include "ops/linear/column_sum_kernels.h"
#include "ops/linear/backend.h"

namespace sfgs::linear::cuda {

at::Tensor column_sum(const at::Tensor& rows) {
  const c10::cuda::CUDAGuard guard(rows.device());
  const int64_t r = rows.size(0), c = rows.size(1);
  const at::Tensor out = at::empty({c}, rows.options());  // no rows: the one-pass launch writes zeros
  if (c == 0) return out;
  const int64_t chunks = cuda_kernels::chunks(r, c, rows.device().index());
  const at::Tensor partials = at::empty({chunks > 1 ? chunks : 0, c}, rows.options());
  const cudaStream_t stream = at::cuda::getCurrentCUDAStream();
  if (rows.scalar_type() == at::kDouble)
    cuda_kernels::column_sum(rows.data_ptr<double>(), r, c, partials.data_ptr<double>(), chunks, out.data_ptr<double>(),
                             stream);
  else
    cuda_kernels::column_sum(rows.data_ptr<float>(), r, c, partials.data_ptr<float>(), chunks, out.data_ptr<float>(),
                             stream);
  return out;
}

}  // namespace sfgs::linear::cuda
