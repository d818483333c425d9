#pragma once
// A frame's GPU work recorded once as a CUDA graph and replayed as one launch (at::cuda::CUDAGraph). Only the CUDA
// build can capture; elsewhere frame_graphs_available() is false and capture refuses.
#include <functional>
#include <memory>

namespace sfgs::animate {

class FrameGraph {
 public:
  virtual ~FrameGraph() = default;
  // Queues the recorded work on the current stream of the device it was captured on.
  virtual void replay() = 0;
};

bool frame_graphs_available();

// Runs `work` eagerly on a side stream of the current CUDA device, then once more while recording it there: the
// recorded run executes nothing until replay(). The work must queue device
// work only (no host synchronisation, no host reads of device memory, no CPU tensors that change between frames).
// Tensors it allocates come from the graph's private memory pool and keep their addresses across replays.
std::unique_ptr<FrameGraph> capture_frame_graph(const std::function<void()>& work);

}  // namespace sfgs::animate
