#pragma once
// Cameras as the Python API takes them: numbers, or tensors that may carry a gradient. A camera whose
// world_to_camera or one of fx, fy, cx, cy is a tensor that requires a gradient (under grad mode) renders through
// sfgs::seen_from (ops/splat/camera_frame.h), so the image's gradient reaches it; any other renders as given.
#include <functional>
#include <optional>
#include <string>

#include <torch/extension.h>

#include "ops/splat/camera_frame.h"
#include "ops/splat/splat.h"

namespace sfgs::python {

namespace py = pybind11;

struct CameraArgument {
  Camera value;
  std::optional<CameraTensors> tensors;  // set when the caller differentiates with respect to the camera
};

// `name` gives each value's name in errors ("render(fx)", "camera['fx']").
CameraArgument camera_argument(const py::handle& world_to_camera, const py::handle& fx, const py::handle& fy,
                               const py::handle& cx, const py::handle& cy, int64_t width, int64_t height,
                               double near_plane, double far_plane,
                               const std::function<std::string(const std::string&)>& name);
// A camera dict (world_to_camera, fx, fy, cx, cy, width, height), as camera_dict() writes it.
CameraArgument camera_argument(const py::handle& camera);
inline Camera camera_from_dict(const py::handle& camera) { return camera_argument(camera).value; }

// The Gaussians rendered by the camera: moved by its tensors and rendered at the origin when it has them.
RenderResult render_through(const Gaussians& gaussians, const at::Tensor& background, const CameraArgument& camera,
                            const RenderOptions& options = {});

}  // namespace sfgs::python
