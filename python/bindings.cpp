// Python bindings: `import sfgs` exposes the splatting op; tensors it returns carry the C++ autograd node, so
// torch.autograd (gradcheck included) works through it.
#include <torch/extension.h>

#include "scene/builtin_scene.h"
#include "splat/splat.h"

namespace py = pybind11;

namespace {

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
  const sfgs::RenderResult r = sfgs::render(g, background, camera, options);
  py::dict out;
  out["image"] = r.image;
  out["alpha"] = r.alpha;
  out["depth"] = r.depth;
  out["radii"] = r.radii;
  out["visible"] = r.visible;
  return out;
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
  m.attr("LOW_PASS_VARIANCE_PX2") = sfgs::kLowPassVariancePx2;
  m.attr("MIN_ALPHA") = sfgs::kMinAlpha;
  m.attr("MAX_ALPHA") = sfgs::kMaxAlpha;
  m.attr("MIN_TRANSMITTANCE") = sfgs::kMinTransmittance;
  m.attr("TILE_SIZE") = sfgs::kTileSize;
}
