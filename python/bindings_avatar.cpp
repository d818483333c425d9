// Python bindings of trained avatars: load a run, pose it, render it (one or a batch of frames), train it further.
#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <torch/extension.h>

#include "animate/batch_animator.h"
#include "animate/camera_placement.h"
#include "common/tensor_description.h"
#include "data/dataset.h"
#include "data/motion_file.h"
#include "model/sampling_filter.h"
#include "common/atomic_file.h"
#include "train/checkpoint.h"
#include "train/losses.h"
#include "train/run_folder.h"
#include "train/trainer.h"
#include "camera_arguments.h"
#include "python_values.h"

namespace sfgs::python {
namespace {

// The pose dict of the Python API: body::SmplxPose's fields by name, and "time".
using sfgs::body::SmplxPose;
struct FramePose {
  SmplxPose pose;
  sfgs::model::FrameTime time;  // none unless the dict gives one: a new motion (model/frame_time.h)
};

// Keys of earlier versions, accepted with a DeprecationWarning.
const std::pair<const char*, const char*> kRenamedPoseKeys[] = {{"left_eye_pose", "leye_pose"},
                                                                {"right_eye_pose", "reye_pose"}};

// A motion clip as Python takes it: its frames as pose dicts (Avatar.gaussians/render take them), and what it is.
py::dict motion_dict(const sfgs::data::MotionClip& clip, const std::vector<SmplxPose>& poses) {
  py::list frames;
  for (const SmplxPose& p : poses) {
    py::dict pose;
    for (const SmplxPose::Field& f : SmplxPose::fields())
      if ((p.*(f.member)).defined()) pose[f.name] = p.*(f.member);
    frames.append(pose);
  }
  py::dict out;
  out["frames"] = frames;
  out["fps"] = clip.frames_per_second;
  out["format"] = clip.format;
  out["note"] = clip.note;
  out["absolute_hands"] = clip.absolute_hands;
  return out;
}

// The clip read from `path`, resampled to `fps` when one is given (> 0).
sfgs::data::MotionClip read_clip(const std::string& path, double fps) {
  const sfgs::data::MotionClip clip = sfgs::data::read_motion(path);
  return fps > 0 ? sfgs::data::resample(clip, fps) : clip;
}

// A trained avatar for experiments: the run's checkpoint with its config, and the dataset it was trained on
// (read when first needed).
class TrainedAvatar {
 public:
  TrainedAvatar(const std::string& run, const std::string& device, const std::string& data, bool other_dataset)
      : device_(device == "cuda" ? at::kCUDA : at::kCPU), run_(run), data_(data), other_dataset_(other_dataset) {
    TORCH_CHECK(device == "cpu" || device == "cuda", "load_avatar: device must be 'cpu' or 'cuda', got '", device, "'");
    TORCH_CHECK(device_.is_cpu() || sfgs::cuda_backend_available(),
                "load_avatar: device 'cuda' but this build of sfgs has no CUDA backend");
    t_ = sfgs::train::load_trained_avatar(sfgs::train::RunFolder{run}, device_);
    t_.avatar->eval();
    parameters_version_ = parameters_version();
    if (!data_.empty()) dataset();  // a dataset given by the caller is checked now, not at its first frame
  }

  // Posed Gaussians and the canonical quantities, as a dict of tensors.
  py::dict gaussians(const py::object& pose) {
    refresh_if_changed();
    const FramePose p = to_pose(pose);
    const sfgs::model::AvatarOutput o = t_.avatar->forward(p.pose, p.time);
    py::dict d;
    d["means"] = o.means;
    d["covariances"] = o.covariances;
    d["opacities"] = o.opacities;
    d["colours"] = o.colours;
    d["canonical_means"] = o.canonical_means;
    d["log_scales"] = o.log_scales;
    d["posed_vertices"] = o.posed_vertices;
    return d;
  }

  std::array<double, 3> centre(const py::object& pose) {
    refresh_if_changed();
    const FramePose p = to_pose(pose);
    const at::NoGradGuard no_grad;
    return sfgs::animate::centre_of(t_.avatar->forward(p.pose, p.time));
  }

  // One frame, or a batch: `camera` and `pose` each one dict or a list of B dicts (one of them may be a single dict,
  // shared by every frame); a batch's outputs are stacked along a first dimension of B.
  py::dict render(const py::object& camera, const py::object& pose, const py::object& background) {
    const auto given = to_optional_tensor(background, "Avatar.render(background)");
    const bool camera_list = py::isinstance<py::list>(camera), pose_list = py::isinstance<py::list>(pose);
    if (!camera_list && !pose_list)
      return result_dict(render_frames({camera_argument(camera)}, {to_pose(pose)}, given));
    const int64_t count = int64_t(camera_list ? py::len(camera) : py::len(pose));
    TORCH_CHECK(count > 0, "Avatar.render: a batch needs at least one camera and pose, got an empty list");
    TORCH_CHECK(!camera_list || !pose_list || int64_t(py::len(pose)) == count, "Avatar.render: ", count,
                " cameras but ", py::len(pose), " poses; give as many of each, or one of either");
    std::vector<CameraArgument> cameras;
    std::vector<FramePose> poses;
    for (int64_t b = 0; b < count; ++b) {
      cameras.push_back(camera_argument(camera_list ? py::list(camera)[size_t(b)] : camera));
      poses.push_back(to_pose(pose_list ? py::list(pose)[size_t(b)] : pose));
    }
    return result_dict(render_frames(cameras, poses, given, true));
  }

  // The loss a training step takes on one frame, with the run's loss weights: the avatar in `pose` rendered by
  // `camera` on `background` (white unless given), against `image` (H, W, 3) in [0, 1] composited on the same
  // background outside `mask` (H, W; all person when none). Returns the weighted terms (as the training log names
  // them), "total" (their sum, differentiable) and "render" (the image).
  py::dict training_loss(const py::object& camera, const py::object& pose, const py::object& image,
                         const py::object& mask, const py::object& background, bool lpips) {
    refresh_if_changed();
    const CameraArgument cam = camera_argument(camera);
    const FramePose p = to_pose(pose);
    const auto given = to_optional_tensor(background, "Avatar.training_loss(background)");
    const at::Tensor target_image = to_tensor(image, "Avatar.training_loss(image)");
    const int64_t h = cam.value.height, w = cam.value.width;
    TORCH_CHECK(target_image.dim() == 3 && target_image.size(0) == h && target_image.size(1) == w &&
                    target_image.size(2) == 3 && at::isFloatingType(target_image.scalar_type()),
                "Avatar.training_loss(image): expected a floating (", h, ", ", w,
                ", 3) image in [0, 1] (the camera's height, width), got ", describe(target_image));
    const sfgs::model::AvatarOutput o = t_.avatar->forward(p.pose, p.time);
    const at::TensorOptions options = o.means.options();
    at::Tensor m = at::ones({h, w}, options);
    if (const auto given_mask = to_optional_tensor(mask, "Avatar.training_loss(mask)")) {
      TORCH_CHECK(given_mask->sizes() == at::IntArrayRef({h, w}), "Avatar.training_loss(mask): expected (", h, ", ", w,
                  "), got ", describe(*given_mask));
      m = given_mask->to(options);
    }
    const at::Tensor bg = given ? given->to(options) : at::ones({3}, options);
    const at::Tensor target = target_image.to(options) * m.unsqueeze(2) + bg * (1 - m.unsqueeze(2));
    const sfgs::RenderResult r = render_through(sfgs::model::to_gaussians(o), bg, cam);
    if (!image_loss_) {
      image_loss_ = std::make_unique<sfgs::train::ImageLoss>(t_.config.loss, device_);
      regularisers_ = std::make_unique<sfgs::train::Regularisers>(t_.config.loss, t_.avatar->part_labels(),
                                                                  t_.avatar->faces(), device_);
    }
    sfgs::train::LossTerms terms;
    image_loss_->add_terms(r.image, target, terms, lpips);
    regularisers_->add_terms(o, terms);
    sfgs::train::total_loss(terms);
    py::dict out;
    for (const auto& [name, value] : terms) out[py::str(name)] = value;
    out["render"] = r.image;
    return out;
  }

  // Frame `index` of the training dataset: its pose (with time), camera and split.
  py::dict frame(const py::object& index_object) {
    py::dict record = frame_record_dict(dataset(), to_int(index_object, "Avatar.frame(index)"));
    py::dict pose = record["pose"];
    if (pose.contains("expression")) pose["expression"] = as_avatar_expression(pose["expression"].cast<at::Tensor>());
    return record;
  }

  // The avatar's expression coefficients from a dataset's or a motion file's, whose space may be larger or smaller:
  // cut, or padded with zeros.
  at::Tensor as_avatar_expression(const at::Tensor& given) const {
    const int64_t count = t_.avatar->expression_count();
    const at::Tensor flat = given.reshape({-1});
    const int64_t used = std::min(flat.size(0), count);
    return at::constant_pad_nd(flat.narrow(0, 0, used), {0, count - used});
  }

  int64_t frame_count() { return dataset().size(); }

  // A motion file or folder as pose dicts in this avatar's hand convention, resampled to `fps` when given.
  py::dict motion(const std::string& path, double fps) {
    const sfgs::data::MotionClip clip = read_clip(path, fps);
    std::vector<SmplxPose> poses;
    for (int64_t k = 0; k < static_cast<int64_t>(clip.poses.size()); ++k) {
      SmplxPose pose = sfgs::train::clip_pose(t_.avatar, clip, k);
      if (pose.expression.defined()) pose.expression = as_avatar_expression(pose.expression);
      poses.push_back(pose);
    }
    return motion_dict(clip, poses);
  }

  // Whether the caller may differentiate the image: the avatar in training mode, or a pose tensor, the camera or the
  // background that requires a gradient.
  bool needs_gradient(const FramePose& p, const CameraArgument& camera,
                      const std::optional<at::Tensor>& background) const {
    if (!at::GradMode::is_enabled()) return false;
    if (t_.avatar->is_training() || camera.tensors || (background && background->requires_grad())) return true;
    for (const SmplxPose::Field& f : SmplxPose::fields()) {
      const at::Tensor& t = p.pose.*(f.member);
      if (t.defined() && t.requires_grad()) return true;
    }
    return false;
  }

  // The frames through the Animator (a CUDA graph replay each, several at once on streams of their own:
  // animate/batch_animator.h): what sfgs render and sfgs eval run. The results are the caller's (no later frame
  // overwrites them), stacked on a first dimension.
  sfgs::RenderResult render_fast(const std::vector<CameraArgument>& cameras, const std::vector<FramePose>& poses,
                                 const std::optional<at::Tensor>& background) {
    std::vector<sfgs::animate::BatchFrame> frames;
    for (size_t b = 0; b < poses.size(); ++b)
      frames.push_back({cameras[b].value, poses[b].pose.to(at::TensorOptions(at::kCPU)), poses[b].time});
    const at::Tensor bg = background ? *background : at::ones({3});
    if (!animator_)
      animator_ = std::make_unique<sfgs::animate::BatchAnimator>(t_.avatar, bg);
    else
      animator_->set_background(bg);
    return animator_->render(frames);
  }

  // The module's parameters or buffers (named as in the checkpoint): the tensors themselves, which sfgs.Avatar, an
  // nn.Module, holds as its own.
  std::vector<std::pair<std::string, at::Tensor>> named_tensors(bool parameters) const {
    std::vector<std::pair<std::string, at::Tensor>> out;
    for (const auto& item : parameters ? t_.avatar->named_parameters() : t_.avatar->named_buffers())
      out.emplace_back(item.key(), item.value());
    return out;
  }

  // Training mode renders with the learned colours and offsets everywhere (the observation prior is off) and without
  // the static-feature cache, and every render is differentiable with respect to the parameters.
  void set_training(bool training) {
    t_.avatar->train(training);
    if (training) t_.avatar->clear_cache();
    animator_.reset();
  }
  bool training() const { return t_.avatar->is_training(); }

  // Moves the parameters and buffers in place (the same tensors, now on `device`) and what was made from them.
  void move_to(const std::string& device) {
    TORCH_CHECK(device == "cpu" || device == "cuda", "Avatar.to: device must be 'cpu' or 'cuda', got '", device, "'");
    const at::Device target = device == "cuda" ? at::Device(at::kCUDA) : at::Device(at::kCPU);
    TORCH_CHECK(target.is_cpu() || sfgs::cuda_backend_available(),
                "Avatar.to: device 'cuda' but this build of sfgs has no CUDA backend");
    if (target == device_) return;
    const bool cached = t_.avatar->has_cache();
    t_.avatar->clear_cache();
    animator_.reset();
    image_loss_.reset();
    regularisers_.reset();
    t_.avatar->to(target);
    t_.avatar->set_observation(t_.avatar->observation());  // its confidence and propagation plan on the new device
    device_ = target;
    if (cached) t_.avatar->cache_static_features();
  }
  std::string device() const { return device_.is_cuda() ? "cuda" : "cpu"; }
  const std::string& run() const { return run_; }
  const std::string& data() const { return data_; }
  bool other_dataset() const { return other_dataset_; }

  // The avatar as a run folder that sfgs eval, render and export and load_avatar take: the run's config, records and
  // fits files with this avatar's parameters. The optimiser's state starts afresh (a resumed training restarts Adam's
  // moments); the checkpoint is written atomically.
  void save(const std::string& folder, bool overwrite) {
    namespace fs = std::filesystem;
    const sfgs::train::RunFolder source{run_}, out{folder};
    TORCH_CHECK(overwrite || !fs::exists(out.checkpoint_file()), "Avatar.save: '", out.checkpoint_file(),
                "' exists; pass overwrite=True to replace it");
    fs::create_directories(folder);
    const sfgs::train::CheckpointInfo info = sfgs::train::CheckpointReader(source.checkpoint_file()).info();
    const std::string config = t_.config.to_yaml();
    sfgs::write_file_atomically(out.config_file(), std::vector<unsigned char>(config.begin(), config.end()), true);
    const std::unique_ptr<torch::optim::Adam> optimizer = sfgs::train::make_optimizer(t_.avatar, t_.config.schedule);
    sfgs::train::save_checkpoint(out.checkpoint_file(), info, t_.avatar, *optimizer);
    const bool same = fs::equivalent(source.path, out.path);
    for (const auto& [from, to] :
         {std::pair(t_.refined_fits, out.refined_fits_file()), std::pair(t_.start_fits, out.start_fits_file())})
      if (!from.empty() && !same) sfgs::write_file_atomically(to, sfgs::train::file_bytes(from), true);
  }

  void set_cached(bool cached) {
    if (cached)
      t_.avatar->cache_static_features();
    else
      t_.avatar->clear_cache();
  }

  const sfgs::train::TrainedAvatar& trained() const { return t_; }

 private:
  // Frames on the fast path when none asks for a gradient on CUDA, else one by one through the differentiable
  // render; stacked on a first dimension unless `batch` is false (one frame).
  sfgs::RenderResult render_frames(const std::vector<CameraArgument>& cameras, const std::vector<FramePose>& poses,
                                   const std::optional<at::Tensor>& background, bool batch = false) {
    refresh_if_changed();
    bool fast = device_.is_cuda();
    for (size_t b = 0; fast && b < poses.size(); ++b) fast = !needs_gradient(poses[b], cameras[b], background);
    if (fast) {
      sfgs::RenderResult r = render_fast(cameras, poses, background);
      if (!batch) r = sfgs::RenderResult{r.image[0], r.alpha[0], r.depth[0], r.radii[0], r.visible[0]};
      return r;
    }
    std::vector<sfgs::RenderResult> frames;
    for (size_t b = 0; b < poses.size(); ++b) frames.push_back(render_eagerly(cameras[b], poses[b], background));
    return batch ? stacked(frames) : frames.front();
  }

  sfgs::RenderResult render_eagerly(const CameraArgument& camera, const FramePose& p,
                                    const std::optional<at::Tensor>& background) {
    const sfgs::model::AvatarOutput o = t_.avatar->forward(p.pose, p.time);
    const at::Tensor bg = background ? background->to(o.means.options()) : at::ones({3}, o.means.options());
    sfgs::Gaussians gaussians = sfgs::model::to_gaussians(o);
    // Widened to the training's blur where the camera samples more finely, as the Animator's frames are.
    if (const at::Tensor& record = t_.avatar->sampling_record(); record.defined())
      gaussians.covariances = sfgs::model::sampling_filtered(gaussians.covariances, gaussians.means, camera.value,
                                                             record.to(o.means.device()));
    return render_through(gaussians, bg, camera);
  }

  // Every parameter's version counter summed: an in-place update (an optimiser's step, load_state_dict) changes it.
  int64_t parameters_version() const {
    int64_t sum = 0;
    for (const at::Tensor& t : t_.avatar->parameters()) sum += int64_t(t._version());
    return sum;
  }

  // After the parameters changed, what was made from them (the static-feature cache, the Animator's recording) is
  // made again.
  void refresh_if_changed() {
    const int64_t version = parameters_version();
    if (version == parameters_version_) return;
    parameters_version_ = version;
    animator_.reset();
    if (t_.avatar->has_cache()) {
      t_.avatar->clear_cache();
      t_.avatar->cache_static_features();
    }
  }

  FramePose to_pose(const py::object& object) const {
    if (!py::isinstance<py::dict>(object))
      throw py::type_error("pose: expected a dict of SMPL-X parameters (e.g. {'body_pose': tensor}), got " +
                           python_type(object));
    FramePose p;
    for (const auto& item : py::dict(object)) {
      if (!py::isinstance<py::str>(item.first))
        throw py::type_error("pose: keys must be str, got " + python_type(item.first));
      std::string key = item.first.cast<std::string>();
      if (key == "time") {
        if (!item.second.is_none()) p.time = to_double(item.second, "pose['time']");
        continue;
      }
      for (const auto& [old_name, new_name] : kRenamedPoseKeys)
        if (key == old_name) {
          const std::string warning = "pose key '" + key + "' is deprecated; use '" + new_name + "'";
          if (PyErr_WarnEx(PyExc_DeprecationWarning, warning.c_str(), 1) != 0) throw py::error_already_set();
          key = new_name;
        }
      const auto& fields = SmplxPose::fields();
      const auto known = std::find_if(fields.begin(), fields.end(), [&](const auto& f) { return key == f.name; });
      if (known == fields.end()) {
        std::string expected = "time";
        for (const SmplxPose::Field& f : fields) expected += std::string(", ") + f.name;
        TORCH_CHECK(false, "pose: unknown key '", key, "'; expected one of ", expected);
      }
      p.pose.*(known->member) = to_tensor(item.second, "pose['" + key + "']");
      if (known->member == &SmplxPose::expression) {
        // Exactly the avatar's coefficients: a longer or shorter vector would be cut or padded without a word.
        const at::Tensor& e = p.pose.expression;
        const int64_t count = t_.avatar->expression_count();
        TORCH_CHECK(e.numel() == count && (e.dim() == 1 || (e.dim() == 2 && e.size(0) == 1)),
                    "pose['expression']: this avatar takes ", count,
                    " expression coefficients (avatar.num_expression_coeffs), got shape ", e.sizes(),
                    "; frame() and motion() give them in that size");
      }
    }
    return p;
  }

  const sfgs::data::Dataset& dataset() {
    if (dataset_) return *dataset_;
    bool own = true;
    sfgs::data::Dataset read = sfgs::train::read_run_dataset(t_, data_, &own);
    TORCH_CHECK(own || other_dataset_, "load_avatar: data '", data_, "' is not the dataset the run was trained on ",
                "(fingerprint ", read.fingerprint(), ", the run's ", t_.dataset_fingerprint,
                "); pass other_dataset=True to use its frames anyway");
    dataset_ = std::move(read);
    return *dataset_;
  }

  at::Device device_;
  std::string run_;             // the run folder given to load_avatar
  std::string data_;            // the dataset folder given to load_avatar; empty: the one the run was trained on
  bool other_dataset_ = false;  // data_ may be another dataset than the run's own
  sfgs::train::TrainedAvatar t_;
  std::optional<sfgs::data::Dataset> dataset_;
  std::unique_ptr<sfgs::animate::BatchAnimator> animator_;  // CUDA renders without a gradient, made at the first
  int64_t parameters_version_ = 0;                      // parameters_version() when the cache and Animator were made
  std::unique_ptr<sfgs::train::ImageLoss> image_loss_;  // training_loss's, made at its first call
  std::unique_ptr<sfgs::train::Regularisers> regularisers_;
};

}  // namespace

void bind_avatar(py::module_& m) {
  py::class_<TrainedAvatar>(m, "Avatar", "A trained SFGS avatar: pose it, render it, read its training frames")
      .def(py::init<const std::string&, const std::string&, const std::string&, bool>(), py::arg("run"),
           py::arg("device") = "cpu", py::arg("data") = "", py::arg("other_dataset") = false)
      .def("gaussians", &TrainedAvatar::gaussians, py::arg("pose") = py::dict(),
           R"(Posed Gaussians for a pose dict (SMPL-X names: global_orient (3), body_pose (21,3), jaw_pose, leye_pose,
reye_pose (3), left_hand_pose, right_hand_pose (15,3) axis-angle, expression (E), transl (3), time in [-1, 1] or None
(a new motion: the time branch is left out; the default); missing keys are at rest). Returns means (N,3), covariances (N,6), opacities (N), colours (N,3), canonical_means,
log_scales, posed_vertices. Differentiable w.r.t. the pose tensors unless torch.no_grad() is active.)")
      .def("render", &TrainedAvatar::render, py::arg("camera"), py::arg("pose") = py::dict(),
           py::arg("background") = py::none(),
           R"(Render the avatar in `pose` from `camera` (a dict: world_to_camera (4,4), fx, fy, cx, cy, width, height;
frame(i)["camera"] gives one). Background white unless given (3). Returns image (H,W,3), alpha, depth, radii,
visible, as render() does. A batch: a list of B cameras and/or B poses (a single one is shared); outputs (B,H,W,3)
and so on.
The image is differentiable w.r.t. pose tensors, the background and camera tensors (world_to_camera, fx, fy, cx, cy)
that require grad, and in training mode w.r.t. the parameters.)")
      .def("training_loss", &TrainedAvatar::training_loss, py::arg("camera"), py::arg("pose"), py::arg("image"),
           py::kw_only(), py::arg("mask") = py::none(), py::arg("background") = py::none(), py::arg("lpips") = true,
           R"(The loss a training step takes on one frame with the run's loss weights: the avatar in `pose` rendered by
`camera` on `background` (white unless given) against `image` (H,W,3) in [0, 1] composited on it outside `mask` (H,W).
Returns the weighted terms (l1, ssim, lpips, lab, gradient, image, the regularisers), 'total' and 'render'.)")
      .def("named_tensors", &TrainedAvatar::named_tensors, py::arg("parameters"),
           "The C++ module's parameters (True) or buffers (False) as (name, tensor) pairs, named as in the checkpoint")
      .def("set_training", &TrainedAvatar::set_training, py::arg("training"),
           "Training mode (True): no observation prior or cache, renders differentiable w.r.t. the parameters")
      .def_property_readonly("training", &TrainedAvatar::training)
      .def("move_to", &TrainedAvatar::move_to, py::arg("device"),
           "Move the parameters and buffers in place to 'cpu' or 'cuda'")
      .def_property_readonly("device", &TrainedAvatar::device)
      .def_property_readonly("run", &TrainedAvatar::run)
      .def_property_readonly("data", &TrainedAvatar::data)
      .def_property_readonly("other_dataset", &TrainedAvatar::other_dataset)
      .def(
          "centre", [](TrainedAvatar& a, const py::object& pose) { return a.centre(pose); },
          py::arg("pose") = py::dict(),
          "The centre (x, y, z) of the posed body's bounding box: where `sfgs render`'s cameras aim.")
      .def("frame", &TrainedAvatar::frame, py::arg("index"),
           "Training-dataset frame `index`: {'pose': dict, 'camera': dict, 'split': 'train'|'val'|'test'}")
      .def_property_readonly("frame_count", &TrainedAvatar::frame_count)
      .def("motion", &TrainedAvatar::motion, py::arg("path"), py::arg("fps") = 0.0,
           R"(An AMASS .npz or ExAvatar motion folder (docs/motions.md) as this avatar takes it: {'frames': [pose dict,
...], 'fps', 'format', 'note', 'absolute_hands'}; hand poses converted to the avatar's convention; resampled to `fps`
when given (> 0). Pass a frame to gaussians() or render().)")
      .def("save", &TrainedAvatar::save, py::arg("folder"), py::kw_only(), py::arg("overwrite") = false,
           R"(Write the avatar as a run folder (config.yaml, checkpoint.pt, the run's fits files) that load_avatar and
sfgs eval, render and export take: this avatar's parameters with the run's config and training records.)")
      .def("set_cached", &TrainedAvatar::set_cached, py::arg("cached"),
           "Cache the pose-independent features for fast inference (True) or drop the cache (False)")
      .def_property_readonly("iteration", [](const TrainedAvatar& a) { return a.trained().iteration; })
      .def_property_readonly("expression_count",
                             [](const TrainedAvatar& a) { return a.trained().avatar->expression_count(); })
      .def_property_readonly("gaussian_count",
                             [](const TrainedAvatar& a) { return a.trained().avatar->gaussian_count(); })
      .def_property_readonly("config_yaml", [](const TrainedAvatar& a) { return a.trained().config.to_yaml(); })
      .def_property_readonly("dataset_path", [](const TrainedAvatar& a) { return a.trained().dataset; });
  m.def(
      "load_avatar",
      [](const std::string& run, const std::string& device, const std::string& data, bool other_dataset) {
        return TrainedAvatar(run, device, data, other_dataset);
      },
      py::arg("run"), py::arg("device") = "cpu", py::arg("data") = "", py::arg("other_dataset") = false,
      "Load a trained avatar from a run folder (sfgs train --out RUN); `data` points at its dataset if it moved "
      "(another dataset than the one it trained on only with other_dataset=True)");
  m.def(
      "read_motion",
      [](const std::string& path, double fps) {
        const sfgs::data::MotionClip clip = read_clip(path, fps);
        return motion_dict(clip, clip.poses);
      },
      py::arg("path"), py::arg("fps") = 0.0,
      R"(Read an AMASS SMPL-X/SMPL-H .npz or an ExAvatar motion folder (docs/motions.md): {'frames': [pose dict (float64,
the avatar's Y-up frame), ...], 'fps', 'format', 'note', 'absolute_hands' (hand poses relative to a flat hand)};
resampled to `fps` when given (> 0). Avatar.motion converts the hands for an avatar.)");
}

}  // namespace sfgs::python
