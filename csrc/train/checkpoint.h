#pragma once
// checkpoint.pt, a run's state: the avatar, the optimiser, the iteration, the random state, the full configuration
// and which dataset it was trained on. Written atomically and only when every parameter is finite; read back with a
// checksum per avatar tensor (and one over the optimiser state), so a damaged file is refused by name instead of
// evaluating to wrong numbers. Version 1 files (no checksums, relative dataset paths) still load.
#include <memory>
#include <string>

#include <ATen/core/Tensor.h>
#include <nlohmann/json.hpp>
#include <torch/optim/adam.h>
#include <torch/optim/optimizer.h>
#include <torch/serialize/input-archive.h>

#include "model/avatar.h"
#include "train/train_config.h"

namespace sfgs::train {

// Adam with the colour networks in their own parameter group (their own learning rate): the optimiser a run's
// checkpoint holds the state of.
std::unique_ptr<torch::optim::Adam> make_optimizer(const model::Avatar& avatar, const Schedule& schedule);

struct CheckpointInfo {
  int64_t version = 0;              // of the file format
  int64_t iteration = 0;            // training steps done
  double training_seconds = 0;      // time spent in those steps (validation and checkpoints excluded)
  std::string rng_state;            // the trainer's frame and background sampler
  TrainConfig config;               // the configuration the run was trained with
  std::string dataset;              // the dataset folder (absolute from version 2 on)
  std::string dataset_fingerprint;  // Dataset::fingerprint() of it; empty in version 1
  at::Tensor betas;                 // the subject's shape, float32 (B)
  // The avatar's observation record as training keeps it: per Gaussian, the sum over `observation_steps` training
  // steps of how squarely each saw it (float32 (N); undefined: no record, as in runs trained before it existed).
  at::Tensor observation_sum;
  int64_t observation_steps = 0;
  // The sampling record as training keeps it: per Gaussian, the smallest world footprint of a pixel a training step
  // had of it, +inf where none held it (float32 (N); undefined: none, as in runs trained before it existed).
  at::Tensor footprint_minimum;
  // PoseRefinement::state() of a run that refines its poses; undefined otherwise.
  at::Tensor pose_refinement;
};

// Writes the checkpoint atomically. Refuses (std::runtime_error naming the tensor) when a parameter is not finite:
// a diverged run keeps its last good checkpoint.
void save_checkpoint(const std::string& path, const CheckpointInfo& info, const model::Avatar& avatar,
                     torch::optim::Optimizer& optimizer);

class CheckpointReader {
 public:
  // Opens the file and reads everything but the avatar and optimiser state; errors name the file and what is wrong.
  explicit CheckpointReader(const std::string& path);
  const CheckpointInfo& info() const { return info_; }
  // Loads the avatar's parameters and buffers into `avatar` (built from info().config and info().betas) and
  // verifies them: they match their checksums and every floating value is finite.
  void load_avatar(model::Avatar& avatar);
  void load_optimizer(torch::optim::Optimizer& optimizer);

 private:
  std::string path_;
  torch::serialize::InputArchive archive_;
  CheckpointInfo info_;
  nlohmann::json checksums_;
};

// The first parameter or buffer of `module` holding NaN or Inf, as "'name' (k of n values)"; empty when all are
// finite. One device synchronisation.
std::string first_non_finite_tensor(const torch::nn::Module& module);

}  // namespace sfgs::train
