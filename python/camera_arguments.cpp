#include "camera_arguments.h"

#include "python_values.h"

namespace sfgs::python {
namespace {

// A number, or a tensor of one value (kept with its gradient), as a 0-dim float64 tensor.
at::Tensor scalar_tensor(const py::handle& value, const std::string& what) {
  if (!THPVariable_Check(value.ptr())) return at::scalar_tensor(to_double(value, what), at::kDouble);
  const at::Tensor t = to_tensor(value, what);
  TORCH_CHECK(t.numel() == 1 && at::isFloatingType(t.scalar_type()), what,
              ": expected a number or a floating tensor of one value, got ", t.numel(), " values of ", t.scalar_type());
  return t.reshape({}).to(at::kDouble);
}

}  // namespace

CameraArgument camera_argument(const py::handle& world_to_camera, const py::handle& fx, const py::handle& fy,
                               const py::handle& cx, const py::handle& cy, int64_t width, int64_t height,
                               double near_plane, double far_plane,
                               const std::function<std::string(const std::string&)>& name) {
  CameraTensors tensors;
  tensors.world_to_camera = to_tensor(world_to_camera, name("world_to_camera"));
  tensors.intrinsics = at::stack({scalar_tensor(fx, name("fx")), scalar_tensor(fy, name("fy")),
                                  scalar_tensor(cx, name("cx")), scalar_tensor(cy, name("cy"))});
  tensors.width = width;
  tensors.height = height;
  tensors.near_plane = near_plane;
  tensors.far_plane = far_plane;
  CameraArgument camera;
  camera.value = tensors.value();
  // Under grad mode the stacked intrinsics require a gradient when any of the four given tensors does.
  if (at::GradMode::is_enabled() && tensors.requires_grad()) camera.tensors = std::move(tensors);
  return camera;
}

CameraArgument camera_argument(const py::handle& camera) {
  if (!py::isinstance<py::dict>(camera))
    throw py::type_error("camera: expected a dict (world_to_camera, fx, fy, cx, cy, width, height), got " +
                         python_type(camera));
  const py::dict d = py::reinterpret_borrow<py::dict>(camera);
  for (const char* key : {"world_to_camera", "fx", "fy", "cx", "cy", "width", "height"})
    TORCH_CHECK(d.contains(key), "camera: expected a dict with world_to_camera, fx, fy, cx, cy, width and height; '",
                key, "' is missing");
  return camera_argument(d["world_to_camera"], d["fx"], d["fy"], d["cx"], d["cy"],
                         to_int(d["width"], "camera['width']"), to_int(d["height"], "camera['height']"),
                         kDefaultNearPlane, kDefaultFarPlane,
                         [](const std::string& key) { return "camera['" + key + "']"; });
}

RenderResult render_through(const Gaussians& gaussians, const at::Tensor& background, const CameraArgument& camera,
                            const RenderOptions& options) {
  if (!camera.tensors) return render(gaussians, background, camera.value, options);
  return render(seen_from(gaussians, *camera.tensors), background, camera_at_origin_of(camera.value), options);
}

}  // namespace sfgs::python
