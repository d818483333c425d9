#pragma once
// LibTorch's choice of TF32 for CUDA float32 matrix products (tensor cores: float32's range, a 10-bit mantissa,
// float32 accumulation), set for a scope and restored after it: the training session's steps
// (`schedule.tf32_matmul`) and the avatar's inference frames on CUDA, whose networks' float32 products took 2.7 of a
// replayed frame's 6 ms on an H200 (docs/performance.md). A process that chose its precision through a mix of
// LibTorch's two ways of setting it (which LibTorch refuses to read) is left as it is.
namespace sfgs {

class Tf32MatmulScope {
 public:
  explicit Tf32MatmulScope(bool allow);
  ~Tf32MatmulScope();
  Tf32MatmulScope(const Tf32MatmulScope&) = delete;
  Tf32MatmulScope& operator=(const Tf32MatmulScope&) = delete;

 private:
  bool changed_ = false;
  bool previous_ = false;
};

}  // namespace sfgs
