// CUDA backend of the feature-fusion ops: the torch side of feature_fusion_kernels.h, queued on the device's current
// stream.
#include "cuda/launch_on_device.h"
#include "ops/feature_fusion/feature_fusion_kernels.h"
#include "ops/feature_fusion/backend.h"

namespace sfgs::feature_fusion::cuda {
using cuda_glue::launch_on_device;

void gated_mix(const GatedMixArrays<float>& a, at::Device d) { launch_on_device(a, d, cuda_kernels::gated_mix<float>); }
void gated_mix(const GatedMixArrays<double>& a, at::Device d) {
  launch_on_device(a, d, cuda_kernels::gated_mix<double>);
}
void gated_mix_backward(const GatedMixGradientArrays<float>& a, at::Device d) {
  launch_on_device(a, d, cuda_kernels::gated_mix_backward<float>);
}
void gated_mix_backward(const GatedMixGradientArrays<double>& a, at::Device d) {
  launch_on_device(a, d, cuda_kernels::gated_mix_backward<double>);
}
void gather_rows(const RowGatherArrays<float>& a, at::Device d) {
  launch_on_device(a, d, cuda_kernels::gather_rows<float>);
}
void gather_rows(const RowGatherArrays<double>& a, at::Device d) {
  launch_on_device(a, d, cuda_kernels::gather_rows<double>);
}

}  // namespace sfgs::feature_fusion::cuda
