// The COCO-WholeBody keypoints on SMPL-X-layout bodies (body/wholebody_keypoints.h): the layout, the geometric
// definitions on the procedural body, the Anny stand-in's landmark embedding, the jaw-contour bins, and the files
// `sfgs synth` writes, whose exact keypoints are the projections of its posed meshes.
#include <ATen/ATen.h>
#include <gtest/gtest.h>

#include <cmath>

#include "body/keypoint_geometry.h"
#include "body/rotations.h"
#include "body/skeleton.h"
#include "body/wholebody_keypoints.h"
#include "data/dataset.h"
#include "data/keypoint_file.h"
#include "data/synthetic.h"
#include "io/npz.h"
#include "test_body_utils.h"
#include "test_files.h"

namespace sfgs::body {
namespace {

TEST(WholeBodyKeypoints, LayoutIsCocoWholeBody) {
  const auto& names = wholebody_keypoint_names();
  EXPECT_EQ(names[0], "nose");
  EXPECT_EQ(names[16], "right_ankle");
  EXPECT_EQ(names[22], "right_heel");
  EXPECT_EQ(names[23], "face_0");
  EXPECT_EQ(names[91], "left_hand_root");
  EXPECT_EQ(names[95], "left_thumb4");
  EXPECT_EQ(names[132], "right_pinky4");
  std::vector<int64_t> sizes;
  for (KeypointGroup g : kKeypointGroups) sizes.push_back(keypoint_range(g).size());
  EXPECT_EQ(sizes, (std::vector<int64_t>{17, 6, 68, 21, 21}));
  const auto& mirror = wholebody_mirrored_keypoints();
  for (int64_t i = 0; i < kWholeBodyKeypointCount; ++i)
    EXPECT_EQ(mirror[size_t(mirror[size_t(i)])], i) << names[size_t(i)];
  EXPECT_EQ(names[size_t(mirror[5])], "right_shoulder");
  EXPECT_EQ(names[size_t(mirror[99])], "right_index4");
}

TEST(WholeBodyKeypoints, GeometricSurfacePointsLieWhereTheirNamesSay) {
  const SmplxModelData& model = testing::procedural_body().smplx;
  const SurfaceKeypointVertices s = surface_keypoint_vertices(model);
  const at::Tensor v = model.v_template.to(at::kDouble);
  const at::Tensor j = model.j_regressor.to(at::kDouble).matmul(v);
  const auto vertex = [&](int64_t i) { return v[i]; };
  const auto joint = [&](int64_t i) { return j[i]; };
  using namespace smplx_joint;
  EXPECT_GT(vertex(s.nose)[2].item<double>(), joint(kHead)[2].item<double>()) << "the nose is in front of the head";
  EXPECT_GT(vertex(s.left_ear)[0].item<double>(), joint(kLeftEye)[0].item<double>()) << "ears are outside the eyes";
  EXPECT_LT(vertex(s.right_ear)[0].item<double>(), joint(kRightEye)[0].item<double>());
  EXPECT_GT(vertex(s.left_eye)[2].item<double>(), joint(kLeftEye)[2].item<double>()) << "the eyeball's front";
  for (Side side : {Side::kLeft, Side::kRight}) {
    const bool left = side == Side::kLeft;
    const double sign = left ? 1 : -1;
    const auto& tips = left ? s.left_fingertips : s.right_fingertips;
    // Fingertips lie beyond the finger's last joint along the arm (the arms point along +-x in the T-pose); the
    // thumb points forward as much as outward, so only the four fingers are checked along x.
    for (int64_t f = 1; f < kFingerCount; ++f)
      EXPECT_GT(sign * vertex(tips[size_t(f)])[0].item<double>(),
                sign * joint(left ? kLeftHandFirst + 2 : kRightHandFirst + 2)[0].item<double>());
    const int64_t ankle = left ? kLeftAnkle : kRightAnkle;
    EXPECT_GT(vertex(left ? s.left_big_toe : s.right_big_toe)[2].item<double>(), joint(ankle)[2].item<double>());
    EXPECT_LT(vertex(left ? s.left_heel : s.right_heel)[2].item<double>(), joint(ankle)[2].item<double>());
    EXPECT_LT(std::abs(vertex(left ? s.left_big_toe : s.right_big_toe)[0].item<double>()),
              std::abs(vertex(left ? s.left_small_toe : s.right_small_toe)[0].item<double>()))
        << "the big toe is on the inner side";
  }
  EXPECT_EQ(s.right_ear, testing::procedural_body().mirrored_vertices[s.left_ear].item<int64_t>())
      << "the procedural body is symmetric, and so are its keypoints";
}

TEST(WholeBodyKeypoints, FaceLandmarksLieOnTheHead) {
  const SmplxModelData& model = testing::procedural_body().smplx;
  const WholeBodyKeypointMap map = WholeBodyKeypointMap::build(model, {});
  EXPECT_EQ(map.definition(), "geometric");
  EXPECT_FALSE(map.face_from_embedding());
  const at::Tensor v = model.v_template.to(at::kDouble).unsqueeze(0);
  const at::Tensor j = model.j_regressor.to(at::kDouble).matmul(v[0]).unsqueeze(0);
  const at::Tensor k = map.evaluate_on_mesh(v, j, at::zeros({1}, at::kLong))[0];
  const KeypointRange face = keypoint_range(KeypointGroup::kFace);
  const at::Tensor landmarks = k.narrow(0, face.begin, face.size());
  const at::Tensor eyes = (j[0][smplx_joint::kLeftEye] + j[0][smplx_joint::kRightEye]) / 2;
  EXPECT_LT((landmarks - eyes).norm(2, -1).max().item<double>(), 0.15) << "within 15 cm of the eyes";
  EXPECT_GT(landmarks.select(1, 2).min().item<double>(), j[0][smplx_joint::kHead][2].item<double>())
      << "on the front of the head";
  // Brows above the eyes, mouth below the nose tip, chin (contour point 8) lowest.
  EXPECT_GT(landmarks[19][1].item<double>(), eyes[1].item<double>());
  EXPECT_LT(landmarks[57][1].item<double>(), landmarks[30][1].item<double>());
  EXPECT_EQ(landmarks.select(1, 1).argmin().item<int64_t>(), 8);
}

TEST(WholeBodyKeypoints, AnnyFaceComesFromItsEmbeddingAndBadEmbeddingsAreErrors) {
  SFGS_SKIP_WITHOUT_SHARED_BODIES();
  const SmplxModelData& model = testing::anny_smplx();
  const std::string path = testing::shared_bodies_folder() + "/anny_smplx_layout.npz";
  const LandmarkEmbedding e = read_landmark_embedding(path, model.faces.size(0));
  ASSERT_TRUE(e.defined());
  EXPECT_EQ(e.contour_faces.size(0), 79);
  const WholeBodyKeypointMap map = WholeBodyKeypointMap::build(model, e);
  EXPECT_TRUE(map.face_from_embedding());
  testing::ScratchFolder dir;
  const std::string bad = dir.file("bad.npz");
  io::write_npz(bad,
                {{"lmk_faces_idx", e.faces},
                 {"lmk_bary_coords", e.barycentrics.narrow(0, 0, 50)},
                 {"dynamic_lmk_faces_idx", e.contour_faces},
                 {"dynamic_lmk_bary_coords", e.contour_barycentrics}},
                false);
  testing::expect_error_mentioning([&] { read_landmark_embedding(bad, model.faces.size(0)); }, "lmk_bary_coords");
  testing::expect_error_mentioning([&] { read_landmark_embedding(path, 100); }, "indexes triangles outside [0, 100)");
}

TEST(WholeBodyKeypoints, ContourBinsFollowTheHeadsTurnAsTheReference) {
  const at::Tensor flip = axis_angle_to_matrix(at::tensor({M_PI, 0.0, 0.0}, at::kDouble));
  const auto bin_of = [&](double degrees) {
    const at::Tensor turn = axis_angle_to_matrix(at::tensor({0.0, degrees * M_PI / 180, 0.0}, at::kDouble));
    return contour_bins(flip.matmul(turn).unsqueeze(0), 79)[0].item<int64_t>();
  };
  EXPECT_EQ(bin_of(0), 0);
  // The reference bins -yaw: a turn of -10 degrees is bin 10, +10 degrees bin 39 + 10.
  EXPECT_EQ(bin_of(-10), 10);
  EXPECT_EQ(bin_of(10), 49);
  EXPECT_EQ(bin_of(-60), 39);
  EXPECT_EQ(bin_of(60), 78);
  EXPECT_EQ(contour_bins(flip.unsqueeze(0), 1)[0].item<int64_t>(), 0);
}

TEST(WholeBodyKeypoints, SynthKeypointsAreTheProjectionsOfItsPosedMeshes) {
  testing::TempFolder dir;
  data::SyntheticVideoOptions o;
  o.frames = 3;
  o.width = 96;
  o.height = 128;
  o.keypoint_noise.exact = true;
  const data::Dataset d = data::write_synthetic_video(dir.str(), o);
  const SmplxModelData& model = testing::procedural_body().smplx;
  const SurfaceKeypointVertices s = surface_keypoint_vertices(model);
  const std::vector<std::pair<int64_t, int64_t>> surface = {{0, s.nose},
                                                            {1, s.left_eye},
                                                            {2, s.right_eye},
                                                            {3, s.left_ear},
                                                            {4, s.right_ear},
                                                            {17, s.left_big_toe},
                                                            {22, s.right_heel},
                                                            {95, s.left_fingertips[0]},
                                                            {132, s.right_fingertips[4]}};
  for (int64_t i = 0; i < d.size(); ++i) {
    const data::FrameRecord& r = d.frames[size_t(i)];
    const at::Tensor k = data::read_wholebody_keypoints(dir / ("keypoints_whole_body/" + std::to_string(i) + ".json"));
    const at::Tensor mesh = io::read_npy(r.mesh_path).to(at::kDouble);
    const auto& m = r.camera.world_to_camera;
    for (const auto& [keypoint, vertex] : surface) {
      const at::Tensor p = mesh[vertex];
      const double x = m[0] * p[0].item<double>() + m[1] * p[1].item<double>() + m[2] * p[2].item<double>() + m[3];
      const double y = m[4] * p[0].item<double>() + m[5] * p[1].item<double>() + m[6] * p[2].item<double>() + m[7];
      const double z = m[8] * p[0].item<double>() + m[9] * p[1].item<double>() + m[10] * p[2].item<double>() + m[11];
      EXPECT_NEAR(k[keypoint][0].item<double>(), r.camera.fx * x / z + r.camera.cx, 0.01) << keypoint;
      EXPECT_NEAR(k[keypoint][1].item<double>(), r.camera.fy * y / z + r.camera.cy, 0.01) << keypoint;
    }
    EXPECT_TRUE((k.select(1, 2) == 1).all().item<bool>()) << "exact keypoints of a body in view score 1";
  }
}

}  // namespace
}  // namespace sfgs::body
