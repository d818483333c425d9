#include "body/model_arrays.h"

#include <ATen/Functions.h>
#include <ATen/TensorOperators.h>
#include <c10/util/Exception.h>

#include "body/mesh.h"
#include "body/parts.h"
#include "body/skeleton.h"
#include "body/tensor_checks.h"
#include "body/constants.h"

namespace sfgs::body {
namespace {

bool shape_matches(const at::Tensor& t, const std::vector<int64_t>& shape) {
  if (!t.defined() || t.dim() != static_cast<int64_t>(shape.size())) return false;
  for (size_t d = 0; d < shape.size(); ++d)
    if (shape[d] >= 0 && t.size(static_cast<int64_t>(d)) != shape[d]) return false;
  return true;
}

std::string shape_text(const std::vector<int64_t>& shape) {
  std::string text = "(";
  for (size_t d = 0; d < shape.size(); ++d) text += (d ? ", " : "") + (shape[d] < 0 ? "*" : std::to_string(shape[d]));
  return text + (shape.size() == 1 ? ",)" : ")");
}

}  // namespace

std::string ModelArrays::name(const char* key) const { return "'" + std::string(key) + "' of '" + npz_.path() + "'"; }

at::Tensor ModelArrays::floating(const char* key, const std::vector<int64_t>& shape) const {
  TORCH_CHECK(npz_.contains(key), "'", npz_.path(), "' is not an ", model_, " model file: it has no array '", key, "'");
  const at::Tensor t = npz_.read(key);
  TORCH_CHECK(at::isFloatingType(t.scalar_type()) && shape_matches(t, shape), name(key),
              " must be a floating array of ", "shape ", shape_text(shape), ", got ", describe(t));
  return t.to(at::kDouble).contiguous();
}

at::Tensor ModelArrays::faces(const char* key, int64_t num_vertices) const {
  TORCH_CHECK(npz_.contains(key), "'", npz_.path(), "' is not an ", model_, " model file: it has no array '", key, "'");
  return checked_faces(npz_.read(key), num_vertices, name(key));
}

std::vector<int64_t> ModelArrays::parents(const char* key, int64_t joints) const {
  TORCH_CHECK(npz_.contains(key), "'", npz_.path(), "' is not an ", model_, " model file: it has no array '", key, "'");
  const at::Tensor table = npz_.read(key);
  TORCH_CHECK(at::isIntegralType(table.scalar_type(), /*includeBool=*/false) && table.dim() == 2 &&
                  table.size(0) == 2 && table.size(1) == joints,
              name(key), " must be an integer array of shape (2, ", joints, "), got ", describe(table));
  const at::Tensor row = table.select(0, 0).to(at::kLong).contiguous();
  std::vector<int64_t> parents(row.data_ptr<int64_t>(), row.data_ptr<int64_t>() + joints);
  parents[0] = -1;
  ModelChecks(name(key)).parents(parents, joints);
  return parents;
}

at::Tensor ModelArrays::posedirs(const char* key, int64_t num_vertices, int64_t joints) const {
  const at::Tensor t = floating(key, {num_vertices, 3, 9 * (joints - 1)});
  return t.abs().max().item<double>() == 0.0 ? at::Tensor() : t;
}

at::Tensor ModelArrays::labels(const char* key, int64_t num_vertices) const {
  const at::Tensor t = npz_.read(key);
  ModelChecks(name(key)).labels(t, key, num_vertices);
  return t.to(at::kByte);
}

void ModelChecks::floating(const at::Tensor& t, const char* name, const std::vector<int64_t>& shape) const {
  TORCH_CHECK(shape_matches(t, shape) && at::isFloatingType(t.scalar_type()), what_, ": ", name,
              " must be a floating tensor of shape ", shape_text(shape), ", got ", describe(t));
  TORCH_CHECK(t.numel() == 0 || at::isfinite(t).all().item<bool>(), what_, ": ", name,
              " holds NaN or infinite values (the file is damaged)");
}

void ModelChecks::weights(const at::Tensor& t, const char* name, int64_t vertices, int64_t joints) const {
  floating(t, name, {vertices, joints});
  if (vertices == 0) return;
  const double worst = (t.sum(1) - 1).abs().max().item<double>();
  if (worst > kSkinningWeightSumTolerance)
    TORCH_WARN(what_, ": the ", name, " of some vertex sum to 1 +- ", worst, " instead of 1");
}

void ModelChecks::parents(const std::vector<int64_t>& parents, int64_t joints) const {
  TORCH_CHECK(static_cast<int64_t>(parents.size()) == joints && joints > 0 && parents[0] == -1, what_,
              ": the kinematic tree must have ", joints, " joints with the root first, got ", parents.size(),
              " joints");
  for (int64_t j = 1; j < joints; ++j) {
    TORCH_CHECK(parents[j] >= 0 && parents[j] < j, what_, ": the parent of joint ", j,
                " must be an earlier joint, got ", parents[j]);
  }
}

void ModelChecks::hand_components(const at::Tensor& t, const char* name) const {
  floating(t, name, {-1, kHandPoseSize});
  TORCH_CHECK(t.size(0) >= 1 && t.size(0) <= kHandPoseSize, what_, ": ", name, " must have 1 to ", kHandPoseSize,
              " components, got ", t.size(0));
}

void ModelChecks::labels(const at::Tensor& t, const char* name, int64_t vertices) const {
  TORCH_CHECK(t.defined() && t.dim() == 1 && t.size(0) == vertices &&
                  at::isIntegralType(t.scalar_type(), /*includeBool=*/false),
              what_, ": ", name, " must be integer labels of shape (", vertices, "), got ", describe(t));
  TORCH_CHECK(t.numel() == 0 || (t.min().item<int64_t>() >= 0 && t.max().item<int64_t>() < kBodyPartCount), what_, ": ",
              name, " must lie in [0, ", kBodyPartCount, ")");
}

int64_t common_batch_size(const char* layer, const NamedTensors& batched, const NamedTensors& optionally_batched) {
  const char* first = nullptr;
  int64_t batch = 1;
  const auto visit = [&](const char* name, const at::Tensor& t) {
    TORCH_CHECK(t.dim() >= 1, layer, ": ", name, " needs a batch dimension, got ", describe(t));
    if (first == nullptr) {
      first = name;
      batch = t.size(0);
    }
    TORCH_CHECK(t.size(0) == batch, layer, ": inputs disagree on the batch size: ", first, " has ", batch, ", ", name,
                " has ", t.size(0));
  };
  for (const auto& [name, t] : batched)
    if (t->defined()) visit(name, *t);
  for (const auto& [name, t] : optionally_batched)
    if (t->defined() && t->dim() == 3) visit(name, *t);
  return batch;
}

}  // namespace sfgs::body
