// Nearest neighbours (a k-d tree on the CPU: blocked brute force through this LibTorch's reference BLAS costs
// ~15 minutes per direction for 167k x 167k points, the tree well under a second) and the region metrics.
#include "metrics/geometry_metrics.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <functional>
#include <limits>
#include <numeric>
#include <vector>

#include <ATen/ATen.h>
#include <ATen/Parallel.h>

#include "metrics/image_layout.h"

namespace sfgs::metrics {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
// Points per k-d tree leaf: small enough to prune well, large enough to keep the tree shallow.
constexpr int64_t kLeafSize = 16;

class KdTree {
 public:
  // points: contiguous (N, 3) float64 on the CPU.
  explicit KdTree(const at::Tensor& points) : count_(points.size(0)) {
    const double* p = points.data_ptr<double>();
    std::vector<int64_t> order(count_);
    std::iota(order.begin(), order.end(), 0);
    if (count_ > 0) build(p, order, 0, count_);
    // Points copied in leaf order so a leaf scan reads contiguous memory.
    coordinates_.resize(3 * count_);
    original_index_ = order;
    for (int64_t i = 0; i < count_; ++i)
      for (int k = 0; k < 3; ++k) coordinates_[3 * i + k] = p[3 * order[i] + k];
  }

  // (squared distance, original index) of the nearest point; exact ties resolve deterministically.
  std::pair<double, int64_t> nearest(const double* q) const {
    std::pair<double, int64_t> best{std::numeric_limits<double>::infinity(), -1};
    if (count_ > 0) visit(0, q, best);
    return best;
  }

 private:
  struct Node {
    int64_t begin, end;  // range of leaf-ordered points below this node
    int axis = -1;       // -1 for a leaf
    double split = 0;
    int64_t left = -1, right = -1;
  };

  int64_t build(const double* p, std::vector<int64_t>& order, int64_t begin, int64_t end) {
    const int64_t id = int64_t(nodes_.size());
    nodes_.push_back({begin, end});
    if (end - begin <= kLeafSize) return id;
    std::array<double, 3> low, high;
    low.fill(std::numeric_limits<double>::infinity());
    high.fill(-std::numeric_limits<double>::infinity());
    for (int64_t i = begin; i < end; ++i)
      for (int k = 0; k < 3; ++k) {
        low[k] = std::min(low[k], p[3 * order[i] + k]);
        high[k] = std::max(high[k], p[3 * order[i] + k]);
      }
    int axis = 0;
    for (int k = 1; k < 3; ++k)
      if (high[k] - low[k] > high[axis] - low[axis]) axis = k;
    const int64_t middle = begin + (end - begin) / 2;
    std::nth_element(order.begin() + begin, order.begin() + middle, order.begin() + end,
                     [&](int64_t a, int64_t b) { return p[3 * a + axis] < p[3 * b + axis]; });
    nodes_[id].axis = axis;
    nodes_[id].split = p[3 * order[middle] + axis];
    // Left holds coordinates <= split, right >= split: the query descends by the sign of its offset.
    const int64_t left = build(p, order, begin, middle);
    const int64_t right = build(p, order, middle, end);
    nodes_[id].left = left;
    nodes_[id].right = right;
    return id;
  }

  void visit(int64_t id, const double* q, std::pair<double, int64_t>& best) const {
    const Node& node = nodes_[id];
    if (node.axis < 0) {
      for (int64_t i = node.begin; i < node.end; ++i) {
        const double dx = coordinates_[3 * i] - q[0], dy = coordinates_[3 * i + 1] - q[1],
                     dz = coordinates_[3 * i + 2] - q[2];
        const double d2 = dx * dx + dy * dy + dz * dz;
        if (d2 < best.first || (d2 == best.first && original_index_[i] < best.second)) best = {d2, original_index_[i]};
      }
      return;
    }
    const double offset = q[node.axis] - node.split;
    visit(offset < 0 ? node.left : node.right, q, best);
    // Strict: exploring on equality would make sets of coincident points quadratic.
    if (offset * offset < best.first) visit(offset < 0 ? node.right : node.left, q, best);
  }

  int64_t count_;
  std::vector<Node> nodes_;
  std::vector<double> coordinates_;
  std::vector<int64_t> original_index_;
};

void check_points(const char* what, const at::Tensor& points) {
  TORCH_CHECK(points.defined() && points.dim() == 2 && points.size(1) == 3 && at::isFloatingType(points.scalar_type()),
              what, " must be a floating tensor of shape (N, 3), got ", describe(points));
}

void check_query_target(const at::Tensor& queries, const at::Tensor& targets) {
  check_points("nearest_neighbours: queries", queries);
  check_points("nearest_neighbours: targets", targets);
  TORCH_CHECK(queries.device() == targets.device(), "nearest_neighbours: queries and targets must share a device, got ",
              describe(queries), " and ", describe(targets));
  TORCH_CHECK(targets.size(0) > 0 || queries.size(0) == 0,
              "nearest_neighbours: targets must not be empty when there are queries, got ", describe(targets));
}

NearestNeighbours kd_tree_search(const at::Tensor& queries, const at::Tensor& targets) {
  const at::Tensor q = queries.to(at::kDouble).contiguous();
  const KdTree tree(targets.to(at::kDouble).contiguous());
  const int64_t count = q.size(0);
  at::Tensor distance = at::empty({count}, q.options());
  at::Tensor index = at::empty({count}, q.options().dtype(at::kLong));
  const double* qp = q.data_ptr<double>();
  double* dp = distance.data_ptr<double>();
  int64_t* ip = index.data_ptr<int64_t>();
  at::parallel_for(0, count, 1024, [&](int64_t begin, int64_t end) {
    for (int64_t i = begin; i < end; ++i) {
      const auto [d2, j] = tree.nearest(qp + 3 * i);
      dp[i] = std::sqrt(d2);
      ip[i] = j;
    }
  });
  return {distance, index};
}

// Mean of `values` over the entries selected by `mask` (NaN when none is).
double masked_mean(const at::Tensor& values, const at::Tensor& mask) {
  return values.index({mask}).mean().item<double>();
}

double masked_max(const at::Tensor& values, const at::Tensor& mask) {
  const at::Tensor selected = values.index({mask});
  return selected.numel() > 0 ? selected.max().item<double>() : kNaN;
}

void check_surface(const char* name, const SurfacePoints& s) {
  check_points(name, s.points);
  TORCH_CHECK(s.labels.defined() && s.labels.dim() == 1 && s.labels.size(0) == s.points.size(0) &&
                  !at::isFloatingType(s.labels.scalar_type()) && s.labels.scalar_type() != at::kBool,
              name, " labels must be an integer tensor of shape (", s.points.size(0), "), got ", describe(s.labels));
  TORCH_CHECK(s.labels.device() == s.points.device(), name, " labels must be on the points' device, got ",
              describe(s.labels));
  if (s.labels.numel() > 0) {
    const int64_t low = s.labels.min().item<int64_t>(), high = s.labels.max().item<int64_t>();
    TORCH_CHECK(low >= 0 && high < body::kBodyPartCount, name, " labels must be body::BodyPart values in [0, ",
                body::kBodyPartCount - 1, "], got values in [", low, ", ", high, "]");
  }
  if (s.normals.defined()) {
    TORCH_CHECK(s.normals.sizes() == s.points.sizes() && at::isFloatingType(s.normals.scalar_type()) &&
                    s.normals.device() == s.points.device(),
                name, " normals must be a floating tensor shaped like the points ", s.points.sizes(), ", got ",
                describe(s.normals));
  }
}

// |n_a . n_b| of unit normals; NaN (a zero normal) counts as consistent, as in SFGS.
at::Tensor normal_agreement(const at::Tensor& normals, const at::Tensor& matched_normals) {
  const auto unit = [](const at::Tensor& n) { return n / n.norm(2, 1, true); };
  const at::Tensor dot = (unit(normals) * unit(matched_normals)).sum(1).abs();
  return at::where(at::isnan(dot), at::ones_like(dot), dot);
}

}  // namespace

NearestNeighbours nearest_neighbours_brute_force(const at::Tensor& queries, const at::Tensor& targets,
                                                 int64_t block_elements) {
  check_query_target(queries, targets);
  TORCH_CHECK(block_elements > 0, "nearest_neighbours_brute_force: block_elements must be positive, got ",
              block_elements);
  const at::Tensor q = queries.to(at::kDouble), t = targets.to(at::kDouble);
  const int64_t m = q.size(0), n = t.size(0);
  const int64_t target_block = std::min(n, block_elements);
  const int64_t query_block = std::max<int64_t>(1, block_elements / std::max<int64_t>(1, target_block));
  const at::Tensor t_squared = t.pow(2).sum(1);
  std::vector<at::Tensor> indices;
  for (int64_t qs = 0; qs < m; qs += query_block) {
    const at::Tensor qb = q.narrow(0, qs, std::min(query_block, m - qs));
    const at::Tensor qb_squared = qb.pow(2).sum(1, true);
    at::Tensor best = at::full({qb.size(0)}, std::numeric_limits<double>::infinity(), qb.options());
    at::Tensor best_index = at::zeros({qb.size(0)}, qb.options().dtype(at::kLong));
    for (int64_t ts = 0; ts < n; ts += target_block) {
      const int64_t width = std::min(target_block, n - ts);
      // |q|^2 - 2 q.t + |t|^2 through one matrix product; the winner's distance is recomputed exactly below.
      const at::Tensor d2 =
          at::addmm(t_squared.narrow(0, ts, width).unsqueeze(0), qb, t.narrow(0, ts, width).t(), 1.0, -2.0) +
          qb_squared;
      const auto [block_best, block_index] = d2.min(1);
      const at::Tensor better = block_best < best;
      best = at::where(better, block_best, best);
      best_index = at::where(better, block_index + ts, best_index);
    }
    indices.push_back(best_index);
  }
  const at::Tensor index = m > 0 ? at::cat(indices) : at::zeros({0}, q.options().dtype(at::kLong));
  const at::Tensor distance = n > 0 ? (q - t.index_select(0, index)).norm(2, 1) : at::zeros({0}, q.options());
  return {distance, index};
}

NearestNeighbours nearest_neighbours(const at::Tensor& queries, const at::Tensor& targets) {
  check_query_target(queries, targets);
  if (queries.device().is_cpu()) return kd_tree_search(queries, targets);
  return nearest_neighbours_brute_force(queries, targets);
}

double bounding_box_iou(const at::Tensor& points_a, const at::Tensor& points_b) {
  check_points("bounding_box_iou: points_a", points_a);
  check_points("bounding_box_iou: points_b", points_b);
  if (points_a.size(0) == 0 || points_b.size(0) == 0) return kNaN;
  const auto bounds = [](const at::Tensor& p) {
    const at::Tensor d = p.to(at::kDouble);
    return std::make_pair(std::get<0>(d.min(0)), std::get<0>(d.max(0)));
  };
  const auto [low_a, high_a] = bounds(points_a);
  const auto [low_b, high_b] = bounds(points_b);
  const double volume_a = (high_a - low_a).prod().item<double>();
  const double volume_b = (high_b - low_b).prod().item<double>();
  const double intersection =
      (at::minimum(high_a, high_b) - at::maximum(low_a, low_b)).clamp_min(0.0).prod().item<double>();
  const double union_volume = volume_a + volume_b - intersection;
  return union_volume > 0 ? intersection / union_volume : 0.0;
}

GeometryMetrics geometry_metrics(const SurfacePoints& prediction, const SurfacePoints& target) {
  check_surface("geometry_metrics: prediction", prediction);
  check_surface("geometry_metrics: target", target);
  TORCH_CHECK(prediction.points.device() == target.points.device(),
              "geometry_metrics: prediction and target must share a device, got ", describe(prediction.points), " and ",
              describe(target.points));
  TORCH_CHECK(prediction.normals.defined() == target.normals.defined(),
              "geometry_metrics: give normals for both surfaces or for neither");
  TORCH_CHECK(prediction.points.size(0) > 0 && target.points.size(0) > 0,
              "geometry_metrics: both surfaces need points, got ", describe(prediction.points), " and ",
              describe(target.points));

  const NearestNeighbours forward = nearest_neighbours(prediction.points, target.points);
  const NearestNeighbours backward = nearest_neighbours(target.points, prediction.points);
  at::Tensor forward_normals, backward_normals;
  if (prediction.normals.defined()) {
    const at::Tensor pn = prediction.normals.to(at::kDouble), tn = target.normals.to(at::kDouble);
    forward_normals = normal_agreement(pn, tn.index_select(0, forward.index));
    backward_normals = normal_agreement(tn, pn.index_select(0, backward.index));
  }
  const auto in_region = [](const at::Tensor& labels, std::initializer_list<body::BodyPart> region) {
    at::Tensor mask = at::zeros_like(labels, labels.options().dtype(at::kBool));
    for (body::BodyPart r : region) mask = mask | (labels == int64_t(r));
    return mask;
  };
  const auto box_iou_of = [&](std::initializer_list<body::BodyPart> region) {
    return bounding_box_iou(prediction.points.index({in_region(prediction.labels, region)}),
                            target.points.index({in_region(target.labels, region)}));
  };
  const auto measure = [&](std::initializer_list<body::BodyPart> region, const std::function<double()>& box_iou) {
    const at::Tensor prediction_mask = in_region(prediction.labels, region);
    const at::Tensor target_mask = in_region(target.labels, region);
    RegionGeometry g;
    g.prediction_points = prediction_mask.sum().item<int64_t>();
    g.target_points = target_mask.sum().item<int64_t>();
    if (g.prediction_points == 0 || g.target_points == 0) {
      g.chamfer = g.chamfer_max = g.box_iou = kNaN;
      if (prediction.normals.defined()) g.normal_consistency = kNaN;
      return g;
    }
    g.chamfer = 0.5 * (masked_mean(forward.distance, prediction_mask) + masked_mean(backward.distance, target_mask));
    g.chamfer_max = 0.5 * (masked_max(forward.distance, prediction_mask) + masked_max(backward.distance, target_mask));
    if (prediction.normals.defined()) {
      g.normal_consistency =
          0.5 * (masked_mean(forward_normals, prediction_mask) + masked_mean(backward_normals, target_mask));
    }
    g.box_iou = box_iou();
    return g;
  };

  using R = body::BodyPart;
  GeometryMetrics metrics;
  metrics.all = measure({R::kBody, R::kFace, R::kLeftHand, R::kRightHand},
                        [&] { return bounding_box_iou(prediction.points, target.points); });
  metrics.face = measure({R::kFace}, [&] { return box_iou_of({R::kFace}); });
  metrics.hands = measure({R::kLeftHand, R::kRightHand},
                          [&] { return 0.5 * (box_iou_of({R::kLeftHand}) + box_iou_of({R::kRightHand})); });
  return metrics;
}

}  // namespace sfgs::metrics
