#include "animate/batch_animator.h"

#include <algorithm>
#include <optional>
#include <utility>

#include <ATen/ATen.h>
#include <c10/core/Event.h>
#include <c10/core/Stream.h>
#include <c10/core/StreamGuard.h>
#include <c10/core/impl/VirtualGuardImpl.h>

#include "common/tensor_description.h"

namespace sfgs::animate {

struct BatchAnimator::Lane {
  Lane(model::Avatar avatar, const Camera& camera, const at::Tensor& background, const AnimatorOptions& options,
       std::optional<c10::Stream> own_stream)
      : animator(std::move(avatar), camera, background, options), stream(own_stream) {}
  Animator animator;
  std::optional<c10::Stream> stream;  // CUDA: the lane's own stream; CPU: none (the current one)
  int64_t pending = -1;               // the batch index of the frame submitted and not yet collected
};

BatchAnimator::BatchAnimator(model::Avatar avatar, const at::Tensor& background, AnimatorOptions options, int64_t lanes)
    : avatar_(std::move(avatar)), background_(background), options_(options), max_lanes_(lanes) {
  TORCH_CHECK(lanes >= 1, "BatchAnimator: lanes must be at least 1, got ", lanes);
}

// A lane's last copies may still be queued when the caller drops the batch renderer; they read its recording's memory.
BatchAnimator::~BatchAnimator() {
  for (const auto& l : lanes_)
    if (l->stream) l->stream->synchronize();
}

BatchAnimator::Lane& BatchAnimator::lane(size_t index, const Camera& camera) {
  while (lanes_.size() <= index) {
    const at::Device device = avatar_->part_labels().device();
    std::optional<c10::Stream> stream;
    if (device.is_cuda()) stream = c10::impl::VirtualGuardImpl(device.type()).getStreamFromGlobalPool(device);
    lanes_.push_back(std::make_unique<Lane>(avatar_, camera, background_, options_, stream));
  }
  Lane& l = *lanes_[index];
  l.animator.set_camera(camera);
  return l;
}

void BatchAnimator::set_background(const at::Tensor& background) {
  for (auto& l : lanes_) l->animator.set_background(background);
  background_ = background;
}

AnimatorStats BatchAnimator::stats() const {
  AnimatorStats sum;
  for (const auto& l : lanes_) {
    const AnimatorStats& s = l->animator.stats();
    sum.frames += s.frames;
    sum.graph_frames += s.graph_frames;
    sum.captures += s.captures;
    sum.budget_overflows += s.budget_overflows;
    sum.intersections = s.intersections;
    sum.budget = std::max(sum.budget, s.budget);
  }
  return sum;
}

RenderResult BatchAnimator::render(const std::vector<BatchFrame>& frames) {
  TORCH_CHECK(!frames.empty(), "BatchAnimator: a batch needs at least one frame, got none");
  const int64_t height = frames.front().camera.height, width = frames.front().camera.width;
  for (size_t b = 0; b < frames.size(); ++b)
    TORCH_CHECK(frames[b].camera.height == height && frames[b].camera.width == width, "BatchAnimator: frame ", b,
                "'s camera is ", frames[b].camera.width, "x", frames[b].camera.height, ", frame 0's ", width, "x",
                height, "; a batch is stacked, so every camera needs one image size");
  const at::Device device = avatar_->part_labels().device();
  const size_t lane_count = std::min<size_t>(frames.size(), size_t(max_lanes_));
  for (size_t k = 0; k < lane_count; ++k) lane(k, frames[k].camera);

  const c10::impl::VirtualGuardImpl guard_impl(device.type());
  // One frame runs on the caller's stream: with nothing to overlap, the hand-over between streams would only cost.
  const bool streams = device.is_cuda() && frames.size() > 1;
  const c10::Stream caller = guard_impl.getStream(device);
  const auto stream_of = [&](const Lane& l) { return streams ? *l.stream : caller; };
  if (streams) {
    // The lanes read the avatar only after the caller's work queued so far (an optimiser step, say).
    c10::Event queued(device.type());
    queued.record(caller);
    for (size_t k = 0; k < lane_count; ++k) queued.block(*lanes_[k]->stream);
  }

  RenderResult out;
  std::optional<c10::Event> outputs_ready;
  std::vector<bool> waited_for_outputs(lane_count, false);
  // The lane's finished frame into its slot, queued on the lane's stream before the lane's next frame can overwrite
  // it. The outputs are made on the caller's stream, so each lane waits for their allocation once.
  const auto collect = [&](size_t k) {
    Lane& l = *lanes_[k];
    const int64_t b = l.pending;
    l.pending = -1;  // collected, or failed: either way not the next batch's
    const RenderResult& r = l.animator.finish();
    if (!out.image.defined()) {
      const c10::StreamGuard on_caller(caller);
      const int64_t count = int64_t(frames.size());
      out.image = at::empty({count, height, width, r.image.size(2)}, r.image.options());
      out.alpha = at::empty({count, height, width}, r.alpha.options());
      out.depth = at::empty({count, height, width}, r.depth.options());
      out.radii = at::empty({count, r.radii.size(0), r.radii.size(1)}, r.radii.options());
      out.visible = at::empty({count, r.visible.size(0)}, r.visible.options());
      if (streams) {
        outputs_ready.emplace(device.type());
        outputs_ready->record(caller);
      }
    }
    if (streams && !waited_for_outputs[k]) {
      outputs_ready->block(*l.stream);
      waited_for_outputs[k] = true;
    }
    out.image[b].copy_(r.image);
    out.alpha[b].copy_(r.alpha);
    out.depth[b].copy_(r.depth);
    out.radii[b].copy_(r.radii);
    out.visible[b].copy_(r.visible);
  };
  // On every way out, an error included: the lanes' frames still queued are finished and dropped (the next batch
  // starts clean), and the caller's stream waits for each lane's work, so that the outputs (the caller's, or freed by
  // an error) are never reused while a lane still writes them.
  const auto hand_back = [&] {
    for (size_t k = 0; k < lane_count; ++k) {
      Lane& l = *lanes_[k];
      const c10::StreamGuard on_lane(stream_of(l));
      if (l.pending >= 0) {
        l.pending = -1;
        try {
          l.animator.finish();
        } catch (...) {  // the error being handed on is the first one
        }
      }
      if (streams) {
        c10::Event done(device.type());
        done.record(*l.stream);
        done.block(caller);
      }
    }
  };

  try {
    for (size_t b = 0; b < frames.size(); ++b) {
      const size_t k = b % lane_count;
      Lane& l = *lanes_[k];
      const c10::StreamGuard on_lane(stream_of(l));
      if (l.pending >= 0) collect(k);
      l.animator.set_camera(frames[b].camera);
      l.animator.submit(frames[b].pose, frames[b].time);
      l.pending = int64_t(b);
    }
    for (size_t k = 0; k < lane_count; ++k) {
      const c10::StreamGuard on_lane(stream_of(*lanes_[k]));
      if (lanes_[k]->pending >= 0) collect(k);
    }
  } catch (...) {
    hand_back();
    throw;
  }
  hand_back();
  return out;
}

}  // namespace sfgs::animate
