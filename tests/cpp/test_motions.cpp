// The motion library and the novel-motion split of `sfgs synth`: each motion does what its name says (checked on the
// posed joints of the built-in body), the split puts whole motions into test, and the ground truth that per-region
// evaluation needs is written.
#include <tuple>

#include <ATen/ATen.h>
#include <gtest/gtest.h>

#include "body/procedural_body.h"
#include "body/smplx.h"
#include "data/dataset.h"
#include "data/motions.h"
#include "data/synthetic.h"
#include "io/npz.h"
#include "test_files.h"

namespace sfgs::data {
namespace {

constexpr int64_t kPelvis = 0, kHead = 15, kLeftWrist = 20, kRightWrist = 21;

// Posed joints (J, 3) of the built-in body (y up) in `motion` at `seconds`.
at::Tensor joints_in(const std::string& motion, double seconds) {
  static const body::SmplxModelData model = body::make_procedural_body().smplx;
  body::SmplxOptions options;
  options.use_pca = false;
  options.flat_hand_mean = true;
  options.num_expression_coeffs = 0;
  static const body::Smplx layer(model, options);
  body::SmplxInput input;
  input.pose = SmplxPose::stack({motion_pose(motion, seconds, 0)});
  input.betas = at::zeros({1, layer->options().num_betas});
  return layer->forward(input).joints[0].detach();
}

double height_of(const at::Tensor& joints, int64_t joint) { return joints[joint][1].item<double>(); }

TEST(SyntheticVideo, LibraryMotionsDoWhatTheirNamesSay) {
  const at::Tensor stand = joints_in("walk", 0.0);
  // Both wrists above the head with the arms raised overhead.
  const at::Tensor up = joints_in("overhead", 0.0);
  EXPECT_GT(height_of(up, kLeftWrist), height_of(up, kHead));
  EXPECT_GT(height_of(up, kRightWrist), height_of(up, kHead));
  // The right wrist above the right shoulder's height while waving, the left one hanging low.
  const at::Tensor wave = joints_in("wave", 0.3);
  EXPECT_GT(height_of(wave, kRightWrist), height_of(wave, kHead) - 0.25);
  EXPECT_LT(height_of(wave, kLeftWrist), height_of(wave, kPelvis) + 0.2);
  // In the deep bend (1 s: deepest) the head drops far below its standing height.
  const double standing_head = height_of(stand, kHead) - height_of(stand, kPelvis);
  const at::Tensor bend = joints_in("bend", 1.0);
  EXPECT_LT(height_of(bend, kHead) - height_of(bend, kPelvis), 0.5 * standing_head);
  // Sitting (1 s: deepest) lowers the pelvis; the guard lifts both fists to about the head.
  EXPECT_LT(height_of(joints_in("sit", 1.0), kPelvis), height_of(stand, kPelvis) - 0.25);
  const at::Tensor guard = joints_in("guard", 0.0);
  EXPECT_GT(height_of(guard, kLeftWrist), height_of(guard, kHead) - 0.35);
  // Turning rotates the body about the vertical: the wrists' line swings round.
  const at::Tensor turned = joints_in("turn", 0.5);
  const at::Tensor across = turned[kLeftWrist] - turned[kRightWrist];
  EXPECT_GT(std::abs(across[2].item<double>()), 0.5 * std::abs(across[0].item<double>()));
  // Talking keeps both wrists in front of the chest, between the pelvis and the head, and never turns the root.
  for (const double seconds : {0.3, 1.1}) {
    const at::Tensor talk = joints_in("talk", seconds);
    for (const int64_t wrist : {kLeftWrist, kRightWrist}) {
      EXPECT_GT(height_of(talk, wrist), height_of(talk, kPelvis)) << seconds;
      EXPECT_LT(height_of(talk, wrist), height_of(talk, kHead)) << seconds;
      EXPECT_GT(talk[wrist][2].item<double>(), talk[kPelvis][2].item<double>() + 0.1) << "in front, " << seconds;
    }
    EXPECT_TRUE(motion_pose("talk", seconds, 0).global_orient.abs().max().item<float>() == 0) << seconds;
  }
  // The kick lifts the left foot forward to near the hips' height in the first cycle (1 s: highest) and the right
  // one in the second (3 s).
  constexpr int64_t kLeftFoot = 10, kRightFoot = 11;
  for (const auto& [seconds, foot, other] : {std::tuple{1.0, kLeftFoot, kRightFoot}, {3.0, kRightFoot, kLeftFoot}}) {
    const at::Tensor kick = joints_in("kick", seconds);
    EXPECT_GT(height_of(kick, foot), height_of(kick, kPelvis) - 0.45) << seconds;
    EXPECT_GT(kick[foot][2].item<double>(), kick[kPelvis][2].item<double>() + 0.5) << "forward, " << seconds;
    EXPECT_LT(height_of(kick, other), height_of(stand, kPelvis) - 0.6) << "the other foot stays down, " << seconds;
  }
  // Deterministic, finite, and moving.
  for (const std::string& m : motion_names()) {
    const SmplxPose a = motion_pose(m, 0.4, 10), b = motion_pose(m, 0.4, 10), c = motion_pose(m, 0.9, 10);
    EXPECT_TRUE(at::equal(a.body_pose, b.body_pose)) << m;
    EXPECT_TRUE(a.non_finite().empty()) << m;
    EXPECT_GT((a.body_pose - c.body_pose).abs().max().item<float>(), 0.02f) << m;
    EXPECT_GT((a.left_hand_pose - c.left_hand_pose).abs().max().item<float>(), 0.01f) << m;
  }
}

TEST(SyntheticVideo, MotionListsAreCheckedWithTheChoicesNamed) {
  EXPECT_EQ(parse_motion_list("walk,wave", "--motions"), (std::vector<std::string>{"walk", "wave"}));
  testing::expect_error_mentioning([] { parse_motion_list("walk,jump", "--motions"); }, "unknown motion 'jump'");
  testing::expect_error_mentioning([] { parse_motion_list("walk,jump", "--motions"); }, "overhead");
  testing::expect_error_mentioning([] { parse_motion_list("walk,walk", "--motions"); }, "listed twice");
  testing::expect_error_mentioning([] { parse_motion_list("", "--test-motions"); }, "--test-motions");
  testing::expect_error_mentioning([] { motion_pose("jump", 0.0, 0); }, "unknown motion 'jump'");
}

TEST(SyntheticVideo, NovelMotionSplitTestsOnWholeMotionsAndWritesRegionGroundTruth) {
  testing::TempFolder dir;
  SyntheticVideoOptions o;
  o.motions = {"walk", "wave"};
  o.test_motions = {"bend"};
  o.frames = 12;
  o.width = 48;
  o.height = 64;
  write_synthetic_video(dir.str(), o);
  const Dataset d = read_dataset(dir.str());
  ASSERT_EQ(d.size(), 36);
  EXPECT_EQ(d.sequences, (std::vector<std::string>{"walk", "wave", "bend"}));
  std::vector<int64_t> bend_frames;
  for (int64_t i = 24; i < 36; ++i) bend_frames.push_back(i);
  EXPECT_EQ(d.split(Split::kTest), bend_frames);
  EXPECT_EQ(d.split(Split::kVal), (std::vector<int64_t>{4, 16}));
  EXPECT_EQ(d.split(Split::kTrain).size(), 22u);
  for (int64_t i : {0, 13, 30}) EXPECT_EQ(d.frames[size_t(i)].sequence, i / 12);
  // Replay times for training motions, none for the new one.
  EXPECT_DOUBLE_EQ(*d.replay_time(0), -1.0);
  EXPECT_DOUBLE_EQ(*d.replay_time(23), 1.0);
  EXPECT_TRUE(d.replay_time(4).has_value()) << "a held-out frame inside its motion's training span";
  EXPECT_FALSE(d.replay_time(24).has_value());
  // Regions per model vertex; observation: the share of training frames that saw each vertex.
  const at::Tensor faces = io::read_npy(dir / "meshes/faces.npy");
  const int64_t vertices = io::read_npy(d.frames[0].mesh_path).size(0);
  const at::Tensor regions = io::read_npy(dir / "meshes/regions.npy");
  const at::Tensor observation = io::read_npy(dir / "meshes/observation.npy");
  ASSERT_EQ(regions.size(0), vertices);
  ASSERT_EQ(observation.size(0), vertices);
  for (int64_t part = 0; part < 4; ++part) EXPECT_GT((regions == part).sum().item<int64_t>(), 0) << "part " << part;
  EXPECT_GE(observation.min().item<float>(), 0.0f);
  EXPECT_FLOAT_EQ(observation.max().item<float>(), 1.0f) << "the front is seen in every training frame";
  EXPECT_GT((observation == 0).sum().item<int64_t>(), 0) << "some surface is never seen from the front";
}

TEST(SyntheticVideo, AMotionCannotBeBothTrainedAndTested) {
  testing::TempFolder dir;
  SyntheticVideoOptions o;
  o.motions = {"walk"};
  o.test_motions = {"walk"};
  o.frames = 2;
  testing::expect_error_mentioning([&] { write_synthetic_video(dir.str(), o); }, "both a training and a test motion");
}

}  // namespace
}  // namespace sfgs::data
