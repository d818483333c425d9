// CUDA backend of the gathered first layer: the torch side of gathered_first_layer_kernels.h, queued on the device's
// current stream.
#include "cuda/launch_on_device.h"
#include "ops/gathered_mlp/gathered_first_layer_kernels.h"
#include "ops/gathered_mlp/backend.h"

namespace sfgs::gathered_mlp::cuda {
using cuda_glue::launch_on_device;

int64_t first_layer_partial_rows(int64_t rows, at::Device device) {
  return cuda_kernels::first_layer_backward_blocks(rows, device.index());
}
void first_layer_forward(const FirstLayerArrays<float>& a, at::Device d) {
  launch_on_device(a, d, cuda_kernels::first_layer_forward<float>);
}
void first_layer_forward(const FirstLayerArrays<double>& a, at::Device d) {
  launch_on_device(a, d, cuda_kernels::first_layer_forward<double>);
}
void first_layer_backward(const FirstLayerGradientArrays<float>& a, at::Device d) {
  launch_on_device(a, d, cuda_kernels::first_layer_backward<float>);
}
void first_layer_backward(const FirstLayerGradientArrays<double>& a, at::Device d) {
  launch_on_device(a, d, cuda_kernels::first_layer_backward<double>);
}

}  // namespace sfgs::gathered_mlp::cuda
