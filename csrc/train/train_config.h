#pragma once
// Everything a training run is configured by, read from YAML (configs/*.yaml). Unknown keys are errors, so a typo
// never silently falls back to a default. docs/training.md lists every key.
#include <string>
#include <vector>

#include "train/constants.h"
#include "model/avatar.h"

namespace sfgs::train {

// Per body part weights of a regulariser (body::BodyPart order: body, face, left hand, right hand).
struct PartWeights {
  double body = 1, face = 1, hands = 1;
};

struct LossWeights {
  double image = 0.8;         // lambda_1 on (L1 + (1 - SSIM) + LPIPS)
  double lab = 0.3;           // lambda_a on L1 in CIELAB
  double gradient = 0.01;     // lambda_g on L1 of image gradients
  bool use_lpips = true;      // AlexNet LPIPS (the shared weights); skipped, with a log line, when unavailable
  std::string lpips_weights;  // folder holding lpips_alex.safetensors; empty: the default search
  // LPIPS in every k-th training step only (its AlexNet forward and backward are the costliest loss); the steps
  // between carry L1, SSIM and the rest. docs/performance.md measures what it costs the metrics.
  int64_t lpips_every = 1;
  // CUDA: the LPIPS loss's AlexNet trunk in bfloat16 on tensor cores (metrics::Lpips::with_trunk_dtype; the taps'
  // normalisation and the distance stay float32). docs/performance.md measures its effect on the final metrics.
  bool lpips_bfloat16 = true;
  // Regularisers.
  double mean_offset = 1.0;
  PartWeights mean_offset_parts{10, 1, 1000};
  double scale = 1.0;
  PartWeights scale_parts{1, 10, 1000};
  double laplacian_mean = 1e5;
  PartWeights laplacian_mean_parts{1, 50, 1};
  double laplacian_scale = 1e5;
};

struct Schedule {
  int64_t iterations = 3000;
  int64_t warmup_iterations = 100;              // learning rates ramp linearly from 0
  std::vector<double> decay_at{0.75, 0.95};     // fractions of the run
  std::vector<double> decay_factor{0.1, 0.01};  // learning-rate factor from each point on
  double learning_rate = 1e-3;                  // feature planes, networks, embeddings
  double colour_learning_rate = 1e-3;
  double adam_epsilon = 1e-15;
  // CUDA: Adam as one fused multi-tensor kernel per parameter group (train/adam_step.h); the same update.
  bool fused_adam = true;
  // CUDA: float32 matrix products (the networks' layers) on TF32 tensor cores: float32's range, a 10-bit mantissa,
  // several times the throughput; the losses and the splatting stay float32 (docs/performance.md measures both).
  bool tf32_matmul = true;
  // CUDA: each kind of step recorded once as a CUDA graph and replayed (train/step_graphs.h): the same kernels
  // without the host launching them one by one. Pose refinement's steps run eagerly either way.
  bool cuda_graphs = true;
};

// Pose refinement (train/pose_refinement.h, docs/training.md "Imperfect fits"): per training frame, a learned
// correction of the SMPL-X fit (axis-angles of the global orientation, body, jaw and fingers; translation).
struct PoseRefinementConfig {
  bool enabled = false;
  // Share of the run before the fits move (the avatar is a blur before): the earliest alignment pass.
  double start = 0.05;
  // Shares of the run at which every training frame's refined fit is aligned to its image with the avatar as it is
  // then (train/pose_fit.h, align_iterations each). From `start` on, rising. The passes carry the whole refinement:
  // each fits against a sharper avatar, and four (the placement at 10 %, every joint at 30, 50 and 70 %) brought a CPU
  // run's training frames within 1.4 dB of the exact-fit avatar's where two left 3.3 (docs/archive/results-history.md,
  // "Per-step corrections"), at about 40 % more training time.
  std::vector<double> align_at{0.1, 0.3, 0.5, 0.7};
  int64_t align_iterations = 60;
  // The alignment passes at or after this share of the run fit every joint as well (the avatar is sharp enough by
  // then to pose them); the earlier ones leave the joints.
  double align_joints_from = 0.3;
  // The alignment passes at or after this share fit the global orientation; the earlier ones the translation alone:
  // against an avatar still a blur a turn towards the camera or about the vertical is nearly free, and a pass at 10 %
  // that fitted it turned the roots from 4 to 6-9 degrees off (docs/archive/results-history.md, "Smoothness on
  // rotations"). At most align_joints_from: joints fitted under a held root would take up its error.
  double align_orientation_from = 0.3;
  // Weight of the drawn frame's whole-body keypoint reprojection error (train/avatar_keypoints.h) where the training
  // frames have detections (keypoints_whole_body/), also in the alignment passes; 0: the image alone. Without it the
  // refined fits drift together out of the camera's frame and the avatar learns them in that drifted frame.
  double keypoint_weight = kPoseFitKeypointWeight;
  // Standard deviation (seconds) of the temporal smoothing of the training fits (train/fit_smoothing.h): the input
  // fits before the first alignment pass and the fits each pass leaves, within each sequence; 0: none (the default).
  // The passes align each frame on its own, and the jitter of joints an image barely shows survives them. On the GPU
  // benchmark 0.1 (3 frames at 30 fps) brought the refined body joints 4.6 -> 4.1 deg and the training frames up
  // 0.6-0.9 dB, but not the test frames (fitted test poses: -1 to -1.5 dB on noisy fits, +0.1 on sfgs fit's);
  // docs/archive/results-history.md, "Temporal smoothing".
  double smoothing_seconds = 0;
  // Rounds of training (trainer.h, train_avatar): each round but the last trains a fresh avatar in the run folder's
  // round-K/ (K = 1, 2, ...) and hands its refined fits to the next as start fits; the last round is the run itself.
  // An avatar that trained on the unrefined fits has learnt their error and its passes agree with it; a fresh one
  // trained on the refined fits has not. On the GPU benchmark a second round on `sfgs fit`'s fits gained 0.6-0.8 dB
  // in three runs (a third lost 0.3), at twice the training time (docs/archive/results-history.md, "Two rounds").
  int64_t rounds = 1;

  // Whether training steps move the drawn frame's correction: either per-step rate positive.
};

// Which body model drives the avatar: empty smplx means the built-in procedural body (with its MANO-layout hands).
struct BodyFiles {
  std::string smplx;
  std::string mano_left, mano_right, hand_vertex_ids, face_vertex_ids;  // optional
};

struct TrainConfig {
  BodyFiles body;
  model::AvatarConfig avatar;
  LossWeights loss;
  Schedule schedule;
  PoseRefinementConfig pose_refinement;
  uint64_t seed = 1;
  std::string device = "cpu";
  int64_t log_every = 10;
  int64_t validate_every = 500;
  int64_t checkpoint_every = 1000;
  int64_t validation_frames = 4;  // validation PSNR over at most this many val frames

  static TrainConfig from_yaml_file(const std::string& path);
  static TrainConfig from_yaml_text(const std::string& text, const std::string& source = "<text>");
  // A run's stored config (its checkpoint's, which lists every key of its time): a key it lacks did not exist when the
  // run was made, so it takes the value that reproduces what the run did then, not today's default (a resumed run
  // must not change its objective): per-step corrections, no alignment passes, placement-only passes that fit the
  // orientation, no keypoint term.
  static TrainConfig from_stored_yaml_text(const std::string& text, const std::string& source);
  static TrainConfig from_stored_yaml_file(const std::string& path);  // a run folder's config.yaml
  std::string to_yaml() const;
  // Every value finite and in its range; errors name the key, the range and the value.
  void validate() const;
};

// A key whose value differs between two configs, with both values as YAML text.
struct ConfigChange {
  std::string key;  // "section.key"
  std::string before, after;
};
std::vector<ConfigChange> config_changes(const TrainConfig& before, const TrainConfig& after);
// Whether a resumed run may take this change: keys that steer how long and how the optimiser runs, what is logged and
// where (schedule.*, run.log_every, run.validate_every, run.checkpoint_every, run.validation_frames, run.device).
// Everything else changes the model, its objective or its data, and is refused.
bool change_allowed_on_resume(const std::string& key);

}  // namespace sfgs::train
