// `sfgs fit` (csrc/fit): the reduced body equals the full SMPL-X layer where it is evaluated, the fitter recovers
// known poses from exact keypoints, bad keypoint files are clear errors, and the fit's files read back.
#include <ATen/ATen.h>
#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>

#include "body/rotations.h"
#include "body/skeleton.h"
#include "body/wholebody_keypoints.h"
#include "data/image_io.h"
#include "data/json_values.h"
#include "data/keypoint_file.h"
#include "data/motions.h"
#include "data/neuman.h"
#include "data/pose_noise.h"
#include "data/synthetic.h"
#include "fit/fit_accuracy.h"
#include "fit/fit_input.h"
#include "fit/fit_losses.h"
#include "fit/fitter.h"
#include "fit/keypoint_body.h"
#include "test_body_utils.h"
#include "test_files.h"
#include "fit/constants.h"

namespace sfgs::fit {
namespace {

constexpr int64_t kWidth = 256, kHeight = 384;
constexpr double kFocal = 460.0;

// A short video of known camera-frame fits (the walk motion, facing the camera 3 m away, slowly turning) and the
// exact keypoints they project to.
struct KnownVideo {
  FitInput input;
  body::SmplxPose poses;  // (B, ...) hands relative to the mean hand
  at::Tensor betas;
};

body::Smplx camera_frame_layer(const body::SmplxModelData& model) {
  body::SmplxOptions o;
  o.num_betas = kFitBetas;
  o.num_expression_coeffs = kFitExpressions;
  o.use_pca = false;
  o.flat_hand_mean = false;
  o.dtype = at::kDouble;
  return body::Smplx(model, o);
}

// The whole-body keypoints (pixels, float64) of camera-frame fits seen by the test camera.
at::Tensor keypoint_pixels(const body::SmplxModelData& model, const body::WholeBodyKeypointMap& map,
                           const body::SmplxPose& poses, const at::Tensor& betas) {
  const int64_t frames = poses.transl.size(0);
  body::SmplxInput in;
  in.pose = poses.to(at::TensorOptions().dtype(at::kDouble));
  in.betas = betas.to(at::kDouble).unsqueeze(0).expand({frames, -1});
  const body::SmplxOutput out = camera_frame_layer(model)->forward(in);
  const at::Tensor neck = out.joint_transforms.select(1, body::smplx_joint::kNeck).narrow(1, 0, 3).narrow(2, 0, 3);
  const at::Tensor points =
      map.evaluate_on_mesh(out.vertices, out.joints, body::contour_bins(neck, map.contour_bin_count()));
  const at::Tensor intrinsics =
      at::tensor({kFocal, kFocal, kWidth / 2.0, kHeight / 2.0}, at::kDouble).expand({frames, 4});
  return project(points, intrinsics);
}

KnownVideo known_video(const body::SmplxModelData& model, const body::WholeBodyKeypointMap& map, int64_t frames) {
  KnownVideo v;
  std::vector<body::SmplxPose> poses;
  for (int64_t i = 0; i < frames; ++i) {
    body::SmplxPose p = data::motion_pose("walk", double(i) / 30.0, kFitExpressions);
    const at::Tensor turn = at::tensor({0.0, 0.2 * double(i) / double(frames), 0.0}, at::kDouble);
    const at::Tensor flip = at::tensor({M_PI, 0.0, 0.0}, at::kDouble);
    p.global_orient =
        body::matrix_to_axis_angle(body::axis_angle_to_matrix(flip).matmul(body::axis_angle_to_matrix(turn)))
            .to(at::kFloat);
    p.transl = at::tensor({0.05f, 0.1f, 3.0f});
    poses.push_back(p);
  }
  v.poses = body::SmplxPose::stack(poses);
  v.betas = at::linspace(-0.5, 0.5, kFitBetas, at::kFloat);
  const at::Tensor pixels = keypoint_pixels(model, map, v.poses, v.betas);
  v.input.keypoints =
      at::cat({pixels, at::ones({frames, body::kWholeBodyKeypointCount, 1}, at::kDouble)}, 2).to(at::kFloat);
  for (int64_t i = 0; i < frames; ++i) {
    FitFrame f;
    f.number = i;
    f.fx = f.fy = kFocal;
    f.cx = kWidth / 2.0;
    f.cy = kHeight / 2.0;
    f.width = kWidth;
    f.height = kHeight;
    v.input.frames.push_back(f);
  }
  return v;
}

TEST(FitKeypointBody, EqualsTheFullLayerAtItsVertices) {
  const body::SmplxModelData& model = testing::procedural_body().smplx;
  const body::WholeBodyKeypointMap map = body::WholeBodyKeypointMap::build(model, {});
  const KnownVideo v = known_video(model, map, 3);
  const KeypointBody reduced(model, map.support_vertices(), kFitBetas, kFitExpressions,
                             at::TensorOptions().dtype(at::kDouble));
  body::SmplxInput in;
  in.pose = v.poses.to(at::TensorOptions().dtype(at::kDouble));
  in.betas = v.betas.to(at::kDouble).unsqueeze(0).expand({3, -1});
  const body::SmplxOutput full = camera_frame_layer(model)->forward(in);
  const PosedPoints posed =
      reduced.forward(v.betas.to(at::kDouble), in.pose.expression, full.rotations, in.pose.transl);
  EXPECT_LT((posed.joints - full.joints).abs().max().item<double>(), 1e-9);
  EXPECT_LT((posed.points - full.vertices.index_select(1, map.support_vertices())).abs().max().item<double>(), 1e-9);
}

// Reference fits for measure_accuracy: the video's known poses.
ReferenceFits known_reference(const KnownVideo& v) {
  ReferenceFits r;
  r.source = "known poses";
  r.betas = v.betas;
  for (int64_t i = 0; i < v.poses.transl.size(0); ++i) r.poses[i] = v.poses.frame(i);
  return r;
}

std::map<int64_t, body::SmplxPose> by_frame(const body::SmplxPose& poses) {
  std::map<int64_t, body::SmplxPose> m;
  for (int64_t i = 0; i < poses.transl.size(0); ++i) m[i] = poses.frame(i);
  return m;
}

// Mean distance (pixels) between the keypoints of camera-frame fits and the video's exact keypoints.
double reprojection_pixels(const body::SmplxModelData& model, const body::WholeBodyKeypointMap& map,
                           const KnownVideo& v, const body::SmplxPose& poses, const at::Tensor& betas) {
  return (keypoint_pixels(model, map, poses, betas) - v.input.keypoints.narrow(2, 0, 2).to(at::kDouble))
      .norm(2, -1)
      .mean()
      .item<double>();
}

TEST(FitAccuracy, MeasuresJointAndVertexErrorsAgainstTheReference) {
  const body::SmplxModelData& model = testing::procedural_body().smplx;
  const KnownVideo v = known_video(model, body::WholeBodyKeypointMap::build(model, {}), 2);
  const ReferenceFits reference = known_reference(v);
  const FitAccuracy same = measure_accuracy(model, by_frame(v.poses), v.betas, reference);
  EXPECT_EQ(same.frames, 2);
  EXPECT_LT(same.mpjpe_mm + same.mpjpe_absolute_mm + same.pa_mpjpe_mm + same.vertex_error_absolute_mm, 1e-6);
  body::SmplxPose shifted = v.poses;
  shifted.transl = shifted.transl + at::tensor({0.0f, 0.0f, 0.1f});  // 10 cm farther
  const FitAccuracy farther = measure_accuracy(model, by_frame(shifted), v.betas, reference);
  EXPECT_NEAR(farther.mpjpe_absolute_mm, 100, 1e-3);
  EXPECT_NEAR(farther.depth_error_mm, 100, 1e-3);
  EXPECT_NEAR(farther.vertex_error_absolute_mm, 100, 1e-3);
  EXPECT_LT(farther.mpjpe_mm + farther.vertex_error_mm, 1e-3) << "pelvis-aligned errors ignore the shift";
}

// One synthetic video written in both layouts: the NeuMan layout's fits (camera coordinates, hands relative to the
// mean hand) measured against the sfgs layout's dataset.json (world coordinates, the same hand convention) are the
// same body, frame by frame: the reference reads the sfgs layout's hands as sfgs synth writes them.
TEST(FitAccuracy, AnSfgsDatasetsFitsAreTheSameBodyAsItsNeumanTwin) {
  testing::TempFolder folder;
  data::SyntheticVideoOptions o;
  o.frames = 3;
  o.width = o.height = 48;
  const data::Dataset sfgs = data::write_synthetic_video(folder / "sfgs", o);
  o.layout = data::DatasetLayout::kNeuman;
  const data::Dataset neuman = data::write_synthetic_video(folder / "neuman", o);
  const std::optional<ReferenceFits> reference = find_reference_fits(folder / "sfgs", "");
  ASSERT_TRUE(reference.has_value());
  std::map<int64_t, body::SmplxPose> fits;
  for (int64_t i = 0; i < neuman.size(); ++i) fits[i] = neuman.frames[size_t(i)].pose;
  const FitAccuracy a = measure_accuracy(testing::procedural_body().smplx, fits, neuman.betas, *reference);
  EXPECT_EQ(a.frames, 3);
  EXPECT_LT(a.mpjpe_absolute_mm + a.hand_mpjpe_mm + a.vertex_error_absolute_mm, 0.1)
      << "hands " << a.hand_mpjpe_mm << " mm, vertices " << a.vertex_error_absolute_mm << " mm";
  EXPECT_EQ(std::filesystem::path(sfgs.frames[1].keypoints_path),
            std::filesystem::path(folder / "sfgs") / "keypoints_whole_body" / "1.json")
      << "dataset.json lists each frame's keypoint file";
  EXPECT_EQ(std::filesystem::path(neuman.frames[1].keypoints_path),
            std::filesystem::path(folder / "neuman") / "keypoints_whole_body" / "1.json")
      << "the NeuMan reader finds keypoints_whole_body/<frame number>.json";
}

TEST(FitSmplx, RecoversAKnownPoseFromExactKeypoints) {
  const body::SmplxModelData& model = testing::procedural_body().smplx;
  const body::WholeBodyKeypointMap map = body::WholeBodyKeypointMap::build(model, {});
  const KnownVideo v = known_video(model, map, 6);
  const FitResult fit = fit_smplx(model, map, v.input, at::kCPU, FitSettings{});
  const FitAccuracy a = measure_accuracy(model, by_frame(fit.poses), fit.betas, known_reference(v));
  // The detections are matched; one view leaves the depth of some bones ambiguous (a thigh swung towards or away
  // from the camera projects alike), which the priors settle, so the joints are recovered up to that.
  const double pixels = reprojection_pixels(model, map, v, fit.poses, fit.betas);
  EXPECT_LT(pixels, 1.0);
  EXPECT_LT(a.mpjpe_mm, 40);
  EXPECT_LT(a.pa_mpjpe_mm, 25);
  EXPECT_LT(a.hand_mpjpe_mm, 30);
  std::printf("exact keypoints, 6 frames: %.2f px, MPJPE %.1f mm, PA-MPJPE %.1f mm, hands %.1f mm\n", pixels,
              a.mpjpe_mm, a.pa_mpjpe_mm, a.hand_mpjpe_mm);
}

TEST(FitSmplx, StartedFromAnEstimatorsFitsItMatchesTheDetections) {
  const body::SmplxModelData& model = testing::procedural_body().smplx;
  const body::WholeBodyKeypointMap map = body::WholeBodyKeypointMap::build(model, {});
  const KnownVideo v = known_video(model, map, 4);
  // An estimator's fits (low noise, without hand swaps) as the start, as a pose regressor would give them.
  const data::NoisyFits start =
      data::corrupt_fits(v.poses, v.betas, at::arange(4, at::kDouble) / 30.0, at::eye(3, at::kDouble).expand({4, 3, 3}),
                         data::pose_noise_level("low"), 1);
  FitSettings settings;
  settings.initial_fits = start.poses;
  settings.known_betas = v.betas;
  const double before = reprojection_pixels(model, map, v, start.poses, v.betas);
  const FitResult fit = fit_smplx(model, map, v.input, at::kCPU, settings);
  const double after = reprojection_pixels(model, map, v, fit.poses, fit.betas);
  const FitAccuracy a = measure_accuracy(model, by_frame(fit.poses), fit.betas, known_reference(v));
  EXPECT_GT(before, 3.0);
  EXPECT_LT(after, 1.0);
  EXPECT_LT(a.mpjpe_mm, 40);
  EXPECT_LT(a.depth_error_mm, 20) << "a known shape fixes the depth";
  std::printf("from low-noise fits: %.2f -> %.2f px, MPJPE %.1f mm\n", before, after, a.mpjpe_mm);
}

std::string triples(int64_t count, const std::string& value) {
  std::string text = "[";
  for (int64_t i = 0; i < count; ++i) text += (i ? ", " : "") + value;
  return text + "]";
}

TEST(KeypointFiles, ReadNestedTriplesAndFlatListsAndRoundTrip) {
  testing::TempFolder dir;
  testing::write_text(dir / "nested.json", triples(body::kWholeBodyKeypointCount, "[1.5, 2, 0.9]"));
  const at::Tensor nested = data::read_wholebody_keypoints(dir / "nested.json");
  EXPECT_EQ(nested.sizes(), at::IntArrayRef({body::kWholeBodyKeypointCount, 3}));
  EXPECT_FLOAT_EQ(nested[132][0].item<float>(), 1.5f);
  testing::write_text(dir / "flat.json", triples(body::kWholeBodyKeypointCount, "1.5, 2, 0.9"));
  EXPECT_TRUE(at::equal(data::read_wholebody_keypoints(dir / "flat.json"), nested));
  data::write_wholebody_keypoints(dir / "written.json", nested, false);
  EXPECT_TRUE(at::allclose(data::read_wholebody_keypoints(dir / "written.json"), nested));
  testing::expect_error_mentioning([&] { data::write_wholebody_keypoints(dir / "written.json", nested, false); },
                                   "written.json");
}

TEST(KeypointFiles, BadFilesAreClearErrorsNamingTheFile) {
  testing::TempFolder dir;
  const auto expect = [&](const std::string& text, const std::string& needle) {
    testing::write_text(dir / "k.json", text);
    testing::expect_error_mentioning([&] { data::read_wholebody_keypoints(dir / "k.json"); }, needle);
    testing::expect_error_mentioning([&] { data::read_wholebody_keypoints(dir / "k.json"); }, dir / "k.json");
  };
  expect(triples(17, "[1, 2, 1]"),
         "expected 133 keypoints (COCO-WholeBody: 17 body, 6 feet, 68 face, 2 x 21 hands), got 17");
  // triples(n, v).replace(0, 1, ", ") continues a list with n more entries.
  expect("[[1, 2]" + triples(132, "[1, 2, 1]").replace(0, 1, ", "),
         "keypoint 0 (nose) must be [x, y, score], got [1,2]");
  expect("[[1, 2, 1], [\"a\", 2, 1]" + triples(131, "[1, 2, 1]").replace(0, 1, ", "),
         "keypoint 1 (left_eye) must be a number, got \"a\"");
  expect("[[1, 2, 1], [NaN, 2, 1]" + triples(131, "[1, 2, 1]").replace(0, 1, ", "),
         "NaN or Infinity, which Python's json module writes but JSON has not");
  expect("[1e400" + triples(398, "1").replace(0, 1, ", "), "number overflow");
  expect("{\"keypoints\": []}", "expected a list of 133 [x, y, score] triples, got object");
  testing::expect_error_mentioning([&] { data::read_wholebody_keypoints(dir / "missing.json"); }, "missing.json");
  testing::write_text(dir / "keypoints_whole_body/frame.json", "[]");
  testing::expect_error_mentioning([&] { data::list_keypoint_files(dir.str()); },
                                   "must be a frame number like 12.json");
}

TEST(FitInput, MissingFramesAndCamerasAreClearErrors) {
  testing::TempFolder dir;
  const std::string keypoints = triples(body::kWholeBodyKeypointCount, "[10, 20, 0.9]");
  testing::write_text(dir / "sparse/cameras.txt", "1 PINHOLE 64 48 50 50 32 24\n");
  testing::write_text(dir / "sparse/images.txt", "1 1 0 0 0 0 0 0 1 00000.png\n\n2 1 0 0 0 0 0 0 1 00001.png\n\n");
  testing::write_text(dir / "keypoints_whole_body/0.json", keypoints);
  testing::expect_error_mentioning([&] { read_fit_input(dir.str(), 0); }, "frame 1 of");
  testing::expect_error_mentioning([&] { read_fit_input(dir.str(), 0); }, "keypoints_whole_body/1.json");
  testing::write_text(dir / "keypoints_whole_body/1.json", keypoints);
  testing::write_text(dir / "keypoints_whole_body/7.json", keypoints);
  testing::expect_error_mentioning([&] { read_fit_input(dir.str(), 0); }, "names frame 7");
  std::filesystem::remove(dir / "keypoints_whole_body/7.json");
  const FitInput in = read_fit_input(dir.str(), 0);
  ASSERT_EQ(in.frames.size(), 2u);
  EXPECT_DOUBLE_EQ(in.frames[1].fx, 50);
  EXPECT_EQ(in.keypoints.sizes(), at::IntArrayRef({2, body::kWholeBodyKeypointCount, 3}));

  testing::TempFolder raw;  // frames only: the camera comes from the image size
  testing::write_text(raw / "keypoints_whole_body/3.json", keypoints);
  testing::expect_error_mentioning([&] { read_fit_input(raw.str(), 0); }, "gives its size for the camera");
  data::write_png(raw / "images/00003.png", at::zeros({30, 40, 3}), false);
  const FitInput estimated = read_fit_input(raw.str(), 0);
  EXPECT_DOUBLE_EQ(estimated.frames[0].fx, 40);
  EXPECT_DOUBLE_EQ(estimated.frames[0].cx, 20);
  EXPECT_DOUBLE_EQ(estimated.frames[0].cy, 15);
  EXPECT_DOUBLE_EQ(read_fit_input(raw.str(), 123).frames[0].fy, 123);

  // A frame whose detector found (almost) nothing cannot be placed: an error naming it, not a fit metres off.
  testing::write_text(dir / "keypoints_whole_body/1.json", triples(body::kWholeBodyKeypointCount, "[10, 20, 0]"));
  testing::expect_error_mentioning([&] { read_fit_input(dir.str(), 0); }, "frame 1 (0)");
  testing::expect_error_mentioning([&] { read_fit_input(dir.str(), 0); }, "too few to place the body");
  testing::write_text(dir / "keypoints_whole_body/1.json", triples(body::kWholeBodyKeypointCount, "[10, 20, -1]"));
  testing::expect_error_mentioning([&] { read_fit_input(dir.str(), 0); }, "1 of 2 frames");
}

TEST(FitCommand, FitsASynthVideoIntoFilesTheNeumanReaderReads) {
  testing::TempFolder dir;
  data::SyntheticVideoOptions o;
  o.frames = 4;
  o.width = 128;
  o.height = 160;
  o.layout = data::DatasetLayout::kNeuman;
  data::write_synthetic_video(dir / "video", o);
  FitOptions f;
  f.data = dir / "video";
  f.out = dir / "fit";
  f.iterations = {10, 20, 10, 5};
  f.quiet = true;
  const FitReport report = run_fit(f);
  EXPECT_EQ(report.frames, 4);
  EXPECT_TRUE(report.silhouette) << "the synthetic video has masks";
  ASSERT_EQ(report.stages.size(), 4u);
  EXPECT_EQ(report.stages[1].name, "body");
  ASSERT_TRUE(report.accuracy.has_value()) << "ground_truth/ is found beside the video";
  EXPECT_EQ(report.accuracy->frames, 4);
  EXPECT_GT(report.accuracy->mpjpe_mm, 0);
  for (int64_t i = 0; i < 4; ++i) {
    const body::SmplxPose p =
        data::read_exavatar_pose(dir / ("fit/smplx_optimized/smplx_params/" + std::to_string(i) + ".json"));
    EXPECT_EQ(p.expression.size(0), kFitExpressions);
    EXPECT_GT(p.transl[2].item<float>(), 0) << "in front of the camera";
  }
  EXPECT_EQ(data::json_numbers(data::read_json_file(dir / "fit/smplx_optimized/shape_param.json"), {-1}, "").size(0),
            kFitBetas);
  std::ifstream log(dir / "fit/fit_log.jsonl");
  int64_t lines = 0;
  for (std::string line; std::getline(log, line); ++lines) EXPECT_NO_THROW((void)nlohmann::json::parse(line));
  EXPECT_GT(lines, 8);
  EXPECT_TRUE(nlohmann::json::parse(std::ifstream(dir / "fit/fit_report.json")).contains("accuracy"));
  testing::expect_error_mentioning([&] { run_fit(f); }, "exists; pass --force");
  // A bad --truth fails before any fitting and before anything is written, naming the option.
  FitOptions bad_truth = f;
  bad_truth.out = dir / "fit_truth";
  bad_truth.truth = dir / "no_such_folder";
  testing::expect_error_mentioning([&] { run_fit(bad_truth); }, "--truth");
  testing::write_text(dir / "empty_truth/readme.txt", "not fits");
  bad_truth.truth = dir / "empty_truth";
  testing::expect_error_mentioning([&] { run_fit(bad_truth); }, "--truth '");
  EXPECT_FALSE(std::filesystem::exists(dir / "fit_truth/smplx_optimized"));
  // The output folder is a NeuMan dataset of the fits (the video's other entries linked), as `sfgs train` reads it.
  EXPECT_TRUE(report.trainable_dataset);
  const data::Dataset fitted = data::read_dataset(dir / "fit");
  EXPECT_EQ(fitted.format, "neuman");
  ASSERT_EQ(fitted.size(), 4);
  const body::SmplxPose written = data::read_exavatar_pose(dir / "fit/smplx_optimized/smplx_params/2.json");
  EXPECT_TRUE(fitted.frames[2].pose.transl.equal(written.transl)) << "the fit's poses, not the video's own";
  // The fits in place of the video's own make a NeuMan folder `sfgs train` reads.
  testing::remove_folder_tree(dir / "video/smplx_optimized");
  std::filesystem::rename(dir / "fit/smplx_optimized", dir / "video/smplx_optimized");
  const data::Dataset d = data::read_dataset(dir / "video");
  EXPECT_EQ(d.format, "neuman");
  EXPECT_EQ(d.size(), 4);
  f.betas_from_data = true;
  f.data = dir / "video";
  f.out = dir / "fit";
  f.iterations = {1, 1, 1, 0};
  EXPECT_NO_THROW(run_fit(f));
  testing::TempFolder bare;
  testing::write_text(bare / "keypoints_whole_body/0.json", triples(body::kWholeBodyKeypointCount, "[1, 2, 1]"));
  data::write_png(bare / "images/00000.png", at::zeros({30, 40, 3}), false);
  f.data = bare.str();
  f.out = bare / "out";
  testing::expect_error_mentioning([&] { run_fit(f); }, "--betas-from-data");
}

}  // namespace
}  // namespace sfgs::fit
