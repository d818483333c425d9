#include <ATen/cuda/CUDAContext.h>
#include <ATen/cuda/CUDAEvent.h>
#include <ATen/cuda/CUDAGraph.h>
#include <c10/cuda/CUDACachingAllocator.h>
#include <c10/cuda/CUDAGuard.h>
#include <c10/cuda/CUDAStream.h>

#include "common/device_graph.h"

namespace sfgs {
namespace {

class CudaDeviceGraph : public DeviceGraph {
 public:
  explicit CudaDeviceGraph(c10::cuda::CUDAStream stream) : stream_(stream) {}
  void replay() override { graph_.replay(); }
  at::cuda::CUDAGraph& graph() { return graph_; }
  const c10::cuda::CUDAStream& stream() const { return stream_; }

 private:
  at::cuda::CUDAGraph graph_;
  c10::cuda::CUDAStream stream_;  // the side stream it was recorded on
};

class CudaDeviceEvent : public DeviceEvent {
 public:
  CudaDeviceEvent() { event_.record(c10::cuda::getCurrentCUDAStream()); }
  void wait() override { event_.synchronize(); }

 private:
  at::cuda::CUDAEvent event_;  // without timing: the cheapest kind
};

}  // namespace

bool device_graphs_available() { return true; }

std::unique_ptr<DeviceEvent> record_device_event() { return std::make_unique<CudaDeviceEvent>(); }

std::unique_ptr<DeviceGraph> capture_device_graph(const std::function<void()>& work, DeviceGraph* share_pool_with) {
  CudaDeviceGraph* shared = static_cast<CudaDeviceGraph*>(share_pool_with);
  // Capture cannot happen on the legacy default stream; the work queued before it must be done first. One eager run
  // on the side stream first makes every lazy one-time allocation (cuBLAS workspaces, the work's own caches) outside
  // the graph. A graph that shares another's pool is recorded on that graph's stream.
  const c10::cuda::CUDAStream side = shared ? shared->stream() : c10::cuda::getStreamFromPool();
  auto recorded = std::make_unique<CudaDeviceGraph>(side);
  const at::cuda::MempoolId_t pool = shared ? shared->graph().pool() : at::cuda::MempoolId_t{0, 0};
  c10::cuda::getCurrentCUDAStream().synchronize();
  // Memory cached but unused (eager work's, or the pools of dropped graphs) goes back to the driver before each run,
  // so a new pool does not come on top of it.
  c10::cuda::CUDACachingAllocator::emptyCache();
  {
    const c10::cuda::CUDAStreamGuard on_side(side);
    work();
    side.synchronize();
    c10::cuda::CUDACachingAllocator::emptyCache();
    recorded->graph().capture_begin(pool);
    try {
      work();
      recorded->graph().capture_end();
    } catch (const std::exception& e) {
      // End the capture so the stream is usable again; the graph is dropped, and the work's error is the one told
      // (ending an invalidated capture reports its own).
      try {
        recorded->graph().capture_end();
      } catch (...) {
      }
      throw GraphCaptureError(e.what());
    }
  }
  side.synchronize();
  return recorded;
}

}  // namespace sfgs
