#include "train/pose_fit_evaluation.h"

#include <iomanip>
#include <sstream>

#include <ATen/ATen.h>
#include <torch/csrc/autograd/autograd.h>

#include "ops/splat/constants.h"
#include "train/constants.h"
#include "common/tensor_description.h"
#include "train/pose_refinement.h"

namespace sfgs::train {

FitLoss::FitLoss(const ImageLoss& image_loss, const body::WholeBodyKeypointMap* keypoint_map, double keypoint_weight,
                 model::PoseGradient gradient)
    : image_loss_(image_loss), keypoint_map_(keypoint_map), keypoint_weight_(keypoint_weight), gradient_(gradient) {}

at::Tensor FitLoss::operator()(model::Avatar& avatar, const FitFrame& frame, const at::Tensor& correction,
                               bool run_loss, const BinningBudget* budget) const {
  const model::AvatarOutput out = avatar->forward_with_attributes(corrected_pose(frame.pose, correction),
                                                                  frame.attributes, frame.has_time, gradient_);
  Gaussians gaussians = model::to_gaussians(out);
  if (frame.camera_frame.defined()) {
    gaussians.means = frame.camera_frame.points(gaussians.means);
    gaussians.covariances = frame.camera_frame.covariances(gaussians.covariances);
  }
  RenderOptions options;
  options.budget = budget;
  const RenderResult r = render(gaussians, at::ones({3}, correction.options()), frame.camera, options);
  at::Tensor loss = image_terms(r, frame, run_loss);
  if (frame.pixel_share != 1) loss = loss * frame.pixel_share;
  if (!keypoint_map_ || !frame.keypoints.defined()) return loss;
  return loss + keypoint_weight_ * keypoint_reprojection_loss(*keypoint_map_, avatar, out, frame.keypoints);
}

at::Tensor FitLoss::image_terms(const RenderResult& r, const FitFrame& frame, bool run_loss) const {
  at::Tensor loss;
  if (!run_loss) {
    loss = (r.image - frame.image).abs().mean();
    if (frame.mask.defined()) loss = loss + kPoseFitSilhouetteWeight * (r.alpha - frame.mask).abs().mean();
  } else if (!frame.mask.defined()) {
    LossTerms terms;
    image_loss_.add_terms(r.image, frame.image, terms);
    loss = total_loss(terms);
  } else {
    // The image inside the person, as the evaluation protocol sees it, and the silhouette.
    LossTerms terms;
    const at::Tensor m = frame.mask.unsqueeze(2);
    image_loss_.add_terms(r.image * m + (1 - m), frame.image, terms);
    loss = total_loss(terms) + kPoseFitFineSilhouetteWeight * (r.alpha - frame.mask).abs().mean();
  }
  return loss;
}

namespace {

// The tensors of a frame's attributes in a fixed order (undefined where the avatar has no such part).
std::vector<at::Tensor*> attribute_fields(model::CanonicalAttributes& a) {
  return {&a.mean_offset,          &a.log_scales,        &a.colour_logits,
          &a.structure_projection, &a.colour_projection, &a.structure_projection_half};
}

std::vector<at::Tensor*> keypoint_fields(FrameKeypoints& k) {
  return {&k.observed.pixels,     &k.observed.confidence, &k.observed.person_size,
          &k.observed.intrinsics, &k.world_to_camera,     &k.weights};
}

void describe_fields(std::ostream& key, const std::vector<at::Tensor*>& fields) {
  for (const at::Tensor* t : fields) key << (t->defined() ? describe(*t) : std::string("-")) << ';';
}

// What a recorded evaluation bakes in besides the values it reads from its buffers.
std::string kind_of(const FitFrame& frame, bool run_loss) {
  FitFrame f = frame;
  const Camera& c = frame.camera;
  std::ostringstream key;
  key << std::setprecision(17) << "run_loss " << run_loss << " time " << frame.has_time << " pose "
      << frame.pose.layout() << " camera " << c.fx << ',' << c.fy << ',' << c.cx << ',' << c.cy << ',' << c.width << ','
      << c.height << ',' << c.near_plane << ',' << c.far_plane << " share " << frame.pixel_share << " image "
      << describe(frame.image) << " mask " << (frame.mask.defined() ? describe(frame.mask) : "-") << " attributes ";
  describe_fields(key, attribute_fields(f.attributes));
  key << " keypoints ";
  describe_fields(key, keypoint_fields(f.keypoints));
  return key.str();
}

void copy_fields(const std::vector<at::Tensor*>& into, const std::vector<at::Tensor*>& from) {
  for (size_t k = 0; k < into.size(); ++k)
    if (into[k]->defined()) into[k]->copy_(*from[k]);
}

void clone_fields(const std::vector<at::Tensor*>& into, const std::vector<at::Tensor*>& from) {
  for (size_t k = 0; k < into.size(); ++k)
    if (from[k]->defined()) *into[k] = from[k]->detach().clone();
}

}  // namespace

// One kind of stage: the buffers its recorded evaluation reads and the outputs its replays write.
struct PoseFitGraphs::Kind {
  bool run_loss = false;
  FitFrame frame;            // views of the buffers below and copies of the loaded frame's tensors
  at::Tensor pose_values;    // the frame's fit, packed (SmplxPose::packed)
  at::Tensor camera_values;  // the camera's placement (write_camera_frame)
  at::Tensor correction;     // (kCorrectionWidth) leaf with a gradient
  std::unique_ptr<DeviceGraph> graph;
  at::Tensor outputs;  // the graph's: the loss, then its gradient
};

PoseFitGraphs::PoseFitGraphs(model::Avatar avatar, const FitLoss& loss, at::Device device)
    : avatar_(std::move(avatar)), loss_(loss), device_(device), budget_(device, kGraphBudgetSlack, "pose fitting") {
  TORCH_CHECK(device.is_cuda() && device_graphs_available(),
              "PoseFitGraphs: recording needs a CUDA device and a CUDA build, got ", device);
}

PoseFitGraphs::~PoseFitGraphs() = default;

void PoseFitGraphs::load(const FitFrame& frame, bool run_loss) {
  TORCH_CHECK(!frame.camera_frame.defined(), "PoseFitGraphs::load: the frame's camera is placed by its buffers");
  // The principal point travels with the placement: crops of one size around different people share a kind.
  FitFrame given = frame;
  given.camera = with_centred_principal_point(frame.camera);
  std::unique_ptr<Kind>& slot = kinds_[kind_of(given, run_loss)];
  const at::Tensor pose_values = frame.pose.packed();
  at::Tensor placement = at::empty({kCameraFrameValues}, at::kFloat);
  write_camera_frame(given.camera, placement.data_ptr<float>());
  at::NoGradGuard no_grad;
  if (slot) {
    // A kind seen before: the frame's values into its buffers.
    Kind& k = *slot;
    copy_fields(attribute_fields(k.frame.attributes), attribute_fields(given.attributes));
    k.frame.image.copy_(frame.image);
    if (frame.mask.defined()) k.frame.mask.copy_(frame.mask);
    copy_fields(keypoint_fields(k.frame.keypoints), keypoint_fields(given.keypoints));
  } else {
    // A new kind: buffers made from the frame itself.
    slot = std::make_unique<Kind>();
    Kind& k = *slot;
    const auto options = at::TensorOptions(device_).dtype(at::kFloat);
    k.run_loss = run_loss;
    k.pose_values = at::empty({pose_values.size(0)}, options);
    k.frame.pose = frame.pose.views_of(k.pose_values);
    clone_fields(attribute_fields(k.frame.attributes), attribute_fields(given.attributes));
    k.frame.has_time = frame.has_time;
    k.camera_values = at::empty({kCameraFrameValues}, options);
    k.frame.camera_frame = CameraFrame(k.camera_values);
    k.frame.camera = camera_at_origin_of(given.camera);
    k.frame.pixel_share = frame.pixel_share;
    k.frame.image = frame.image.detach().clone();
    if (frame.mask.defined()) k.frame.mask = frame.mask.detach().clone();
    clone_fields(keypoint_fields(k.frame.keypoints), keypoint_fields(given.keypoints));
    k.correction = at::zeros({kCorrectionWidth}, options).requires_grad_(true);
  }
  slot->pose_values.copy_(pose_values);
  slot->camera_values.copy_(placement);
  loaded_ = slot.get();
}

FitEvaluation PoseFitGraphs::evaluate(const at::Tensor& correction) {
  TORCH_CHECK(loaded_, "PoseFitGraphs::evaluate: load() a frame first");
  TORCH_CHECK(correction.dim() == 1 && correction.size(0) == kCorrectionWidth,
              "PoseFitGraphs::evaluate: a correction has ", kCorrectionWidth, " values, got ", describe(correction));
  Kind& k = *loaded_;
  {
    at::NoGradGuard no_grad;
    k.correction.detach().copy_(correction);
  }
  const auto download = [](const at::Tensor& outputs) {
    const at::Tensor host = outputs.cpu();
    return FitEvaluation{host[0].item<double>(), host.narrow(0, 1, kCorrectionWidth)};
  };
  for (;;) {
    if (!budget_.measured()) {
      // No evaluation has measured the splatting yet: an eager one under a guess. If it fitted, it is this one.
      const at::Tensor outputs = run_budgeted(k);
      const BinningCounts counts = budget_.read();
      const bool fitted = budget_.fits(counts);
      budget_.grow(counts);
      if (fitted) return download(outputs);
      continue;
    }
    if (!k.graph) capture(k);
    k.graph->replay();
    // One wait for the loss, the gradient and the counts: L-BFGS decides its next point on the host anyway.
    const auto pinned = at::TensorOptions().pinned_memory(true);
    at::Tensor outputs = at::empty({k.outputs.size(0)}, pinned.dtype(at::kFloat));
    at::Tensor counts = at::empty({BinningBudget::kCounts}, pinned.dtype(at::kLong));
    outputs.copy_(k.outputs, /*non_blocking=*/true);
    counts.copy_(budget_.device_counts(), /*non_blocking=*/true);
    record_device_event()->wait();
    const BinningCounts read = budget_.counts_from(counts);
    if (budget_.fits(read)) return FitEvaluation{outputs[0].item<double>(), outputs.narrow(0, 1, kCorrectionWidth)};
    // An incomplete image: a larger budget, recorded again, and the same point evaluated again.
    budget_.grow(read);
    drop_graphs();
  }
}

at::Tensor PoseFitGraphs::run_budgeted(Kind& k) {
  const BinningBudget budget = budget_.budget(avatar_->gaussian_count());
  const at::Tensor loss = loss_(avatar_, k.frame, k.correction, k.run_loss, &budget);
  // The gradient of the correction alone: the frozen avatar's parameters accumulate none.
  const at::Tensor gradient = torch::autograd::grad({loss}, {k.correction})[0];
  return at::cat({loss.detach().reshape({1}).to(at::kFloat), gradient.detach().to(at::kFloat)});
}

void PoseFitGraphs::capture(Kind& k) {
  // Every kind records into the first one's pool: evaluations never run at once, and each graph keeps its outputs.
  DeviceGraph* pool = nullptr;
  for (auto& [name, other] : kinds_)
    if (other->graph) pool = other->graph.get();
  at::Tensor recorded;
  try {
    k.graph = capture_device_graph([&] { recorded = run_budgeted(k); }, pool);
  } catch (const GraphCaptureError&) {
    drop_graphs();
    throw;
  }
  k.outputs = recorded;
  ++captures_;
}

void PoseFitGraphs::drop_graphs() {
  for (auto& [name, kind] : kinds_) {
    kind->graph.reset();
    kind->outputs = at::Tensor();
  }
}

}  // namespace sfgs::train
