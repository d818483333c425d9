#pragma once
// Reading and checking the arrays of body-model files, shared by the SMPL-X and MANO loaders and layers
// (internal to csrc/body). Every message names the file or model, the array, what was expected and what came.
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include <ATen/core/Tensor.h>
#include <c10/util/Exception.h>

#include "body/mesh.h"
#include "body/tensor_checks.h"
#include "io/npz.h"

namespace sfgs::body {

// Typed access to the arrays of one model file; shapes use -1 for "any size".
class ModelArrays {
 public:
  ModelArrays(const io::NpzArchive& npz, std::string model) : npz_(npz), model_(std::move(model)) {}
  std::string name(const char* key) const;                                        // "'J_regressor' of '<path>'"
  at::Tensor floating(const char* key, const std::vector<int64_t>& shape) const;  // float64, C-contiguous
  at::Tensor faces(const char* key, int64_t num_vertices) const;                  // int64 (F, 3)
  // kintree_table (2, J): row 0 holds the parents, whatever marks the root in [0, 0].
  std::vector<int64_t> parents(const char* key, int64_t joints) const;
  // posedirs (V, 3, 9 (J - 1)); undefined when all zero (a model without pose correctives).
  at::Tensor posedirs(const char* key, int64_t num_vertices, int64_t joints) const;
  at::Tensor labels(const char* key, int64_t num_vertices) const;  // uint8 BodyPart labels

 private:
  const io::NpzArchive& npz_;
  std::string model_;
};

// Consistency checks of model data built in memory or loaded; `what` names the model ("MANO model 'x.npz'").
class ModelChecks {
 public:
  explicit ModelChecks(std::string what) : what_(std::move(what)) {}
  void floating(const at::Tensor& t, const char* name, const std::vector<int64_t>& shape) const;  // and finite
  void weights(const at::Tensor& t, const char* name, int64_t vertices, int64_t joints) const;
  void parents(const std::vector<int64_t>& parents, int64_t joints) const;
  void labels(const at::Tensor& t, const char* name, int64_t vertices) const;
  // PCA hand-pose components: (K, 45) with 1 <= K <= 45.
  void hand_components(const at::Tensor& t, const char* name) const;

  // The arrays every skinned model has (SmplxModelData, ManoModelData): template, faces, joint regressor, skinning
  // weights, kinematic tree, shape and pose blend shapes. Returns the vertex count.
  template <typename ModelData> int64_t skinned_model(const ModelData& d, int64_t joints) const {
    TORCH_CHECK(d.v_template.defined() && d.v_template.dim() == 2 && d.v_template.size(1) == 3, what_,
                ": v_template must have shape (V, 3), got ", describe(d.v_template));
    const int64_t v = d.v_template.size(0);
    floating(d.v_template, "v_template", {v, 3});
    checked_faces(d.faces, v, what_ + ": faces");
    floating(d.j_regressor, "j_regressor", {joints, v});
    weights(d.weights, "weights", v, joints);
    parents(d.parents, joints);
    floating(d.shapedirs, "shapedirs", {v, 3, -1});
    if (d.posedirs.defined()) floating(d.posedirs, "posedirs", {v, 3, 9 * (joints - 1)});
    return v;
  }

 private:
  std::string what_;
};

using NamedTensors = std::vector<std::pair<const char*, const at::Tensor*>>;

// The batch size B shared by the defined inputs: `batched` ones always lead with it, `optionally_batched` ones
// only when they have three dimensions. 1 when nothing is given.
int64_t common_batch_size(const char* layer, const NamedTensors& batched, const NamedTensors& optionally_batched);

}  // namespace sfgs::body
