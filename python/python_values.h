#pragma once
// Python values into C++ ones for the module's bindings, with messages that name the argument, the type expected
// and the type that came (instead of pybind11's "Unable to cast Python instance to C++ type").
#include <optional>
#include <string>
#include <vector>

#include <torch/extension.h>

#include "data/dataset.h"
#include "ops/splat/splat.h"

namespace sfgs::python {

namespace py = pybind11;

inline std::string python_type(const py::handle& value) { return py::str(py::type::handle_of(value).attr("__name__")); }

inline at::Tensor to_tensor(const py::handle& value, const std::string& what) {
  if (THPVariable_Check(value.ptr())) {
    const at::Tensor t = THPVariable_Unpack(value.ptr());
    // A meta tensor has no values to read: refused here rather than by the first operation that reads one.
    if (t.defined() && !(t.is_cpu() || t.is_cuda()))
      throw py::value_error(what + ": expected a tensor on the CPU or a CUDA device, got one on " + t.device().str());
    return t;
  }
  throw py::type_error(
      what + ": expected a torch.Tensor, got " + python_type(value) +
      (py::isinstance<py::list>(value) || py::isinstance<py::tuple>(value) ? " (wrap it: torch.tensor(...))" : ""));
}

inline int64_t to_int(const py::handle& value, const std::string& what) {
  if (py::isinstance<py::bool_>(value) || !py::isinstance<py::int_>(value))
    throw py::type_error(what + ": expected an int, got " + python_type(value) + " " + std::string(py::repr(value)));
  return value.cast<int64_t>();
}

inline double to_double(const py::handle& value, const std::string& what) {
  if (py::isinstance<py::bool_>(value) || !(py::isinstance<py::int_>(value) || py::isinstance<py::float_>(value)))
    throw py::type_error(what + ": expected a number, got " + python_type(value) + " " + std::string(py::repr(value)));
  return value.cast<double>();
}

inline std::optional<at::Tensor> to_optional_tensor(const py::handle& value, const std::string& what) {
  if (value.is_none()) return std::nullopt;
  return to_tensor(value, what);
}

// A camera as the Python API gives and takes it.
inline py::dict camera_dict(const sfgs::Camera& c) {
  py::dict d;
  d["world_to_camera"] =
      at::tensor(std::vector<double>(c.world_to_camera.begin(), c.world_to_camera.end()), at::kDouble).view({4, 4});
  d["fx"] = c.fx;
  d["fy"] = c.fy;
  d["cx"] = c.cx;
  d["cy"] = c.cy;
  d["width"] = c.width;
  d["height"] = c.height;
  return d;
}

// A render's result as the Python API returns it.
inline py::dict result_dict(const sfgs::RenderResult& r) {
  py::dict out;
  out["image"] = r.image;
  out["alpha"] = r.alpha;
  out["depth"] = r.depth;
  out["radii"] = r.radii;
  out["visible"] = r.visible;
  return out;
}

// Renders of a batch as one result, each output stacked along a new first dimension.
inline sfgs::RenderResult stacked(const std::vector<sfgs::RenderResult>& frames) {
  const auto all = [&](at::Tensor sfgs::RenderResult::*member) {
    std::vector<at::Tensor> tensors;
    for (const sfgs::RenderResult& r : frames) tensors.push_back(r.*member);
    return at::stack(tensors);
  };
  sfgs::RenderResult r;
  r.image = all(&sfgs::RenderResult::image);
  r.alpha = all(&sfgs::RenderResult::alpha);
  r.depth = all(&sfgs::RenderResult::depth);
  r.radii = all(&sfgs::RenderResult::radii);
  r.visible = all(&sfgs::RenderResult::visible);
  return r;
}

// Dataset frame `index` without its images: {'pose': dict (with 'time', None for a frame without replay time),
// 'camera': dict, 'split': 'train'|'val'|'test' (absent when in none), 'name'}. bindings_data.cpp.
py::dict frame_record_dict(const sfgs::data::Dataset& dataset, int64_t index);

// The metrics (psnr, ssim, lpips) and dataset reading (read_dataset), bindings_data.cpp.
void bind_metrics_and_data(py::module_& m);
// Trained avatars (Avatar, load_avatar) and motion files (read_motion), bindings_avatar.cpp.
void bind_avatar(py::module_& m);
// The SMPL-X and MANO layers (Smplx, Mano), bindings_body.cpp.
void bind_body_layers(py::module_& m);

}  // namespace sfgs::python
