// Python bindings: `import sfgs` exposes the splatting op and trained avatars (load a run, pose it, render it);
// tensors it returns carry the C++ autograd nodes, so torch.autograd (gradcheck included) works through them.
#include <algorithm>
#include <optional>

#include <torch/extension.h>

#include "data/dataset.h"
#include "scene/builtin_scene.h"
#include "splat/splat.h"
#include "train/run_folder.h"

namespace py = pybind11;

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

py::dict render(const at::Tensor& means, const at::Tensor& opacities, const at::Tensor& features,
                const at::Tensor& background, const at::Tensor& world_to_camera, double fx, double fy, double cx,
                double cy, int64_t width, int64_t height, const c10::optional<at::Tensor>& scales,
                const c10::optional<at::Tensor>& rotations, const c10::optional<at::Tensor>& covariances,
                double near_plane, double far_plane, bool low_pass, bool antialiased, bool deterministic) {
  sfgs::Gaussians g;
  g.means = means;
  g.opacities = opacities;
  g.features = features;
  if (scales) g.scales = *scales;
  if (rotations) g.rotations = *rotations;
  if (covariances) g.covariances = *covariances;
  const sfgs::Camera camera =
      sfgs::Camera::from_tensor(world_to_camera, fx, fy, cx, cy, width, height, near_plane, far_plane);
  sfgs::RenderOptions options;
  options.low_pass = low_pass;
  options.antialiased = antialiased;
  options.deterministic = deterministic;
  return result_dict(sfgs::render(g, background, camera, options));
}

// The pose fields an avatar takes, by their SMPL-X names (and "time").
using sfgs::model::AvatarPose;
const std::pair<const char*, at::Tensor AvatarPose::*> kPoseFields[] = {
    {"global_orient", &AvatarPose::global_orient},   {"body_pose", &AvatarPose::body_pose},
    {"jaw_pose", &AvatarPose::jaw_pose},             {"left_eye_pose", &AvatarPose::left_eye_pose},
    {"right_eye_pose", &AvatarPose::right_eye_pose}, {"left_hand_pose", &AvatarPose::left_hand_pose},
    {"right_hand_pose", &AvatarPose::right_hand_pose}, {"expression", &AvatarPose::expression},
    {"transl", &AvatarPose::transl}};

py::dict camera_dict(const sfgs::Camera& c) {
  py::dict d;
  d["world_to_camera"] = at::tensor(std::vector<double>(c.world_to_camera.begin(), c.world_to_camera.end()),
                                    at::kDouble)
                             .view({4, 4});
  d["fx"] = c.fx;
  d["fy"] = c.fy;
  d["cx"] = c.cx;
  d["cy"] = c.cy;
  d["width"] = c.width;
  d["height"] = c.height;
  return d;
}

sfgs::Camera camera_from_dict(const py::dict& d) {
  for (const char* key : {"world_to_camera", "fx", "fy", "cx", "cy", "width", "height"})
    TORCH_CHECK(d.contains(key), "camera: expected a dict with world_to_camera, fx, fy, cx, cy, width and height; '",
                key, "' is missing");
  return sfgs::Camera::from_tensor(d["world_to_camera"].cast<at::Tensor>(), d["fx"].cast<double>(),
                                   d["fy"].cast<double>(), d["cx"].cast<double>(), d["cy"].cast<double>(),
                                   d["width"].cast<int64_t>(), d["height"].cast<int64_t>());
}

// A trained avatar for experiments: the run's checkpoint with its config, and the dataset it was trained on
// (read when first needed).
class TrainedAvatar {
 public:
  TrainedAvatar(const std::string& run, const std::string& device)
      : device_(device == "cuda" ? at::kCUDA : at::kCPU) {
    TORCH_CHECK(device == "cpu" || device == "cuda", "load_avatar: device must be 'cpu' or 'cuda', got '", device, "'");
    TORCH_CHECK(device_.is_cpu() || sfgs::cuda_backend_available(),
                "load_avatar: device 'cuda' but this build of sfgs has no CUDA backend");
    t_ = sfgs::train::load_trained_avatar(sfgs::train::RunFolder{run}, device_);
    t_.avatar->eval();
  }

  // Posed Gaussians and the canonical quantities, as a dict of tensors.
  py::dict gaussians(const py::dict& pose) {
    const sfgs::model::AvatarOutput o = t_.avatar->forward(to_pose(pose));
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

  py::dict render(const py::dict& camera, const py::dict& pose, const c10::optional<at::Tensor>& background) {
    const sfgs::model::AvatarOutput o = t_.avatar->forward(to_pose(pose));
    const at::Tensor bg = background ? background->to(o.means.options()) : at::ones({3}, o.means.options());
    return result_dict(
        sfgs::render({o.means, {}, {}, o.covariances, o.opacities, o.colours}, bg, camera_from_dict(camera)));
  }

  // Frame `index` of the training dataset: its pose (with time), camera and split.
  py::dict frame(int64_t index) {
    const sfgs::data::Dataset& d = dataset();
    TORCH_CHECK(index >= 0 && index < d.size(), "frame: index must be in [0, ", d.size(), "), got ", index);
    const AvatarPose p = sfgs::train::avatar_pose(d, index, at::kCPU);
    py::dict pose;
    for (const auto& [key, field] : kPoseFields)
      if ((p.*field).defined()) pose[key] = p.*field;
    pose["time"] = p.time;
    py::dict out;
    out["pose"] = pose;
    out["camera"] = camera_dict(sfgs::train::render_camera(d.frames[size_t(index)]));
    const char* names[] = {"train", "val", "test"};
    for (const auto split : {sfgs::data::Split::kTrain, sfgs::data::Split::kVal, sfgs::data::Split::kTest}) {
      const auto& members = d.split(split);
      if (std::find(members.begin(), members.end(), index) != members.end()) out["split"] = names[int(split)];
    }
    return out;
  }

  int64_t frame_count() { return dataset().size(); }
  void set_cached(bool cached) {
    if (cached)
      t_.avatar->cache_static_features();
    else
      t_.avatar->clear_cache();
  }

  const sfgs::train::TrainedAvatar& trained() const { return t_; }

 private:
  AvatarPose to_pose(const py::dict& pose) const {
    AvatarPose p;
    for (const auto& item : pose) {
      const std::string key = item.first.cast<std::string>();
      if (key == "time") {
        p.time = item.second.cast<double>();
        continue;
      }
      const auto* known = std::find_if(std::begin(kPoseFields), std::end(kPoseFields),
                                       [&](const auto& f) { return key == f.first; });
      if (known == std::end(kPoseFields)) {
        std::string expected = "time";
        for (const auto& [name, field] : kPoseFields) expected += std::string(", ") + name;
        TORCH_CHECK(false, "pose: unknown key '", key, "'; expected one of ", expected);
      }
      p.*(known->second) = item.second.cast<at::Tensor>().to(device_);
    }
    return p;
  }

  const sfgs::data::Dataset& dataset() {
    if (!dataset_) dataset_ = sfgs::data::read_dataset(t_.dataset);
    return *dataset_;
  }

  at::Device device_;
  sfgs::train::TrainedAvatar t_;
  std::optional<sfgs::data::Dataset> dataset_;
};

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
      .def(py::init<const std::string&, const std::string&>(), py::arg("run"), py::arg("device") = "cpu")
      .def("gaussians", &TrainedAvatar::gaussians, py::arg("pose") = py::dict(),
           R"(Posed Gaussians for a pose dict (SMPL-X names: global_orient (3), body_pose (21,3), jaw_pose, left_eye_pose,
right_eye_pose (3), left_hand_pose, right_hand_pose (15,3) axis-angle, expression (E), transl (3), time in [-1, 1];
missing keys are at rest). Returns means (N,3), covariances (N,6), opacities (N), colours (N,3), canonical_means,
log_scales, posed_vertices. Differentiable w.r.t. the pose tensors unless torch.no_grad() is active.)")
      .def("render", &TrainedAvatar::render, py::arg("camera"), py::arg("pose") = py::dict(),
           py::arg("background") = py::none(),
           R"(Render the avatar in `pose` from `camera` (a dict: world_to_camera (4,4), fx, fy, cx, cy, width, height;
frame(i)["camera"] gives one). Background white unless given (3). Returns image (H,W,3), alpha, depth, radii,
visible, as render() does.)")
      .def("frame", &TrainedAvatar::frame, py::arg("index"),
           "Training-dataset frame `index`: {'pose': dict, 'camera': dict, 'split': 'train'|'val'|'test'}")
      .def_property_readonly("frame_count", &TrainedAvatar::frame_count)
      .def("set_cached", &TrainedAvatar::set_cached, py::arg("cached"),
           "Cache the pose-independent features for fast inference (True) or drop the cache (False)")
      .def_property_readonly("iteration", [](const TrainedAvatar& a) { return a.trained().iteration; })
      .def_property_readonly("gaussian_count", [](const TrainedAvatar& a) { return a.trained().avatar->gaussian_count(); })
      .def_property_readonly("config_yaml", [](const TrainedAvatar& a) { return a.trained().config.to_yaml(); })
      .def_property_readonly("dataset_path", [](const TrainedAvatar& a) { return a.trained().dataset; });
  m.def(
      "load_avatar", [](const std::string& run, const std::string& device) { return TrainedAvatar(run, device); },
      py::arg("run"), py::arg("device") = "cpu", "Load a trained avatar from a run folder (sfgs train --out RUN)");
  m.attr("LOW_PASS_VARIANCE_PX2") = sfgs::kLowPassVariancePx2;
  m.attr("MIN_ALPHA") = sfgs::kMinAlpha;
  m.attr("MAX_ALPHA") = sfgs::kMaxAlpha;
  m.attr("MIN_TRANSMITTANCE") = sfgs::kMinTransmittance;
  m.attr("TILE_SIZE") = sfgs::kTileSize;
}
