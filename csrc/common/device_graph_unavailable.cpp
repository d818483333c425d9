// Builds without a CUDA LibTorch: nothing can be captured; frames and training steps run eagerly.
#include <c10/util/Exception.h>

#include "common/device_graph.h"

namespace sfgs {

bool device_graphs_available() { return false; }

std::unique_ptr<DeviceGraph> capture_device_graph(const std::function<void()>&, DeviceGraph*) {
  TORCH_CHECK(false, "sfgs: this build has no CUDA backend, so it cannot capture CUDA graphs");
}

std::unique_ptr<DeviceEvent> record_device_event() {
  TORCH_CHECK(false, "sfgs: this build has no CUDA backend, so it records no CUDA events");
}

}  // namespace sfgs
