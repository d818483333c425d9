#pragma once
// Geometry metrics of a reconstructed surface against the ground truth per body region, as SFGS's region table
// (CD, CD-MAX, NC, IoU for all / face / hands; definitions follow SFGS common/evaluate.py, on given point sets
// instead of sampled mesh surfaces). Evaluation only: not differentiable. See docs/metrics.md.
#include <cstdint>
#include <optional>

#include <ATen/core/Tensor.h>

#include "body/parts.h"
#include "metrics/constants.h"

namespace sfgs::metrics {

struct NearestNeighbours {
  at::Tensor distance;  // (M) float64 Euclidean distance to the nearest target
  at::Tensor index;     // (M) int64 index of that target (among exact ties, the same one on every run)
};

// Exact nearest neighbour in targets (N, 3) of every query (M, 3), float32 or float64, computed in float64.
// CPU: a k-d tree, parallel over queries, O(N) memory. CUDA: nearest_neighbours_brute_force.
NearestNeighbours nearest_neighbours(const at::Tensor& queries, const at::Tensor& targets);

// Brute force on any device, holding at most block_elements query-target distances at a time.
NearestNeighbours nearest_neighbours_brute_force(const at::Tensor& queries, const at::Tensor& targets,
                                                 int64_t block_elements = kNearestNeighbourBlockElements);

// IoU of the axis-aligned bounding boxes of two point sets (N, 3) and (M, 3), as SFGS's "IoU" column.
// 0 when the boxes do not overlap or their union has no volume; NaN when either set is empty.
double bounding_box_iou(const at::Tensor& points_a, const at::Tensor& points_b);

struct SurfacePoints {
  at::Tensor points;   // (N, 3)
  at::Tensor normals;  // (N, 3), any length; undefined: normal consistency is not computed
  at::Tensor labels;   // (N) integer body::BodyPart values (the avatar's part labels' numbering)
};

// A region's metrics. Distances are in the unit of the points (SFGS prints millimetres: metres x 1e3).
// A region with no point in the prediction or in the target has NaN metrics.
struct RegionGeometry {
  int64_t prediction_points = 0, target_points = 0;
  double chamfer = 0;                        // (mean d(p -> T) + mean d(t -> P)) / 2 over the region's points
  double chamfer_max = 0;                    // (max d(p -> T) + max d(t -> P)) / 2
  std::optional<double> normal_consistency;  // mean |n_p . n_t| at the nearest neighbours, both directions averaged
  double box_iou = 0;                        // hands: the mean of the left and right hands' box IoUs
};

struct GeometryMetrics {
  RegionGeometry all, face, hands;
};

// Region points are matched against the whole other surface (a face point's nearest neighbour may lie
// anywhere), as SFGS does.
GeometryMetrics geometry_metrics(const SurfacePoints& prediction, const SurfacePoints& target);

}  // namespace sfgs::metrics
