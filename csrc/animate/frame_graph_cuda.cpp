#include <ATen/cuda/CUDAContext.h>
#include <ATen/cuda/CUDAGraph.h>
#include <c10/cuda/CUDAGuard.h>
#include <c10/cuda/CUDAStream.h>

#include "animate/frame_graph.h"

namespace sfgs::animate {
namespace {

class CudaFrameGraph : public FrameGraph {
 public:
  void replay() override { graph_.replay(); }
  at::cuda::CUDAGraph& graph() { return graph_; }

 private:
  at::cuda::CUDAGraph graph_;
};

}  // namespace

bool frame_graphs_available() { return true; }

std::unique_ptr<FrameGraph> capture_frame_graph(const std::function<void()>& work) {
  auto frame = std::make_unique<CudaFrameGraph>();
  // Capture cannot happen on the legacy default stream; the work queued before it must be done first. One eager run
  // on the side stream first makes the per-stream one-time allocations (cuBLAS workspaces) outside the graph.
  const c10::cuda::CUDAStream side = c10::cuda::getStreamFromPool();
  c10::cuda::getCurrentCUDAStream().synchronize();
  {
    const c10::cuda::CUDAStreamGuard on_side(side);
    work();
    side.synchronize();
    frame->graph().capture_begin();
    try {
      work();
    } catch (...) {
      // End the capture so the stream is usable again; the graph is dropped, and the work's error is the one told
      // (ending an invalidated capture reports its own).
      try {
        frame->graph().capture_end();
      } catch (...) {
      }
      throw;
    }
    frame->graph().capture_end();
  }
  side.synchronize();
  return frame;
}

}  // namespace sfgs::animate
