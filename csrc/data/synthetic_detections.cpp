#include "data/synthetic_detections.h"

#include <ATen/ATen.h>

#include <algorithm>
#include <cmath>

#include "body/wholebody_keypoints.h"
#include "data/constants.h"
#include "ops/splat/constants.h"

namespace sfgs::data {
namespace {

using body::KeypointGroup;

// The diagonal of the image-space bounding box of `points` (N, 2) where `inside` holds; 0 when fewer than two.
double box_diagonal(const at::Tensor& points, const at::Tensor& inside) {
  const at::Tensor p = points.index({inside});
  if (p.size(0) < 2) return 0;
  const at::Tensor extent = std::get<0>(p.max(0)) - std::get<0>(p.min(0));
  return extent.norm().item<double>();
}

}  // namespace

DetectorNoise::DetectorNoise()
    : floor_pixels(kDetectorNoiseFloorPixels),
      body_share(kDetectorNoiseBodyShare),
      part_share(kDetectorNoisePartShare),
      outlier_rate(kDetectorOutlierRate),
      hidden_drop_rate(kDetectorHiddenDropRate) {}

at::Tensor simulate_detections(const at::Tensor& camera_keypoints, const Camera& camera, const at::Tensor& depth,
                               const at::Tensor& on_surface, const DetectorNoise& noise, at::Generator& gen) {
  const int64_t n = body::kWholeBodyKeypointCount;
  TORCH_CHECK(camera_keypoints.dim() == 2 && camera_keypoints.size(0) == n && camera_keypoints.size(1) == 3,
              "simulate_detections: expected (", n, ", 3) keypoints, got ", camera_keypoints.sizes());
  TORCH_CHECK(depth.dim() == 2 && depth.size(0) == camera.height && depth.size(1) == camera.width,
              "simulate_detections: the depth map must be (", camera.height, ", ", camera.width, "), got ",
              depth.sizes());
  const at::Tensor k = camera_keypoints.detach().to(at::kCPU, at::kDouble);
  const at::Tensor z = k.select(1, 2);
  const at::Tensor safe_z = z.clamp_min(kDefaultNearPlane);
  const at::Tensor u = camera.fx * k.select(1, 0) / safe_z + camera.cx;
  const at::Tensor v = camera.fy * k.select(1, 1) / safe_z + camera.cy;
  const at::Tensor exact_xy = at::stack({u, v}, 1);
  const at::Tensor in_image =
      (z > kDefaultNearPlane) & (u >= 0) & (u < double(camera.width)) & (v >= 0) & (v < double(camera.height));

  // Hidden: behind the rendered surface at its pixel by more than the layer a point of its kind may sit under.
  const at::Tensor column = u.floor().clamp(0, double(camera.width - 1)).to(at::kLong);
  const at::Tensor row = v.floor().clamp(0, double(camera.height - 1)).to(at::kLong);
  const at::Tensor surface_depth = depth.to(at::kCPU, at::kDouble).index({row, column});
  const at::Tensor allowance =
      at::where(on_surface.to(at::kCPU), at::full({n}, kSurfaceKeypointOcclusionDepth, at::kDouble),
                at::full({n}, kJointKeypointOcclusionDepth, at::kDouble));
  const at::Tensor hidden = in_image & (surface_depth > 0) & (z > surface_depth + allowance);

  // Noise per group: a floor plus a share of the person's height (body, feet) or of the part's own size.
  const double person = box_diagonal(exact_xy, in_image);
  at::Tensor sigma = at::full({n}, noise.floor_pixels, at::kDouble);
  for (KeypointGroup group : body::kKeypointGroups) {
    const body::KeypointRange r = body::keypoint_range(group);
    const bool whole_body = group == KeypointGroup::kBody || group == KeypointGroup::kFeet;
    const double size =
        whole_body ? person
                   : box_diagonal(exact_xy.narrow(0, r.begin, r.size()), in_image.narrow(0, r.begin, r.size()));
    sigma.narrow(0, r.begin, r.size()).add_((whole_body ? noise.body_share : noise.part_share) * size);
  }
  sigma = at::where(hidden, sigma * kDetectorHiddenNoiseFactor, sigma);

  // Every random draw happens whatever the options, so a video's detections depend on its seed alone.
  const at::Tensor jitter = at::empty({n, 2}, at::kDouble).normal_(0.0, 1.0, gen);
  const at::Tensor visible_score =
      at::empty({n}, at::kDouble).uniform_(kDetectorVisibleScore[0], kDetectorVisibleScore[1], gen);
  const at::Tensor hidden_score =
      at::empty({n}, at::kDouble).uniform_(kDetectorHiddenScore[0], kDetectorHiddenScore[1], gen);
  const at::Tensor drop_draw = at::empty({n}, at::kDouble).uniform_(0.0, 1.0, gen);
  const at::Tensor outlier_draw = at::empty({n}, at::kDouble).uniform_(0.0, 1.0, gen);
  const at::Tensor outlier_kind = at::empty({n}, at::kDouble).uniform_(0.0, 1.0, gen);
  const at::Tensor stray = at::empty({n, 2}, at::kDouble).uniform_(0.0, 1.0, gen);
  const at::Tensor outlier_score =
      at::empty({n}, at::kDouble).uniform_(kDetectorOutlierScore[0], kDetectorOutlierScore[1], gen);
  if (noise.exact) {
    const at::Tensor xy = at::stack({u.clamp(0, double(camera.width)), v.clamp(0, double(camera.height))}, 1);
    return at::cat({xy, in_image.to(at::kDouble).unsqueeze(1)}, 1).to(at::kFloat);
  }

  at::Tensor xy = exact_xy + jitter * sigma.unsqueeze(1);
  at::Tensor score = at::where(hidden, hidden_score, visible_score);
  // Outliers: half take the mirrored keypoint's place (the sides confused), half a stray point on the person.
  const at::Tensor face = at::zeros({n}, at::kBool);
  const body::KeypointRange face_range = body::keypoint_range(KeypointGroup::kFace);
  face.narrow(0, face_range.begin, face_range.size()).fill_(true);
  const at::Tensor outlier = in_image & ~hidden & ~face & (outlier_draw < noise.outlier_rate);
  const auto& mirror = body::wholebody_mirrored_keypoints();
  const at::Tensor mirrored =
      xy.index_select(0, at::tensor(std::vector<int64_t>(mirror.begin(), mirror.end()), at::kLong));
  const at::Tensor inside = exact_xy.index({in_image});
  at::Tensor stray_xy = stray;
  if (inside.size(0) > 0) {
    const at::Tensor lo = std::get<0>(inside.min(0)), hi = std::get<0>(inside.max(0));
    stray_xy = lo + stray * (hi - lo);
  }
  const at::Tensor replacement = at::where((outlier_kind < 0.5).unsqueeze(1), mirrored, stray_xy);
  xy = at::where(outlier.unsqueeze(1), replacement, xy);
  score = at::where(outlier, outlier_score, score);
  // Dropped: outside the image, or hidden and given up by the detector.
  const at::Tensor dropped = ~in_image | (hidden & (drop_draw < noise.hidden_drop_rate));
  score = at::where(dropped, at::zeros_like(score), score);
  xy = at::stack({xy.select(1, 0).clamp(0, double(camera.width)), xy.select(1, 1).clamp(0, double(camera.height))}, 1);
  return at::cat({xy, score.unsqueeze(1)}, 1).to(at::kFloat);
}

}  // namespace sfgs::data
