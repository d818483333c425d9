#pragma once
// GPU work recorded once as a CUDA graph and replayed as one launch (at::cuda::CUDAGraph): an animated frame
// (animate::Animator) or a training step (train/step_graphs.h). Only the CUDA build can capture; elsewhere
// device_graphs_available() is false and capture refuses.
#include <functional>
#include <memory>
#include <stdexcept>

namespace sfgs {

class DeviceGraph {
 public:
  virtual ~DeviceGraph() = default;
  // Queues the recorded work on the current stream of the device it was captured on.
  virtual void replay() = 0;
};

bool device_graphs_available();

// A point in the current CUDA stream's queue: wait() blocks the host until the work queued before it is done, and
// not the work queued after it (which a read of device memory would wait for too). The recorded training steps read
// their splatting counts this way one step late, so the host never waits for the step it has just queued.
class DeviceEvent {
 public:
  virtual ~DeviceEvent() = default;
  virtual void wait() = 0;
};

// Records one on the current stream of the current CUDA device (the CUDA build only).
std::unique_ptr<DeviceEvent> record_device_event();

// The recorded run of capture_device_graph failed (it synchronised with the host, read host memory, ...): the work
// cannot be recorded. Errors of the eager run before it come as they are.
class GraphCaptureError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// Runs `work` eagerly on a side stream of the current CUDA device, then once more while recording it there: the
// recorded run executes nothing until replay(). The work must queue device work only (no host synchronisation, no
// host reads of device memory, no uploads from pageable host memory, no values that change between replays except
// in device tensors it reads). Tensors it allocates come from the graph's private memory pool and keep their
// addresses across replays. The allocator's unused cached blocks are returned to the driver before each run. A
// failure of the recorded run comes as GraphCaptureError.
//
// `share_pool_with` (optional) records into that graph's pool, on its stream, so graphs that never run at the same
// time reuse each other's intermediates. Safe only while every tensor a graph's replays write that outlives its capture
// (its outputs) is kept alive as long as the graph: the pool never hands out a live block, but it does hand out a block
// a graph wrote if that graph's reference to it was dropped.
std::unique_ptr<DeviceGraph> capture_device_graph(const std::function<void()>& work,
                                                  DeviceGraph* share_pool_with = nullptr);

}  // namespace sfgs
