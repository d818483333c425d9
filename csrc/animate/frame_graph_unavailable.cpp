// Builds without a CUDA LibTorch: nothing can be captured; the Animator runs its frames eagerly.
#include <c10/util/Exception.h>

#include "animate/frame_graph.h"

namespace sfgs::animate {

bool frame_graphs_available() { return false; }

std::unique_ptr<FrameGraph> capture_frame_graph(const std::function<void()>&) {
  TORCH_CHECK(false, "sfgs: this build has no CUDA backend, so it cannot capture CUDA graphs");
}

}  // namespace sfgs::animate
