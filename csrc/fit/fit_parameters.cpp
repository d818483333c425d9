#include "fit/fit_parameters.h"

#include <ATen/ATen.h>

#include <cmath>
#include <vector>

#include "body/rotations.h"
#include "body/skeleton.h"
#include "fit/constants.h"

namespace sfgs::fit {
namespace {

using body::KeypointGroup;

// Upright orientations in camera coordinates: the model's y up turned to the camera's y down, facing the camera
// (a rotation of pi about x), then turned about the body's vertical axis in even steps.
at::Tensor candidate_orientations(const at::TensorOptions& options) {
  std::vector<at::Tensor> candidates;
  const at::Tensor flip = at::tensor({1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0}, options).view({3, 3});
  for (int64_t k = 0; k < kFitOrientationCandidates; ++k) {
    const double yaw = 2 * M_PI * double(k) / double(kFitOrientationCandidates);
    candidates.push_back(flip.matmul(body::axis_angle_to_matrix(at::tensor({0.0, yaw, 0.0}, options))));
  }
  return at::stack(candidates);  // (C, 3, 3)
}

// Keypoints that place a body still at rest: torso and head, which the limbs' poses do not move.
at::Tensor torso_and_head_mask(const at::TensorOptions& options) {
  at::Tensor mask = at::zeros({body::kWholeBodyKeypointCount}, options);
  for (int64_t k : {0, 1, 2, 3, 4, 5, 6, 11, 12}) mask[k] = 1.0;  // nose, eyes, ears, shoulders, hips
  return mask;
}

}  // namespace

at::Tensor FitParameters::rotations() const {
  const int64_t batch = translation.size(0);
  const auto options = translation.options();
  const at::Tensor root = body::axis_angle_to_matrix(root_correction).matmul(root_start).unsqueeze(1);
  const at::Tensor eyes = at::eye(3, options).expand({batch, 2, 3, 3});
  const at::Tensor rest = at::cat({body_pose, jaw_pose.unsqueeze(1)}, 1);
  const at::Tensor hands = at::cat({left_hand + left_hand_mean, right_hand + right_hand_mean}, 1);
  return at::cat({root, body::axis_angle_to_matrix(rest), eyes, body::axis_angle_to_matrix(hands)}, 1);
}

body::SmplxPose FitParameters::poses() const {
  const auto host = at::TensorOptions().dtype(at::kFloat).device(at::kCPU);
  const int64_t batch = translation.size(0);
  body::SmplxPose p;
  const at::Tensor root = body::axis_angle_to_matrix(root_correction.detach()).matmul(root_start);
  p.global_orient = body::matrix_to_axis_angle(root).to(host);
  p.body_pose = body_pose.detach().to(host);
  p.jaw_pose = jaw_pose.detach().to(host);
  p.leye_pose = at::zeros({batch, 3}, host);
  p.reye_pose = at::zeros({batch, 3}, host);
  p.left_hand_pose = left_hand.detach().to(host);
  p.right_hand_pose = right_hand.detach().to(host);
  p.expression = expression.detach().to(host);
  p.transl = translation.detach().to(host);
  return p;
}

FitParameters parameters_from_fits(const body::SmplxPose& fits, const at::Tensor& betas,
                                   const at::Tensor& left_hand_mean, const at::Tensor& right_hand_mean,
                                   int64_t expressions, const at::TensorOptions& options) {
  const int64_t batch = fits.transl.size(0);
  FitParameters p;
  p.betas = betas.to(options).clone();
  p.root_start = body::axis_angle_to_matrix(fits.global_orient.to(options).view({batch, 3}));
  p.root_correction = at::zeros({batch, 3}, options);
  p.translation = fits.transl.to(options).view({batch, 3}).clone();
  p.body_pose = fits.body_pose.to(options).view({batch, body::kSmplxBodyJointCount, 3}).clone();
  p.jaw_pose = fits.jaw_pose.to(options).view({batch, 3}).clone();
  p.left_hand = fits.left_hand_pose.to(options).view({batch, body::kHandJointCount, 3}).clone();
  p.right_hand = fits.right_hand_pose.to(options).view({batch, body::kHandJointCount, 3}).clone();
  // Expressions of another length are cut or padded with zeros.
  p.expression = at::zeros({batch, expressions}, options);
  const int64_t given = std::min<int64_t>(expressions, fits.expression.size(1));
  p.expression.narrow(1, 0, given).copy_(fits.expression.to(options).narrow(1, 0, given));
  p.left_hand_mean = left_hand_mean.to(options).view({body::kHandJointCount, 3});
  p.right_hand_mean = right_hand_mean.to(options).view({body::kHandJointCount, 3});
  return p;
}

PosedKeypoints pose_keypoints(const KeypointBody& body, const body::WholeBodyKeypointMap& keypoint_map,
                              const FitParameters& parameters) {
  const PosedPoints posed =
      body.forward(parameters.betas, parameters.expression, parameters.rotations(), parameters.translation);
  const at::Tensor neck = posed.joint_rotations.select(1, body::smplx_joint::kNeck);
  const at::Tensor bins = body::contour_bins(neck, keypoint_map.contour_bin_count());
  const int64_t support = keypoint_map.support_vertices().size(0);
  return {keypoint_map.evaluate(posed.points.narrow(1, 0, support), posed.joints, bins), posed.joints};
}

FitParameters initial_parameters(const KeypointBody& body, const body::WholeBodyKeypointMap& keypoint_map,
                                 const KeypointObservations& observed, const at::Tensor& betas,
                                 const at::Tensor& left_hand_mean, const at::Tensor& right_hand_mean,
                                 int64_t expressions) {
  const int64_t batch = observed.pixels.size(0);
  const auto options = observed.pixels.options();
  FitParameters p;
  p.betas = betas.to(options).clone();
  p.expression = at::zeros({batch, expressions}, options);
  p.body_pose = body_prior_centre_and_weights(options).first.expand({batch, -1, -1}).clone();
  p.jaw_pose = at::zeros({batch, 3}, options);
  p.left_hand = at::zeros({batch, body::kHandJointCount, 3}, options);
  p.right_hand = at::zeros({batch, body::kHandJointCount, 3}, options);
  p.left_hand_mean = left_hand_mean.to(options).view({body::kHandJointCount, 3});
  p.right_hand_mean = right_hand_mean.to(options).view({body::kHandJointCount, 3});
  p.root_correction = at::zeros({batch, 3}, options);

  // The rest body's keypoints about its pelvis, turned by every candidate: (C, 133, 3).
  FitParameters rest = p;
  rest.expression = p.expression.narrow(0, 0, 1);
  rest.body_pose = p.body_pose.narrow(0, 0, 1);
  rest.jaw_pose = p.jaw_pose.narrow(0, 0, 1);
  rest.left_hand = p.left_hand.narrow(0, 0, 1);
  rest.right_hand = p.right_hand.narrow(0, 0, 1);
  rest.root_correction = p.root_correction.narrow(0, 0, 1);
  rest.root_start = at::eye(3, options).unsqueeze(0);
  rest.translation = at::zeros({1, 3}, options);
  const at::Tensor rest_keypoints = pose_keypoints(body, keypoint_map, rest).keypoints[0];
  const at::Tensor pelvis = body.rest_pelvis(p.betas, rest.expression)[0];
  const at::Tensor candidates = candidate_orientations(options);
  const at::Tensor turned = (rest_keypoints - pelvis).matmul(candidates.transpose(1, 2)) + pelvis;  // (C, 133, 3)

  // Per frame and candidate, the translation t minimising the algebraic error of x + t projecting onto the
  // detection: rows [1, 0, -u'] t = u' z - x and [0, 1, -v'] t = v' z - y with u' = (u - cx) / fx.
  const at::Tensor w = observed.confidence * torso_and_head_mask(options);  // (B, 133)
  const at::Tensor f = observed.intrinsics.narrow(1, 0, 2).unsqueeze(1),
                   c = observed.intrinsics.narrow(1, 2, 2).unsqueeze(1);
  const at::Tensor ray = (observed.pixels - c) / f;  // (B, 133, 2)
  const at::Tensor u = ray.select(2, 0), v = ray.select(2, 1);
  const at::Tensor sw = w.sum(1), su = (w * u).sum(1), sv = (w * v).sum(1), suv = (w * (u * u + v * v)).sum(1);
  const at::Tensor zero = at::zeros_like(sw);
  const at::Tensor normal =
      at::stack({at::stack({sw, zero, -su}, 1), at::stack({zero, sw, -sv}, 1), at::stack({-su, -sv, suv}, 1)}, 1) +
      kFitInitialRidge * at::eye(3, options);                                                  // (B, 3, 3)
  const at::Tensor x = turned.select(2, 0), y = turned.select(2, 1), z = turned.select(2, 2);  // (C, 133)
  const auto weighted = [&](const at::Tensor& a, const at::Tensor& b) { return at::einsum("bk,ck->bc", {a, b}); };
  const at::Tensor rx = weighted(w * u, z) - weighted(w, x);  // sum w (u z - x)
  const at::Tensor ry = weighted(w * v, z) - weighted(w, y);
  const at::Tensor rz = -(weighted(w * u * u, z) - weighted(w * u, x)) - (weighted(w * v * v, z) - weighted(w * v, y));
  const at::Tensor rhs = at::stack({rx, ry, rz}, 2);                                          // (B, C, 3)
  const at::Tensor t = at::linalg_solve(normal.unsqueeze(1), rhs.unsqueeze(-1)).squeeze(-1);  // (B, C, 3)

  // The candidate whose placed rest body reprojects best.
  const int64_t count = candidates.size(0);
  const at::Tensor placed = turned.unsqueeze(0) + t.unsqueeze(2);  // (B, C, 133, 3)
  const at::Tensor intrinsics = observed.intrinsics.repeat_interleave(count, 0);
  const at::Tensor pixels = project(placed.flatten(0, 1), intrinsics).view({batch, count, -1, 2});
  at::Tensor error = ((pixels - observed.pixels.unsqueeze(1)).square().sum(-1) * w.unsqueeze(1)).sum(-1);
  error = at::where(t.select(2, 2) > kFitMinInitialDepth, error, at::full_like(error, INFINITY));
  const at::Tensor best = error.argmin(1);
  p.root_start = candidates.index_select(0, best);
  p.translation = t.gather(1, best.view({batch, 1, 1}).expand({batch, 1, 3})).squeeze(1);

  // A frame with too few torso or head detections keeps the frontal orientation at the depth its size suggests.
  const at::Tensor unplaced = ((w > 0).sum(1) < kFitMinInitialKeypoints) | ~std::get<0>(error.min(1)).isfinite();
  const at::Tensor depth = observed.intrinsics.select(1, 0) * kFitAssumedBodyHeight / observed.person_size;
  const at::Tensor fallback = at::stack({zero, zero, depth}, 1);
  p.translation = at::where(unplaced.unsqueeze(1), fallback, p.translation);
  p.root_start = at::where(unplaced.view({batch, 1, 1}), candidates[0].expand({batch, 3, 3}), p.root_start);
  return p;
}

}  // namespace sfgs::fit
