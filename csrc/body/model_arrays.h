#pragma once
// Reading and checking the arrays of body-model files, shared by the SMPL-X and MANO loaders and layers
// (internal to csrc/body). Every message names the file or model, the array, what was expected and what came.
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include <ATen/core/Tensor.h>

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

 private:
  std::string what_;
};

using NamedTensors = std::vector<std::pair<const char*, const at::Tensor*>>;

// The batch size B shared by the defined inputs: `batched` ones always lead with it, `optionally_batched` ones
// only when they have three dimensions. 1 when nothing is given.
int64_t common_batch_size(const char* layer, const NamedTensors& batched, const NamedTensors& optionally_batched);

}  // namespace sfgs::body
