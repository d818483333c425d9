// Python bindings: `import sfgs` exposes the splatting op and trained avatars (load a run, pose it, render it);
// tensors it returns carry the C++ autograd nodes, so torch.autograd (gradcheck included) works through them.
#include <algorithm>
#include <array>
#include <cmath>
#include <memory>
#include <optional>
#include <string>

#include <torch/extension.h>

#include "animate/animator.h"
#include "animate/camera_placement.h"
#include "data/dataset.h"
#include "data/motion_file.h"
#include "model/sampling_filter.h"
#include "scene/builtin_scene.h"
#include "ops/splat/splat.h"
#include "train/run_folder.h"
#include "python_values.h"
#include "ops/splat/constants.h"

namespace py = pybind11;
using namespace sfgs::python;

namespace {

py::dict result_dict(const sfgs::RenderResult& r) {
  py::dict out;
  out["image"] = r.image;
  out["alpha"] = r.alpha;
  out["depth"] = r.depth;
  out["radii"] = r.radii;
  out["visible"] = r.visible;
  return out;
}

py::dict render(const py::object& means, const py::object& opacities, const py::object& features,
                const py::object& background, const py::object& world_to_camera, const py::object& fx,
                const py::object& fy, const py::object& cx, const py::object& cy, const py::object& width,
                const py::object& height, const py::object& scales, const py::object& rotations,
                const py::object& covariances, const py::object& near_plane, const py::object& far_plane, bool low_pass,
                bool antialiased, bool deterministic) {
  sfgs::Gaussians g;
  g.means = to_tensor(means, "render(means)");
  g.opacities = to_tensor(opacities, "render(opacities)");
  g.features = to_tensor(features, "render(features)");
  if (auto t = to_optional_tensor(scales, "render(scales)")) g.scales = *t;
  if (auto t = to_optional_tensor(rotations, "render(rotations)")) g.rotations = *t;
  if (auto t = to_optional_tensor(covariances, "render(covariances)")) g.covariances = *t;
  const sfgs::Camera camera =
      sfgs::Camera::from_tensor(to_tensor(world_to_camera, "render(world_to_camera)"), to_double(fx, "render(fx)"),
                                to_double(fy, "render(fy)"), to_double(cx, "render(cx)"), to_double(cy, "render(cy)"),
                                to_int(width, "render(width)"), to_int(height, "render(height)"),
                                to_double(near_plane, "render(near_plane)"), to_double(far_plane, "render(far_plane)"));
  sfgs::RenderOptions options;
  options.low_pass = low_pass;
  options.antialiased = antialiased;
  options.deterministic = deterministic;
  return result_dict(sfgs::render(g, to_tensor(background, "render(background)"), camera, options));
}

// The pose dict of the Python API: body::SmplxPose's fields by name, and "time".
using sfgs::body::SmplxPose;
struct FramePose {
  SmplxPose pose;
  sfgs::model::FrameTime time;  // none unless the dict gives one: a new motion (model/frame_time.h)
};

// Keys of earlier versions, accepted with a DeprecationWarning.
const std::pair<const char*, const char*> kRenamedPoseKeys[] = {{"left_eye_pose", "leye_pose"},
                                                                {"right_eye_pose", "reye_pose"}};

sfgs::Camera camera_from_dict(const py::object& object) {
  if (!py::isinstance<py::dict>(object))
    throw py::type_error("camera: expected a dict (world_to_camera, fx, fy, cx, cy, width, height), got " +
                         python_type(object));
  const py::dict d = object;
  for (const char* key : {"world_to_camera", "fx", "fy", "cx", "cy", "width", "height"})
    TORCH_CHECK(d.contains(key), "camera: expected a dict with world_to_camera, fx, fy, cx, cy, width and height; '",
                key, "' is missing");
  return sfgs::Camera::from_tensor(to_tensor(d["world_to_camera"], "camera['world_to_camera']"),
                                   to_double(d["fx"], "camera['fx']"), to_double(d["fy"], "camera['fy']"),
                                   to_double(d["cx"], "camera['cx']"), to_double(d["cy"], "camera['cy']"),
                                   to_int(d["width"], "camera['width']"), to_int(d["height"], "camera['height']"));
}

// A trained avatar for experiments: the run's checkpoint with its config, and the dataset it was trained on
// (read when first needed).
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

class TrainedAvatar {
 public:
  TrainedAvatar(const std::string& run, const std::string& device, const std::string& data, bool other_dataset)
      : device_(device == "cuda" ? at::kCUDA : at::kCPU), data_(data), other_dataset_(other_dataset) {
    TORCH_CHECK(device == "cpu" || device == "cuda", "load_avatar: device must be 'cpu' or 'cuda', got '", device, "'");
    TORCH_CHECK(device_.is_cpu() || sfgs::cuda_backend_available(),
                "load_avatar: device 'cuda' but this build of sfgs has no CUDA backend");
    t_ = sfgs::train::load_trained_avatar(sfgs::train::RunFolder{run}, device_);
    t_.avatar->eval();
    if (!data_.empty()) dataset();  // a dataset given by the caller is checked now, not at its first frame
  }

  // Posed Gaussians and the canonical quantities, as a dict of tensors.
  py::dict gaussians(const py::object& pose) {
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
    const FramePose p = to_pose(pose);
    const at::NoGradGuard no_grad;
    return sfgs::animate::centre_of(t_.avatar->forward(p.pose, p.time));
  }

  py::dict render(const py::object& camera, const py::object& pose, const py::object& background) {
    const sfgs::Camera cam = camera_from_dict(camera);
    const FramePose p = to_pose(pose);
    const auto given = to_optional_tensor(background, "Avatar.render(background)");
    if (device_.is_cuda() && !needs_gradient(p, given)) return render_fast(cam, p, given);
    const sfgs::model::AvatarOutput o = t_.avatar->forward(p.pose, p.time);
    const at::Tensor bg = given ? given->to(o.means.options()) : at::ones({3}, o.means.options());
    sfgs::Gaussians gaussians = sfgs::model::to_gaussians(o);
    // Widened to the training's blur where the camera samples more finely, as the Animator's frames are.
    if (const at::Tensor& record = t_.avatar->sampling_record(); record.defined())
      gaussians.covariances =
          sfgs::model::sampling_filtered(gaussians.covariances, gaussians.means, cam, record.to(o.means.device()));
    return result_dict(sfgs::render(gaussians, bg, cam));
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

  // Whether the caller may differentiate the image: a pose tensor or the background asks for a gradient.
  static bool needs_gradient(const FramePose& p, const std::optional<at::Tensor>& background) {
    if (!at::GradMode::is_enabled()) return false;
    if (background && background->requires_grad()) return true;
    for (const SmplxPose::Field& f : SmplxPose::fields()) {
      const at::Tensor& t = p.pose.*(f.member);
      if (t.defined() && t.requires_grad()) return true;
    }
    return false;
  }

  // The frame through the Animator (one CUDA graph replay): what sfgs render and sfgs eval run. The result is
  // cloned, since the next replay writes into the graph's tensors.
  py::dict render_fast(const sfgs::Camera& camera, const FramePose& p, const std::optional<at::Tensor>& background) {
    SmplxPose host;
    for (const SmplxPose::Field& f : SmplxPose::fields()) {
      const at::Tensor& t = p.pose.*(f.member);
      if (t.defined()) host.*(f.member) = t.detach().cpu();
    }
    const at::Tensor bg = background ? *background : at::ones({3});
    if (!animator_)
      animator_ = std::make_unique<sfgs::animate::Animator>(t_.avatar, camera, bg);
    else {
      animator_->set_camera(camera);
      animator_->set_background(bg);
    }
    animator_->render(host, p.time);
    const sfgs::RenderResult& r = animator_->latest();
    sfgs::RenderResult copy;
    copy.image = r.image.clone();
    copy.alpha = r.alpha.clone();
    copy.depth = r.depth.clone();
    copy.radii = r.radii.clone();
    copy.visible = r.visible.clone();
    return result_dict(copy);
  }

  void set_cached(bool cached) {
    if (cached)
      t_.avatar->cache_static_features();
    else
      t_.avatar->clear_cache();
  }

  const sfgs::train::TrainedAvatar& trained() const { return t_; }

 private:
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
  std::string data_;            // the dataset folder given to load_avatar; empty: the one the run was trained on
  bool other_dataset_ = false;  // data_ may be another dataset than the run's own
  sfgs::train::TrainedAvatar t_;
  std::optional<sfgs::data::Dataset> dataset_;
  std::unique_ptr<sfgs::animate::Animator> animator_;  // CUDA renders without a gradient, made at the first
};

// A point (x, y, z): three numbers, or a tensor of three.
std::array<double, 3> to_point(const py::object& object, const std::string& what) {
  std::array<double, 3> point{};
  if (THPVariable_Check(object.ptr())) {
    const at::Tensor t = to_tensor(object, what).detach().to(at::kCPU, at::kDouble).reshape({-1});
    TORCH_CHECK(t.numel() == 3, what, ": expected a point of 3 values (x, y, z), got ", t.numel());
    for (int k = 0; k < 3; ++k) point[size_t(k)] = t[k].item<double>();
  } else {
    if (!py::isinstance<py::sequence>(object) || py::isinstance<py::str>(object) || py::len(object) != 3)
      throw py::type_error(what + ": expected a point (x, y, z): three numbers or a tensor of three, got " +
                           python_type(object));
    const py::sequence values = object;
    for (size_t k = 0; k < 3; ++k) point[k] = to_double(values[k], what);
  }
  for (const double v : point) TORCH_CHECK(std::isfinite(v), what, " must be finite, got ", v);
  return point;
}

// A camera of `width` x `height` pixels, principal point centred, focal length `fx` pixels (None: the framing
// default, animate::kFramingFocalPerHeight times the height), at the origin.
sfgs::Camera framing_lens(const py::object& width, const py::object& height, const py::object& fx, const char* what) {
  const int64_t w = to_int(width, std::string(what) + "(width)"), h = to_int(height, std::string(what) + "(height)");
  TORCH_CHECK(w > 0 && h > 0, what, ": width and height must be positive, got ", w, " x ", h);
  const double focal =
      fx.is_none() ? sfgs::animate::kFramingFocalPerHeight * double(h) : to_double(fx, std::string(what) + "(fx)");
  TORCH_CHECK(std::isfinite(focal) && focal > 0, what, ": fx must be positive, got ", focal);
  return sfgs::Camera::looking_forward(focal, w, h);
}

}  // namespace

PYBIND11_MODULE(_C, m) {
  m.doc() = "sfgs: structure-aware fine-grained Gaussian splatting (C++/LibTorch)";
  m.def("render", &render, py::arg("means"), py::arg("opacities"), py::arg("features"), py::arg("background"),
        py::arg("world_to_camera"), py::arg("fx"), py::arg("fy"), py::arg("cx"), py::arg("cy"), py::arg("width"),
        py::arg("height"), py::kw_only(), py::arg("scales") = py::none(), py::arg("rotations") = py::none(),
        py::arg("covariances") = py::none(), py::arg("near_plane") = sfgs::kDefaultNearPlane,
        py::arg("far_plane") = sfgs::kDefaultFarPlane, py::arg("low_pass") = true, py::arg("antialiased") = false,
        py::arg("deterministic") = false,
        R"(Render 3D Gaussians. Give scales (N,3) with rotations (N,4; w,x,y,z) or covariances (N,6: xx,xy,xz,yy,yz,zz).
opacities (N), features (N,C), background (C); world_to_camera (4,4), OpenCV convention, pixel centres at +0.5.
Returns a dict: image (H,W,C), alpha (H,W), depth (H,W; expected depth), radii (N,2) int32, visible (N) bool.
Differentiable w.r.t. means, scales, rotations, covariances, opacities, features and background.)");
  m.def("cuda_available", &sfgs::cuda_backend_available, "Whether this build has the CUDA backend");
  m.def(
      "demo_scene",
      [](int64_t count, int64_t width, int64_t height, uint64_t seed, bool double_precision) {
        const sfgs::scene::GaussianScene s =
            sfgs::scene::demo_scene(count, width, height, seed, double_precision ? at::kDouble : at::kFloat);
        py::dict d;
        d["means"] = s.gaussians.means;
        d["scales"] = s.gaussians.scales;
        d["rotations"] = s.gaussians.rotations;
        d["opacities"] = s.gaussians.opacities;
        d["features"] = s.gaussians.features;
        d["background"] = s.background;
        d["world_to_camera"] = at::eye(4, at::kDouble);
        d["fx"] = s.camera.fx;
        d["fy"] = s.camera.fy;
        d["cx"] = s.camera.cx;
        d["cy"] = s.camera.cy;
        return d;
      },
      py::arg("count") = 20000, py::arg("width") = 320, py::arg("height") = 240, py::arg("seed") = 7,
      py::arg("double_precision") = false, "The built-in demo scene as a dict of tensors and camera values");
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
visible, as render() does.)")
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
      "look_at_camera",
      [](const py::object& eye, const py::object& target, const py::object& width, const py::object& height,
         const py::object& fx) {
        return camera_dict(sfgs::animate::look_at_camera(framing_lens(width, height, fx, "look_at_camera"),
                                                         to_point(eye, "look_at_camera(eye)"),
                                                         to_point(target, "look_at_camera(target)")));
      },
      py::arg("eye"), py::arg("target"), py::arg("width"), py::arg("height"), py::arg("fx") = py::none(),
      "A camera dict at `eye` looking at `target` (world +Y up, the body model facing +Z; OpenCV axes), width x "
      "height pixels, principal point centred, focal length fx (default 1.2 x height, about 45 degrees of view).");
  m.def(
      "camera_in_front",
      [](const py::object& target, const py::object& width, const py::object& height, double distance,
         double height_above, double angle, const py::object& fx) {
        return camera_dict(sfgs::animate::camera_in_front(framing_lens(width, height, fx, "camera_in_front"),
                                                          to_point(target, "camera_in_front(target)"), distance,
                                                          height_above, angle));
      },
      py::arg("target"), py::arg("width"), py::arg("height"), py::arg("distance") = sfgs::animate::kFramingDistance,
      py::arg("height_above") = 0.0, py::arg("angle") = 0.0, py::arg("fx") = py::none(),
      "`sfgs render`'s cameras: looking at `target` from `distance` m in front of it (+Z, where the body faces), "
      "`height_above` m above it, turned `angle` radians about the vertical. Follow a body with target = "
      "Avatar.centre(pose); orbit it by stepping the angle.");
  m.def(
      "orbit_camera",
      [](const py::object& camera, const py::object& centre, double angle) {
        return camera_dict(
            sfgs::animate::orbit_camera(camera_from_dict(camera), to_point(centre, "orbit_camera(centre)"), angle));
      },
      py::arg("camera"), py::arg("centre"), py::arg("angle"),
      "`camera` (a dict, e.g. a dataset frame's) moved `angle` radians about the vertical through `centre`, at its "
      "own distance and height, looking at the centre: `sfgs render`'s default orbit of a training frame.");
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
  bind_metrics_and_data(m);
  bind_body_layers(m);
  m.attr("LOW_PASS_VARIANCE_PX2") = sfgs::kLowPassVariancePx2;
  m.attr("MIN_ALPHA") = sfgs::kMinAlpha;
  m.attr("MAX_ALPHA") = sfgs::kMaxAlpha;
  m.attr("MIN_TRANSMITTANCE") = sfgs::kMinTransmittance;
  m.attr("TILE_SIZE") = sfgs::kTileSize;
}
