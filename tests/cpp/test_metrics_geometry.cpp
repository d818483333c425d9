// Geometry metrics on analytic point sets: a sphere against a scaled sphere, tilted normals, boxes with known
// overlap, region matching against the whole other surface; the k-d tree against brute force.
#include <cmath>
#include <limits>

#include <gtest/gtest.h>

#include "metrics/geometry_metrics.h"
#include "test_metrics_support.h"

namespace sfgs::testing {
namespace {

using body::BodyPart;
using metrics::SurfacePoints;

// Unit vectors spread evenly over the sphere (Fibonacci lattice), (N, 3) float64.
at::Tensor sphere_points(int64_t n) {
  const at::Tensor i = at::arange(n, at::kDouble);
  const at::Tensor z = 1.0 - 2.0 * (i + 0.5) / double(n);
  const at::Tensor r = at::sqrt(1.0 - z * z);
  const at::Tensor phi = i * (M_PI * (3.0 - std::sqrt(5.0)));
  return at::stack({r * at::cos(phi), r * at::sin(phi), z}, 1);
}

// Face on top (z > 0.8), right hand at +x, left hand at -x, the rest body.
at::Tensor region_labels(const at::Tensor& directions) {
  at::Tensor labels = at::zeros({directions.size(0)}, at::kLong);
  labels.masked_fill_(directions.select(1, 2) > 0.8, int64_t(BodyPart::kFace));
  labels.masked_fill_(directions.select(1, 0) > 0.8, int64_t(BodyPart::kRightHand));
  labels.masked_fill_(directions.select(1, 0) < -0.8, int64_t(BodyPart::kLeftHand));
  return labels;
}

TEST(MetricsGeometry, SphereAgainstAScaledSphere) {
  // Every point's nearest neighbour on the other sphere is along its own direction: distance 0.1 both ways.
  const at::Tensor directions = sphere_points(3000);
  const at::Tensor labels = region_labels(directions);
  const double scale = 1.1;
  const SurfacePoints prediction{directions, directions * 3.0, labels};  // normals of any length
  const SurfacePoints target{directions * scale, directions, labels};
  const metrics::GeometryMetrics g = metrics::geometry_metrics(prediction, target);
  for (const metrics::RegionGeometry* r : {&g.all, &g.face, &g.hands}) {
    EXPECT_NEAR(r->chamfer, scale - 1.0, 1e-12);
    EXPECT_NEAR(r->chamfer_max, scale - 1.0, 1e-12);
    ASSERT_TRUE(r->normal_consistency.has_value());
    EXPECT_NEAR(*r->normal_consistency, 1.0, 1e-12);
    EXPECT_EQ(r->prediction_points, r->target_points);
  }
  EXPECT_EQ(g.all.prediction_points, 3000);
  EXPECT_EQ(g.face.prediction_points, (labels == int64_t(BodyPart::kFace)).sum().item<int64_t>());
  EXPECT_GT(g.face.prediction_points, 100);
  EXPECT_GT(g.hands.prediction_points, 200);
  // The scaled sphere's box is the unit box scaled about the origin, which it contains: IoU = 1 / scale^3.
  EXPECT_NEAR(g.all.box_iou, 1.0 / std::pow(scale, 3), 1e-12);
  EXPECT_GT(g.face.box_iou, 0.0);
  EXPECT_LT(g.face.box_iou, 1.0);
}

TEST(MetricsGeometry, TiltedNormalsGiveTheCosineOfTheTilt) {
  const at::Tensor directions = sphere_points(1000);
  const at::Tensor labels = region_labels(directions);
  // Tilt every normal by 30 degrees towards a tangent: |cos| = cos(30 deg) in both directions.
  const at::Tensor helper = at::tensor({0.3, 0.5, 0.8}, at::kDouble).expand_as(directions);
  at::Tensor tangent = at::cross(directions, helper, 1);
  tangent = tangent / tangent.norm(2, 1, true);
  const double tilt = M_PI / 6;
  const at::Tensor tilted = std::cos(tilt) * directions + std::sin(tilt) * tangent;
  const metrics::GeometryMetrics g = metrics::geometry_metrics({directions, -tilted, labels},  // sign is ignored
                                                               {directions * 1.05, directions, labels});
  EXPECT_NEAR(*g.all.normal_consistency, std::cos(tilt), 1e-12);
  EXPECT_NEAR(*g.face.normal_consistency, std::cos(tilt), 1e-12);
  const metrics::GeometryMetrics no_normals =
      metrics::geometry_metrics({directions, at::Tensor(), labels}, {directions * 1.05, at::Tensor(), labels});
  EXPECT_FALSE(no_normals.all.normal_consistency.has_value());
  EXPECT_NEAR(no_normals.all.chamfer, 0.05, 1e-12);
}

TEST(MetricsGeometry, RegionPointsAreMatchedAgainstTheWholeOtherSurface) {
  // Prediction: a face point at 0 and a body point at 5; target: a body point at 0.5 and a face point at 3.
  // Face, prediction -> target: 0 -> 0.5 (a body point) = 0.5; target -> prediction: 3 -> 5 = 2.
  // Region-to-region matching would give 3 both ways instead.
  const at::Tensor prediction_points = at::tensor({0.0, 0.0, 0.0, 5.0, 0.0, 0.0}, at::kDouble).view({2, 3});
  const at::Tensor target_points = at::tensor({0.5, 0.0, 0.0, 3.0, 0.0, 0.0}, at::kDouble).view({2, 3});
  const int64_t face = int64_t(BodyPart::kFace), body = int64_t(BodyPart::kBody);
  const metrics::GeometryMetrics g = metrics::geometry_metrics({prediction_points, {}, at::tensor({face, body})},
                                                               {target_points, {}, at::tensor({body, face})});
  EXPECT_NEAR(g.face.chamfer, 1.25, 1e-15);
  EXPECT_NEAR(g.face.chamfer_max, 1.25, 1e-15);
  // All: prediction -> target distances 0.5, 2 (mean 1.25, max 2); target -> prediction 0.5, 2 (same).
  EXPECT_NEAR(g.all.chamfer, 1.25, 1e-15);
  EXPECT_NEAR(g.all.chamfer_max, 2.0, 1e-15);
  // No hand points anywhere: the hands' metrics are undefined, not 0.
  EXPECT_EQ(g.hands.prediction_points, 0);
  EXPECT_TRUE(std::isnan(g.hands.chamfer) && std::isnan(g.hands.chamfer_max) && std::isnan(g.hands.box_iou));
}

TEST(MetricsGeometry, BoundingBoxIou) {
  // [0,2]x[0,1]x[0,1] (volume 2) and [1,3]x[0,1]x[0.5,1.5] (volume 2) overlap in [1,2]x[0,1]x[0.5,1]: 0.5 / 3.5.
  const at::Tensor a = at::tensor({0.0, 0.0, 0.0, 2.0, 1.0, 1.0, 1.0, 0.5, 0.2}, at::kDouble).view({3, 3});
  const at::Tensor b = at::tensor({1.0, 0.0, 0.5, 3.0, 1.0, 1.5}, at::kFloat).view({2, 3});
  EXPECT_NEAR(metrics::bounding_box_iou(a, b), 1.0 / 7.0, 1e-7);  // b is float32
  EXPECT_NEAR(metrics::bounding_box_iou(a, a), 1.0, 1e-15);
  EXPECT_EQ(metrics::bounding_box_iou(a, a + 5.0), 0.0);
  EXPECT_EQ(metrics::bounding_box_iou(a * at::tensor({1.0, 1.0, 0.0}, at::kDouble),
                                      a * at::tensor({1.0, 1.0, 0.0}, at::kDouble)),
            0.0)
      << "flat boxes have no volume";
  EXPECT_TRUE(std::isnan(metrics::bounding_box_iou(a, at::zeros({0, 3}, at::kDouble))));
}

TEST(MetricsNearestNeighbours, KdTreeAgreesWithBruteForce) {
  at::manual_seed(11);
  // Clustered points with exact duplicates, so ties and uneven density both occur.
  const at::Tensor centres = at::rand({8, 3}, at::kDouble) * 4.0;
  at::Tensor targets = centres.repeat({300, 1}) + 0.05 * at::randn({2400, 3}, at::kDouble);
  targets = at::cat({targets, targets.slice(0, 0, 100)});
  const at::Tensor queries = at::cat({at::rand({1500, 3}, at::kDouble) * 4.5 - 0.25, targets.slice(0, 0, 50)});
  const metrics::NearestNeighbours tree = metrics::nearest_neighbours(queries, targets);
  const metrics::NearestNeighbours brute = metrics::nearest_neighbours_brute_force(queries, targets, 97);
  EXPECT_LT((tree.distance - brute.distance).abs().max().item<double>(), 1e-12);
  // Whichever neighbour each search picked lies at the reported distance.
  EXPECT_LT(((queries - targets.index_select(0, tree.index)).norm(2, 1) - tree.distance).abs().max().item<double>(),
            1e-15);
  EXPECT_LT(((queries - targets.index_select(0, brute.index)).norm(2, 1) - tree.distance).abs().max().item<double>(),
            1e-12);
  EXPECT_EQ(tree.distance.slice(0, 1500).abs().max().item<double>(), 0.0) << "queries on targets";
  // float32 input is searched in float64.
  const metrics::NearestNeighbours single = metrics::nearest_neighbours(queries.to(at::kFloat), targets.to(at::kFloat));
  EXPECT_EQ(single.distance.scalar_type(), at::kDouble);
  EXPECT_LT((single.distance - tree.distance).abs().max().item<double>(), 1e-5);
}

TEST(MetricsNearestNeighbours, TiesAndCoincidentPoints) {
  const at::Tensor targets =
      at::tensor({0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0}, at::kDouble).view({4, 3});
  const at::Tensor queries = at::tensor({1.0, 0.0, 0.0, 2.0, 0.0, 0.0, 0.5, 0.5, 0.0}, at::kDouble).view({3, 3});
  const metrics::NearestNeighbours n = metrics::nearest_neighbours(queries, targets);
  for (int i = 0; i < 2; ++i) EXPECT_TRUE(n.index[i].item<int64_t>() == 1 || n.index[i].item<int64_t>() == 2) << i;
  EXPECT_EQ(n.distance[0].item<double>(), 0.0);
  EXPECT_NEAR(n.distance[1].item<double>(), 1.0, 1e-15);
  EXPECT_NEAR(n.distance[2].item<double>(), std::sqrt(0.5), 1e-15) << "three targets tie at sqrt(0.5)";
  EXPECT_TRUE(at::equal(metrics::nearest_neighbours(queries, targets).index, n.index)) << "deterministic";
  // Thousands of coincident points (collapsed Gaussians) against a few others.
  const at::Tensor pile = at::cat({at::zeros({5000, 3}, at::kDouble), at::ones({3, 3}, at::kDouble)});
  const metrics::NearestNeighbours p = metrics::nearest_neighbours(pile, pile);
  EXPECT_EQ(p.distance.abs().max().item<double>(), 0.0);
}

TEST(MetricsGeometryValidation, BadInputsAreClearErrors) {
  const at::Tensor points = sphere_points(10), labels = at::zeros({10}, at::kLong);
  expect_error(
      [&] {
        metrics::geometry_metrics({points, {}, labels + 7}, {points, {}, labels});
      },
      {"geometry_metrics: prediction labels must be body::BodyPart values in [0, 3], got values in [7, 7]"});
  expect_error(
      [&] {
        metrics::geometry_metrics({points, {}, labels.slice(0, 0, 9)}, {points, {}, labels});
      },
      {"prediction labels must be an integer tensor of shape (10)", "[9]"});
  expect_error(
      [&] {
        metrics::geometry_metrics({points, {}, labels}, {points.slice(1, 0, 2), {}, labels});
      },
      {"geometry_metrics: target must be a floating tensor of shape (N, 3)", "[10, 2]"});
  expect_error(
      [&] {
        metrics::geometry_metrics({points, points.slice(0, 0, 5), labels}, {points, points, labels});
      },
      {"prediction normals must be a floating tensor shaped like the points"});
  expect_error(
      [&] {
        metrics::geometry_metrics({points, points, labels}, {points, {}, labels});
      },
      {"give normals for both surfaces or for neither"});
  expect_error(
      [&] {
        metrics::geometry_metrics({points, {}, labels}, {points.slice(0, 0, 0), {}, labels.slice(0, 0, 0)});
      },
      {"both surfaces need points"});
  expect_error(
      [&] {
        metrics::nearest_neighbours(points, at::zeros({0, 3}, at::kDouble));
      },
      {"targets must not be empty when there are queries"});
}

}  // namespace
}  // namespace sfgs::testing
