// What makes an avatar hold up on motions it never saw: the time branch and the colour offset can be left out (and
// then truly are), the observation record of training reaches the avatar, and the observation prior replaces the
// learned colour and offsets of poorly observed Gaussians only, with colours propagated over the mesh from the observed
// surface.
#include <cmath>

#include <ATen/ATen.h>
#include <gtest/gtest.h>

#include "body/mesh.h"
#include "body/parts.h"
#include "model/observation_prior.h"
#include "train/run_folder.h"
#include "test_avatar_utils.h"
#include "test_files.h"
#include "test_trainer_utils.h"
#include "train/rounds.h"

namespace sfgs::testing {
namespace {

using model::Avatar;
using model::AvatarOutput;

// A strip of 5 x 2 vertices at x = 0..4, y = 0..1, triangulated.
body::VertexNeighbours strip_neighbours() {
  std::vector<int64_t> faces;
  for (int64_t i = 0; i < 4; ++i) {
    const int64_t a = 2 * i, b = 2 * i + 1, c = 2 * i + 2, d = 2 * i + 3;  // (i,0) (i,1) (i+1,0) (i+1,1)
    faces.insert(faces.end(), {a, c, b, b, c, d});
  }
  return body::vertex_neighbours(at::tensor(faces, at::kLong).view({-1, 3}), 10);
}

TEST(AvatarObservation, PropagationKeepsObservedValuesAndFillsTheRestFromThem) {
  const body::VertexNeighbours neighbours = strip_neighbours();
  at::Tensor values = at::full({10, 1}, 100.0);  // what a poorly observed point learned: garbage
  at::Tensor confidence = at::zeros({10});
  for (int64_t v : {0, 1}) values[v] = 1.0, confidence[v] = 1.0;  // x = 0 observed, value 1
  for (int64_t v : {8, 9}) values[v] = 3.0, confidence[v] = 1.0;  // x = 4 observed, value 3
  const at::Tensor out = model::propagate_from_observed(values, confidence, neighbours);
  for (int64_t v : {0, 1}) EXPECT_DOUBLE_EQ(out[v][0].item<double>(), 1.0);
  for (int64_t v : {8, 9}) EXPECT_DOUBLE_EQ(out[v][0].item<double>(), 3.0);
  for (int64_t x = 1; x < 4; ++x) {
    const double here = out[2 * x][0].item<double>(), before = out[2 * (x - 1)][0].item<double>();
    EXPECT_GT(here, 1.0) << "x = " << x;
    EXPECT_LT(here, 3.0) << "x = " << x;
    EXPECT_GE(here, before) << "propagated values run from one observed end to the other";
  }
  // Half-trusted points keep half of what they learned.
  at::Tensor half = confidence.clone();
  half[4] = 0.5;
  const at::Tensor blended = model::propagate_from_observed(values, half, neighbours);
  const at::Tensor alone = model::propagate_from_observed(values, confidence, neighbours);
  EXPECT_NEAR(blended[4][0].item<double>(), 0.5 * 100.0 + 0.5 * alone[4][0].item<double>(), 1.0);
  // Nothing observed: nothing to propagate from, values unchanged.
  EXPECT_TRUE(at::equal(model::propagate_from_observed(values, at::zeros({10}), neighbours), values));
  EXPECT_THROW(model::propagate_from_observed(values, at::zeros({9}), neighbours), c10::Error);
}

TEST(AvatarObservation, FrameObservationCountsFrontFacingUnoccludedPointsInView) {
  Camera camera = Camera::looking_forward(100.0, 100, 100);  // at the origin, looking along +z
  // Facing the camera in view; occluded (behind the rendered surface); facing away; outside the image.
  const at::Tensor means =
      at::tensor({0.0, 0.0, 2.0, 0.1, 0.0, 2.5, -0.1, 0.0, 2.0, 3.0, 0.0, 2.0}, at::kFloat).view({4, 3});
  const at::Tensor normals =
      at::tensor({0.0, 0.0, -1.0, 0.0, 0.0, -1.0, 0.0, 0.0, 1.0, 0.0, 0.0, -1.0}, at::kFloat).view({4, 3});
  const at::Tensor depth = at::full({100, 100}, 2.0f);
  const at::Tensor seen = model::frame_observation(means, normals, depth, camera);
  EXPECT_NEAR(seen[0].item<float>(), 1.0f, 1e-6f);
  EXPECT_EQ(seen[1].item<float>(), 0.0f);
  EXPECT_EQ(seen[2].item<float>(), 0.0f);
  EXPECT_EQ(seen[3].item<float>(), 0.0f);
  // A point seen at a slant counts by its cosine.
  const at::Tensor slanted = at::tensor({0.0, std::sqrt(0.5), -std::sqrt(0.5)}, at::kFloat).view({1, 3});
  EXPECT_NEAR(model::frame_observation(means.narrow(0, 0, 1), slanted, depth, camera)[0].item<float>(), std::sqrt(0.5f),
              1e-5f);
}

TEST(Avatar, WithoutATimeTheTimeBranchIsLeftOut) {
  Avatar avatar(procedural_avatar_body(), subject_betas(), small_config());
  randomise_parameters(*avatar, 0.1, 5);
  at::NoGradGuard no_grad;
  const body::SmplxPose pose = test_pose(5, 0.4, true);
  const AvatarOutput no_time = avatar->forward(pose, std::nullopt), timed = avatar->forward(pose, kTestTime);
  for (const auto& p : avatar->named_parameters())
    if (p.key().find("hexplane_time") != std::string::npos) p.value().add_(1.0);
  EXPECT_EQ(max_abs_difference(avatar->forward(pose, std::nullopt).colours, no_time.colours), 0.0)
      << "the time planes must not reach a frame without a time";
  EXPECT_GT(max_abs_difference(avatar->forward(pose, kTestTime).colours, timed.colours), 1e-4);
  // Cached inference keeps the timeless attributes apart from the timed ones.
  avatar->eval();
  const AvatarOutput uncached = avatar->forward(pose, std::nullopt), uncached_timed = avatar->forward(pose, kTestTime);
  avatar->cache_static_features();
  for (int repeat = 0; repeat < 2; ++repeat) {
    EXPECT_EQ(max_abs_difference(avatar->forward(pose, kTestTime).colours, uncached_timed.colours), 0.0);
    EXPECT_EQ(max_abs_difference(avatar->forward(pose, std::nullopt).colours, uncached.colours), 0.0);
  }
}

TEST(Avatar, TheColourOffsetIsAResidualOfReplay) {
  Avatar avatar(procedural_avatar_body(), subject_betas(), small_config());
  randomise_parameters(*avatar, 0.1, 8);
  model::AvatarConfig without_offset = small_config();
  without_offset.use_colour_offset = false;
  Avatar plain(procedural_avatar_body(), subject_betas(), without_offset);
  copy_parameters(*avatar, *plain);
  at::NoGradGuard no_grad;
  const body::SmplxPose pose = test_pose(8, 0.4, true);
  // A new motion (no time): exactly the avatar without the module.
  const AvatarOutput novel = avatar->forward(pose, std::nullopt);
  EXPECT_FALSE(novel.colour_offset.defined());
  EXPECT_EQ(max_abs_difference(novel.colours, plain->forward(pose, std::nullopt).colours), 0.0);
  // Replay (a time): the offset is there and changes the colours.
  const AvatarOutput replay = avatar->forward(pose, kTestTime);
  ASSERT_TRUE(replay.colour_offset.defined());
  EXPECT_GT(max_abs_difference(replay.colours, plain->forward(pose, kTestTime).colours), 1e-4);
  // The paper's behaviour on request: every frame gets it.
  model::AvatarConfig everywhere = small_config();
  everywhere.colour_offset_on_new_motions = true;
  Avatar paper(procedural_avatar_body(), subject_betas(), everywhere);
  copy_parameters(*avatar, *paper);
  const AvatarOutput paper_novel = paper->forward(pose, std::nullopt);
  ASSERT_TRUE(paper_novel.colour_offset.defined());
  EXPECT_GT(max_abs_difference(paper_novel.colours, novel.colours), 1e-4);
}

TEST(Avatar, ObservationPriorChangesOnlyPoorlyObservedGaussiansAndOnlyInEvalMode) {
  model::AvatarConfig config = small_config();
  config.use_colour_offset = false;  // with no shading, colours are then the sigmoid of the propagated logits alone
  config.use_shading = false;
  Avatar avatar(procedural_avatar_body(), subject_betas(), config);
  randomise_parameters(*avatar, 0.3, 6);
  at::NoGradGuard no_grad;
  const body::SmplxPose pose = test_pose(6, 0.4, true);
  avatar->eval();
  const AvatarOutput plain = avatar->forward(pose, std::nullopt);
  const int64_t n = avatar->gaussian_count();
  avatar->set_observation(at::ones({n}));
  EXPECT_EQ(max_abs_difference(avatar->forward(pose, std::nullopt).colours, plain.colours), 0.0)
      << "a fully observed avatar is unchanged";
  // The face never observed: its colours and offsets change, nothing else does.
  const at::Tensor face = avatar->part_labels() == int64_t(body::BodyPart::kFace);
  avatar->set_observation(at::where(face, at::zeros({n}), at::ones({n})));
  const AvatarOutput prior = avatar->forward(pose, std::nullopt);
  const at::Tensor colour_change = (prior.colours - plain.colours).abs().amax(1);
  EXPECT_EQ(colour_change.masked_select(face.logical_not()).max().item<float>(), 0.0f);
  EXPECT_GT(colour_change.masked_select(face).mean().item<float>(), 1e-3f);
  EXPECT_EQ(max_abs_difference(prior.canonical_means.index({face.logical_not()}),
                               plain.canonical_means.index({face.logical_not()})),
            0.0);
  EXPECT_GT(max_abs_difference(prior.canonical_means.index({face}), plain.canonical_means.index({face})), 1e-5)
      << "the learned offsets of unobserved Gaussians are dropped";
  // Propagated colours are means of observed ones: within the observed range, channel by channel.
  const at::Tensor observed = plain.colours.index({face.logical_not()}), filled = prior.colours.index({face});
  EXPECT_TRUE((std::get<0>(filled.max(0)) <= std::get<0>(observed.max(0)) + 1e-6f).all().item<bool>());
  EXPECT_TRUE((std::get<0>(filled.min(0)) >= std::get<0>(observed.min(0)) - 1e-6f).all().item<bool>());
  // Training mode ignores the record.
  avatar->train();
  EXPECT_EQ(max_abs_difference(avatar->forward(pose, std::nullopt).colours, plain.colours), 0.0);
  expect_error_mentioning([&] { avatar->set_observation(at::ones({n + 1})); }, "observation record");
  expect_error_mentioning([&] { avatar->set_observation(at::full({n}, -1.0)); }, "non-negative");
}

TEST(Avatar, TrainingRecordsWhatItObservedAndTheCheckpointCarriesIt) {
  TempFolder folder;
  const data::Dataset video = tiny_video(folder, 10, 32);
  train::TrainConfig config = tiny_train_config();
  const train::RunFolder run{folder / "run"};
  train::train_avatar(video, config, run, quiet());
  const train::TrainedAvatar trained = train::load_trained_avatar(run, at::kCPU);
  const at::Tensor observation = trained.avatar->observation();
  ASSERT_TRUE(observation.defined());
  ASSERT_EQ(observation.size(0), trained.avatar->gaussian_count());
  EXPECT_GE(observation.min().item<float>(), 0.0f);
  EXPECT_LE(observation.max().item<float>(), 1.0f);
  EXPECT_GT(observation.max().item<float>(), 0.5f) << "the front faces the camera in every step";
  EXPECT_GT((observation == 0).sum().item<int64_t>(), 0) << "the back is never seen from the front";
  // The sampling record: a pixel's world length at each Gaussian, the finest any training view gave it.
  const at::Tensor sampling = trained.avatar->sampling_record();
  ASSERT_TRUE(sampling.defined());
  ASSERT_EQ(sampling.size(0), trained.avatar->gaussian_count());
  EXPECT_TRUE(sampling.isfinite().all().item<bool>());
  EXPECT_GT(sampling.min().item<float>(), 0.0f);
  const Camera camera = train::render_camera(video.frames[0]);
  const double nearest = camera.world_to_camera[11] - 1.0, farthest = camera.world_to_camera[11] + 1.0;
  EXPECT_GT(sampling.min().item<double>(), nearest / std::sqrt(camera.fx * camera.fy));
  EXPECT_LT(sampling.max().item<double>(), farthest / std::sqrt(camera.fx * camera.fy));
}

}  // namespace
}  // namespace sfgs::testing
