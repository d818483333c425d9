// Mesh topology (csrc/body/mesh.h) and part labels (csrc/body/parts.h): PyTorch3D's subdivision layout, counts and
// Euler characteristic, exact interpolation, UV seams, neighbourhoods, the Laplacian, labels and id files.
#include <array>
#include <vector>

#include <gtest/gtest.h>

#include "body/mesh.h"
#include "body/parts.h"
#include "body/skeleton.h"
#include "io/npz.h"
#include "test_body_utils.h"

namespace sfgs::testing {
namespace {

using body::MidpointSubdivision;

int64_t edge_count(const at::Tensor& faces, int64_t vertices) {
  return body::mesh_edges(faces, vertices).edges.size(0);
}

TEST(BodyMesh, SubdivisionFollowsPyTorch3DsLayout) {
  // Two triangles sharing the edge 0-2; edges in sorted order: 01, 02, 03, 12, 23.
  const at::Tensor faces = at::tensor({0, 1, 2, 0, 2, 3}, at::kLong).view({2, 3});
  const MidpointSubdivision step(faces, 4);
  EXPECT_TRUE(step.edges().equal(at::tensor({0, 1, 0, 2, 0, 3, 1, 2, 2, 3}, at::kLong).view({5, 2})));
  EXPECT_TRUE(body::mesh_edges(faces, 4).face_edges.equal(at::tensor({3, 1, 0, 4, 2, 1}, at::kLong).view({2, 3})));
  EXPECT_EQ(step.fine_vertex_count(), 9);
  const at::Tensor expected =
      at::tensor({0, 4, 5, 0, 5, 6, 1, 7, 4, 2, 8, 5, 2, 5, 7, 3, 6, 8, 7, 5, 4, 8, 6, 5}, at::kLong).view({8, 3});
  EXPECT_TRUE(step.fine_faces().equal(expected)) << step.fine_faces();
}

TEST(BodyMesh, SubdivisionKeepsClosedSurfacesClosedWithTheirEulerCharacteristic) {
  const auto& body = procedural_body().smplx;
  at::Tensor faces = body.faces;
  int64_t v = body.v_template.size(0);
  const int64_t euler = v - edge_count(faces, v) + faces.size(0);
  EXPECT_EQ(euler, 6);  // the body and two eyeballs: three spheres
  for (const MidpointSubdivision& step : body::midpoint_subdivisions(faces, v, 2)) {
    const int64_t e = step.edges().size(0);
    EXPECT_EQ(step.fine_vertex_count(), v + e);
    EXPECT_EQ(step.fine_faces().size(0), 4 * faces.size(0));
    EXPECT_EQ(2 * e, 3 * faces.size(0));  // closed: every edge has two faces
    faces = step.fine_faces();
    v = step.fine_vertex_count();
    EXPECT_EQ(v - edge_count(faces, v) + faces.size(0), euler);
    EXPECT_TRUE(closed_and_oriented(faces, v));
  }
}

TEST(BodyMesh, AnnyUpsamplesTwiceToTheExpectedCounts) {
  SFGS_SKIP_WITHOUT_SHARED_BODIES();
  const auto& anny = anny_smplx();
  const auto chain = body::midpoint_subdivisions(anny.faces, anny.v_template.size(0), 2);
  // 13492 + 40458 edges, then + 161832 edges (closed meshes: E = 3F / 2).
  EXPECT_EQ(chain[0].fine_vertex_count(), 53950);
  EXPECT_EQ(chain[1].fine_vertex_count(), 215782);
  EXPECT_EQ(chain[1].fine_faces().size(0), 16 * 26972);
}

TEST(BodyMesh, InterpolationIsExactForAffineAttributes) {
  const auto& body = procedural_body().smplx;
  const int64_t v = body.v_template.size(0);
  const MidpointSubdivision step(body.faces, v);
  const at::Tensor fine = step.interpolate(body.v_template);
  EXPECT_TRUE(fine.narrow(0, 0, v).equal(body.v_template));  // originals first, unchanged
  const at::Tensor e = step.edges();
  EXPECT_TRUE(fine.narrow(0, v, e.size(0))
                  .allclose(0.5 * (body.v_template.index_select(0, e.select(1, 0)) +
                                   body.v_template.index_select(0, e.select(1, 1))),
                            0, 1e-15));
  const at::Tensor a = at::randn({3, 4}, at::kDouble), b = at::randn({4}, at::kDouble);
  EXPECT_LT((step.interpolate(body.v_template.matmul(a) + b) - (fine.matmul(a) + b)).abs().max().item<double>(), 1e-14);
  // Any dimension, any trailing shape.
  const at::Tensor channels_first = body.v_template.t().unsqueeze(0);  // (1, 3, V)
  EXPECT_TRUE(step.interpolate(channels_first, 2).equal(fine.t().unsqueeze(0)));
  // Labels: a midpoint takes the larger label of its ends.
  const at::Tensor labels = at::randint(0, 4, {v}, at::kLong).to(at::kByte);
  const at::Tensor fine_labels = step.interpolate_labels(labels);
  EXPECT_TRUE(fine_labels.narrow(0, v, e.size(0))
                  .equal(at::maximum(labels.index_select(0, e.select(1, 0)), labels.index_select(0, e.select(1, 1)))));
  expect_error(
      [&] {
        step.interpolate(at::zeros({v + 1, 3}, at::kDouble));
      },
      {"must have", "entries along dimension 0"});
}

TEST(BodyMesh, UvsAreSubdividedPerFaceSoSeamsStaySeams) {
  const auto& body = procedural_body().smplx;
  const body::SmplxModelData fine = body::subdivide(body, 1);
  const int64_t f = body.faces.size(0);
  // Fine face (block k, face i) takes its UVs from coarse face i's own corners: midpoints never mix charts.
  const at::Tensor corner = body.uvs.index_select(0, body.uv_faces.flatten()).view({f, 3, 2});
  const auto mid = [&](int a, int b) { return 0.5 * (corner.select(1, a) + corner.select(1, b)); };
  const std::vector<std::array<at::Tensor, 3>> blocks = {{corner.select(1, 0), mid(0, 1), mid(0, 2)},
                                                         {corner.select(1, 1), mid(1, 2), mid(0, 1)},
                                                         {corner.select(1, 2), mid(0, 2), mid(1, 2)},
                                                         {mid(1, 2), mid(0, 2), mid(0, 1)}};
  for (size_t k = 0; k < blocks.size(); ++k) {
    const at::Tensor got =
        fine.uvs.index_select(0, fine.uv_faces.narrow(0, static_cast<int64_t>(k) * f, f).flatten()).view({f, 3, 2});
    for (int c = 0; c < 3; ++c) EXPECT_LT((got.select(1, c) - blocks[k][c]).abs().max().item<double>(), 1e-15);
  }
  // The procedural body has seams (more UV vertices than vertices), and they gain their own midpoints.
  EXPECT_GT(body.uvs.size(0), body.v_template.size(0));
  EXPECT_GT(fine.uvs.size(0) - body.uvs.size(0), fine.v_template.size(0) - body.v_template.size(0));
}

TEST(BodyMesh, NeighboursAndTheUniformLaplacian) {
  // A 5 x 5 grid of unit squares, each split along the same diagonal: interior vertices have six neighbours
  // in opposite pairs, so the Laplacian of an affine function vanishes there.
  std::vector<int64_t> f;
  const auto id = [](int64_t i, int64_t j) { return i * 6 + j; };
  for (int64_t i = 0; i < 5; ++i)
    for (int64_t j = 0; j < 5; ++j) {
      for (int64_t k : {id(i, j), id(i + 1, j), id(i + 1, j + 1)}) f.push_back(k);
      for (int64_t k : {id(i, j), id(i + 1, j + 1), id(i, j + 1)}) f.push_back(k);
    }
  const at::Tensor faces = at::tensor(f, at::kLong).view({-1, 3});
  const body::VertexNeighbours all = body::vertex_neighbours(faces, 36);
  EXPECT_EQ(all.indices.size(1), 6);
  EXPECT_EQ(all.counts[id(2, 2)].item<int64_t>(), 6);
  EXPECT_EQ(all.counts[id(0, 5)].item<int64_t>(), 2);
  EXPECT_TRUE(all.indices[id(2, 2)].equal(
      std::get<0>(at::tensor({id(1, 2), id(1, 1), id(2, 1), id(2, 3), id(3, 2), id(3, 3)}, at::kLong).sort())));
  at::Tensor xy = at::empty({36, 2}, at::kDouble);
  for (int64_t i = 0; i < 6; ++i)
    for (int64_t j = 0; j < 6; ++j) xy[id(i, j)] = at::tensor({double(i), double(j)}, at::kDouble);
  const at::Tensor values =
      at::cat({xy.matmul(at::randn({2, 3}, at::kDouble)) + 2.0, at::ones({36, 1}, at::kDouble)}, 1);
  const at::Tensor lap = body::uniform_laplacian(all, values.unsqueeze(0).repeat({2, 1, 1}));
  for (int64_t i = 1; i < 5; ++i)
    for (int64_t j = 1; j < 5; ++j) EXPECT_LT(lap[1][id(i, j)].abs().max().item<double>(), 1e-12);
  EXPECT_LT(lap.select(2, 3).abs().max().item<double>(), 1e-15);  // constants everywhere
  EXPECT_GT(lap[0][id(0, 5)].abs().max().item<double>(), 1e-3);   // a corner is not the mean of its neighbours
  // Capped neighbourhoods keep the lowest-indexed neighbours.
  const body::VertexNeighbours capped = body::vertex_neighbours(faces, 36, 4);
  EXPECT_EQ(capped.indices.size(1), 4);
  EXPECT_TRUE(capped.indices[id(2, 2)].equal(all.indices[id(2, 2)].narrow(0, 0, 4)));
  EXPECT_EQ(capped.counts[id(2, 2)].item<int64_t>(), 4);
}

TEST(BodyMesh, FacesAroundEachVertexInTheReferencesOrder) {
  // Face 3 has a corner beyond the 4 vertices: left out. Each vertex lists the faces where it is the first corner,
  // then the second, then the third, each by face index.
  const at::Tensor faces = at::tensor({0, 1, 2, 2, 1, 3, 3, 0, 2, 0, 9, 1}, at::kLong).view({4, 3});
  const body::VertexFaces around = body::vertex_faces(faces, 4);
  EXPECT_TRUE(around.offsets.equal(at::tensor({0, 2, 4, 7, 9}, at::kInt)));
  EXPECT_TRUE(around.face_indices.narrow(0, 0, 9).equal(at::tensor({0, 2, 0, 1, 1, 0, 2, 2, 1}, at::kInt)));
  EXPECT_THROW(body::vertex_faces(faces.to(at::kInt), 4), c10::Error);
  EXPECT_THROW(body::vertex_faces(faces.view({-1}), 4), c10::Error);

  // On the procedural body's mesh the listed faces are each vertex's own: their normals, summed in that order (as
  // the fused CUDA kernel does), are the reference's normals.
  at::manual_seed(3);
  const auto& body = procedural_body().smplx;
  const at::Tensor mesh = body.faces.to(at::kLong);
  const int64_t v = body.v_template.size(0);
  const at::Tensor points = body.v_template.to(at::kFloat) + 0.002 * at::randn({v, 3});
  const body::VertexFaces order = body::vertex_faces(mesh, v);
  const auto offsets = order.offsets.accessor<int32_t, 1>();
  const auto listed = order.face_indices.accessor<int32_t, 1>();
  const auto f = mesh.accessor<int64_t, 2>();
  const auto p = points.accessor<float, 2>();
  at::Tensor sums = at::zeros({v, 3});
  auto sum = sums.accessor<float, 2>();
  for (int64_t i = 0; i < v; ++i)
    for (int32_t k = offsets[i]; k < offsets[i + 1]; ++k) {
      const int64_t face = listed[k];
      float e1[3], e2[3];
      for (int c = 0; c < 3; ++c) {
        e1[c] = p[f[face][1]][c] - p[f[face][0]][c];
        e2[c] = p[f[face][2]][c] - p[f[face][0]][c];
      }
      sum[i][0] += e1[1] * e2[2] - e1[2] * e2[1];
      sum[i][1] += e1[2] * e2[0] - e1[0] * e2[2];
      sum[i][2] += e1[0] * e2[1] - e1[1] * e2[0];
    }
  const at::Tensor reference = body::vertex_normals_reference(points, mesh);
  const at::Tensor length = sums.pow(2).sum(1, /*keepdim=*/true).sqrt();
  EXPECT_LT((sums / length - reference).abs().max().item<double>(), 1e-5);
}

TEST(BodyParts, LabelsFromWeightsFollowTheDominantJoint) {
  const auto& body = procedural_body().smplx;
  const at::Tensor dominant = body::dominant_joints(body.weights);
  EXPECT_TRUE(dominant.equal(body.weights.argmax(1)));
  const at::Tensor labels = body::part_labels_from_weights(body.weights);
  EXPECT_TRUE(labels.equal(body.part_labels));
  const auto d = dominant.accessor<int64_t, 1>();
  const auto l = labels.accessor<uint8_t, 1>();
  std::array<int64_t, 4> counts = {0, 0, 0, 0};
  for (int64_t i = 0; i < labels.size(0); ++i) {
    const int64_t j = d[i];
    body::BodyPart expected = body::BodyPart::kBody;
    if (j == 15 || j == 22 || j == 23 || j == 24) expected = body::BodyPart::kFace;
    if (j == 20 || (j >= 25 && j < 40)) expected = body::BodyPart::kLeftHand;
    if (j == 21 || j >= 40) expected = body::BodyPart::kRightHand;
    ASSERT_EQ(l[i], static_cast<uint8_t>(expected)) << "vertex " << i << " dominated by joint " << j;
    ++counts[l[i]];
  }
  for (int64_t c : counts) EXPECT_GT(c, 500);
  EXPECT_EQ(counts[2], counts[3]);
  EXPECT_STREQ(body::body_part_name(body::BodyPart::kLeftHand), "left_hand");
}

TEST(BodyParts, LabelsFromIdFilesWithHandsWinningOverlaps) {
  const at::Tensor labels = body::part_labels_from_vertex_ids(6, at::tensor({1, 2, 3}, at::kLong),
                                                              at::tensor({3}, at::kInt), at::tensor({5}, at::kLong));
  EXPECT_TRUE(labels.equal(at::tensor({0, 1, 1, 2, 0, 3}, at::kInt).to(at::kByte)));
  expect_error([] { body::part_labels_from_vertex_ids(6, at::tensor({7}, at::kLong), {}, {}); },
               {"face vertex ids", "7..7", "6 vertices"});

  ScratchFolder folder;
  const auto& body = procedural_body();
  const int64_t v = body.smplx.v_template.size(0);
  const std::string hand_file = folder.file("MANO_SMPLX_vertex_ids.npz"), face_file = folder.file("face_ids.npy");
  io::write_npz(hand_file, {{"left_hand", body.hand_vertex_ids.left}, {"right_hand", body.hand_vertex_ids.right}},
                false);
  io::write_npy(face_file, body.face_vertex_ids.to(at::kInt), false);  // any integer dtype will do
  const body::HandVertexIds ids = body::load_hand_vertex_ids(hand_file, v);
  EXPECT_TRUE(ids.left.equal(body.hand_vertex_ids.left));
  EXPECT_TRUE(ids.right.equal(body.hand_vertex_ids.right));
  const at::Tensor face = body::load_face_vertex_ids(face_file, v);
  EXPECT_TRUE(face.equal(body.face_vertex_ids));
  // The hand regions reach up the wrist beyond the hand labels; the face ids are exactly the face labels.
  const at::Tensor from_ids = body::part_labels_from_vertex_ids(v, face, ids.left, ids.right);
  EXPECT_TRUE((from_ids == body.smplx.part_labels).logical_or(body.smplx.part_labels == 0).all().item<bool>());
  expect_error([&] { body::load_hand_vertex_ids(hand_file, 100); },
               {"'left_hand' of", "100 vertices", "another model"});
  io::write_npz(folder.file("one_hand.npz"), {{"left_hand", ids.left}}, false);
  expect_error([&] { body::load_hand_vertex_ids(folder.file("one_hand.npz"), v); }, {"has no array 'right_hand'"});
}

TEST(BodyParts, AnnyIdFilesLoad) {
  SFGS_SKIP_WITHOUT_SHARED_BODIES();
  const std::string folder = shared_bodies_folder();
  const int64_t v = anny_smplx().v_template.size(0);
  const body::HandVertexIds ids = body::load_hand_vertex_ids(folder + "/MANO_SMPLX_vertex_ids.npz", v);
  EXPECT_EQ(ids.left.size(0), 1649);
  const at::Tensor face = body::load_face_vertex_ids(folder + "/FLAME_SMPLX_vertex_ids.npy", v);
  EXPECT_EQ(face.size(0), 4344);
  const at::Tensor labels = body::part_labels_from_vertex_ids(v, face, ids.left, ids.right);
  EXPECT_EQ((labels == 1).sum().item<int64_t>(), 4344);
  EXPECT_EQ((labels == 2).sum().item<int64_t>(), 1649);
  // The id-file regions agree with the weights' dominant joints for most vertices.
  const at::Tensor from_weights = body::part_labels_from_weights(anny_smplx().weights);
  EXPECT_GT((from_weights == labels).to(at::kDouble).mean().item<double>(), 0.9);
}

}  // namespace
}  // namespace sfgs::testing
