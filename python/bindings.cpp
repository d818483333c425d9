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
#include "camera_arguments.h"
#include "common/tensor_description.h"
#include "python_values.h"
#include "ops/splat/constants.h"

namespace py = pybind11;
using namespace sfgs::python;

namespace {

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
  const int64_t w = to_int(width, "render(width)"), h = to_int(height, "render(height)");
  const double near = to_double(near_plane, "render(near_plane)"), far = to_double(far_plane, "render(far_plane)");
  const auto camera = [&](const py::handle& placement) {
    return camera_argument(placement, fx, fy, cx, cy, w, h, near, far,
                           [](const std::string& key) { return "render(" + key + ")"; });
  };
  sfgs::RenderOptions options;
  options.low_pass = low_pass;
  options.antialiased = antialiased;
  options.deterministic = deterministic;
  const at::Tensor bg = to_tensor(background, "render(background)");
  const at::Tensor placements = to_tensor(world_to_camera, "render(world_to_camera)");
  if (placements.dim() != 3) return result_dict(render_through(g, bg, camera(world_to_camera), options));
  // A batch of B placements (B, 4, 4): one image each, stacked.
  TORCH_CHECK(placements.size(0) > 0, "render: a batch of cameras (B, 4, 4) needs B >= 1, got ",
              sfgs::describe(placements));
  std::vector<sfgs::RenderResult> frames;
  for (int64_t b = 0; b < placements.size(0); ++b)
    frames.push_back(render_through(g, bg, camera(py::cast(placements[b])), options));
  return result_dict(stacked(frames));
}

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
world_to_camera (B,4,4) renders B images (outputs stacked: image (B,H,W,C), ...).
Returns a dict: image (H,W,C), alpha (H,W), depth (H,W; expected depth), radii (N,2) int32, visible (N) bool.
Differentiable w.r.t. means, scales, rotations, covariances, opacities, features and background, and w.r.t.
world_to_camera and fx, fy, cx, cy when given as tensors that require grad.)");
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
  bind_avatar(m);
  bind_metrics_and_data(m);
  bind_body_layers(m);
  m.attr("LOW_PASS_VARIANCE_PX2") = sfgs::kLowPassVariancePx2;
  m.attr("MIN_ALPHA") = sfgs::kMinAlpha;
  m.attr("MAX_ALPHA") = sfgs::kMaxAlpha;
  m.attr("MIN_TRANSMITTANCE") = sfgs::kMinTransmittance;
  m.attr("TILE_SIZE") = sfgs::kTileSize;
}
