#pragma once
// Process-wide tuning of the C allocator for LibTorch's CPU work, for executables (not for the Python module, whose
// host process is not ours to tune).

namespace sfgs {

// glibc serves every block above its mmap threshold with a fresh mapping and unmaps it on free, so each training
// step page-faults its activations in again (at 254k Gaussians: 2.4-3.5x slower forward and backward, most of it
// kernel time). Keeping freed blocks in the heap for reuse avoids that; the process keeps its peak size.
void reuse_freed_host_memory();

}  // namespace sfgs
