// The module's body-model layers: sfgs.Smplx and sfgs.Mano load the official .npz files (or the CC0 stand-ins of
// ../shared/bodies) and pose them, differentiably (docs/python.md, docs/body_models.md).
#include <algorithm>
#include <string>
#include <vector>

#include "body/mano.h"
#include "body/smplx.h"
#include "python_values.h"

namespace sfgs::python {
namespace {

using body::SmplxPose;

at::ScalarType dtype_of(const std::string& name) {
  if (name == "float32") return at::kFloat;
  if (name == "float64") return at::kDouble;
  throw py::value_error("dtype: expected 'float32' or 'float64', got '" + name + "'");
}

at::Tensor optional_input(const py::dict& inputs, const char* key, const std::string& where) {
  return inputs.contains(key) && !inputs[key].is_none() ? to_tensor(inputs[key], where + "['" + key + "']")
                                                        : at::Tensor();
}

// Every key of `inputs` must be one of `known` (a typo would otherwise silently leave that input at rest).
void check_keys(const py::dict& inputs, const std::vector<std::string>& known, const std::string& where) {
  for (const auto& item : inputs) {
    const std::string key = py::str(item.first);
    if (std::find(known.begin(), known.end(), key) != known.end()) continue;
    std::string expected;
    for (const std::string& k : known) expected += (expected.empty() ? "" : ", ") + k;
    throw py::value_error(where + ": unknown key '" + key + "'; expected one of " + expected);
  }
}

py::dict output_dict(const body::BodyOutput& o, const at::Tensor& faces) {
  py::dict d;
  d["vertices"] = o.vertices;
  d["joints"] = o.joints;
  d["joint_transforms"] = o.joint_transforms;
  d["faces"] = faces;
  return d;
}

class PySmplx {
 public:
  PySmplx(const std::string& path, int64_t num_betas, int64_t num_expression_coeffs, bool use_pca, bool flat_hand_mean,
          const std::string& device, const std::string& dtype) {
    body::SmplxOptions options;
    options.num_betas = num_betas;
    options.num_expression_coeffs = num_expression_coeffs;
    options.use_pca = use_pca;
    options.flat_hand_mean = flat_hand_mean;
    options.dtype = dtype_of(dtype);
    layer_ = body::Smplx(path, options);
    layer_->to(at::Device(device), options.dtype);
  }
  py::dict forward(const py::dict& inputs) const {
    std::vector<std::string> known{"betas"};
    for (const SmplxPose::Field& f : SmplxPose::fields()) known.push_back(f.name);
    check_keys(inputs, known, "Smplx.forward");
    body::SmplxInput input;
    for (const SmplxPose::Field& f : SmplxPose::fields())
      input.pose.*(f.member) = optional_input(inputs, f.name, "Smplx.forward");
    input.betas = optional_input(inputs, "betas", "Smplx.forward");
    return output_dict(layer_->forward(input), layer_->faces());
  }
  int64_t vertex_count() const { return layer_->vertex_count(); }

 private:
  body::Smplx layer_{nullptr};
};

class PyMano {
 public:
  PyMano(const std::string& path, int64_t num_betas, bool use_pca, int64_t num_pca_comps, bool flat_hand_mean,
         const std::string& device, const std::string& dtype) {
    body::ManoOptions options;
    options.num_betas = num_betas;
    options.use_pca = use_pca;
    options.num_pca_comps = num_pca_comps;
    options.flat_hand_mean = flat_hand_mean;
    options.dtype = dtype_of(dtype);
    layer_ = body::Mano(path, options);
    layer_->to(at::Device(device), options.dtype);
  }
  py::dict forward(const py::dict& inputs) const {
    check_keys(inputs, {"betas", "global_orient", "hand_pose", "transl"}, "Mano.forward");
    body::ManoInput input;
    input.betas = optional_input(inputs, "betas", "Mano.forward");
    input.global_orient = optional_input(inputs, "global_orient", "Mano.forward");
    input.hand_pose = optional_input(inputs, "hand_pose", "Mano.forward");
    input.transl = optional_input(inputs, "transl", "Mano.forward");
    return output_dict(layer_->forward(input), layer_->faces());
  }

 private:
  body::Mano layer_{nullptr};
};

}  // namespace

void bind_body_layers(py::module_& m) {
  py::class_<PySmplx>(m, "Smplx", "The SMPL-X layer from an official SMPLX_*.npz (docs/body_models.md)")
      .def(py::init<const std::string&, int64_t, int64_t, bool, bool, const std::string&, const std::string&>(),
           py::arg("path"), py::arg("num_betas") = 10, py::arg("num_expression_coeffs") = 10,
           py::arg("use_pca") = false, py::arg("flat_hand_mean") = false, py::arg("device") = "cpu",
           py::arg("dtype") = "float32")
      .def("forward", &PySmplx::forward, py::arg("inputs"),
           R"(Pose a batch: a dict of (B, ...) tensors with any of betas (B, num_betas), global_orient (B, 3), body_pose
(B, 21, 3), jaw_pose, leye_pose, reye_pose (B, 3), left_hand_pose, right_hand_pose (B, 15, 3), expression (B, E),
transl (B, 3); missing ones are at rest. Returns vertices (B, V, 3), joints (B, 55, 3), joint_transforms
(B, 55, 4, 4), faces (F, 3). Differentiable.)")
      .def("__call__", &PySmplx::forward, py::arg("inputs"))
      .def_property_readonly("vertex_count", &PySmplx::vertex_count);
  py::class_<PyMano>(m, "Mano", "The MANO layer from an official MANO_{LEFT,RIGHT}.npz (docs/body_models.md)")
      .def(py::init<const std::string&, int64_t, bool, int64_t, bool, const std::string&, const std::string&>(),
           py::arg("path"), py::arg("num_betas") = 10, py::arg("use_pca") = false, py::arg("num_pca_comps") = 6,
           py::arg("flat_hand_mean") = false, py::arg("device") = "cpu", py::arg("dtype") = "float32")
      .def("forward", &PyMano::forward, py::arg("inputs"),
           R"(Pose a batch: betas (B, num_betas), global_orient (B, 3), hand_pose (B, 45) or (B, num_pca_comps) with
use_pca, transl (B, 3); missing ones at rest. Returns vertices (B, 778, 3), joints (B, 16, 3), joint_transforms,
faces. Differentiable.)")
      .def("__call__", &PyMano::forward, py::arg("inputs"));
}

}  // namespace sfgs::python
