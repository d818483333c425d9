#include "fit/fit_losses.h"

#include <ATen/ATen.h>

#include <algorithm>

#include "body/skeleton.h"
#include "body/wholebody_keypoints.h"
#include "fit/constants.h"
#include "ops/splat/constants.h"

namespace sfgs::fit {
namespace {

using namespace body::smplx_joint;

// Squared hinge: (max(0, x))^2.
at::Tensor hinge2(const at::Tensor& x) { return x.clamp_min(0).square(); }

}  // namespace

KeypointObservations observe_keypoints(const at::Tensor& keypoints, const at::Tensor& intrinsics) {
  KeypointObservations o;
  o.pixels = keypoints.narrow(2, 0, 2);
  const at::Tensor score = keypoints.select(2, 2);
  o.confidence = at::where(score >= kFitMinKeypointScore, score.clamp_max(1.0), at::zeros_like(score));
  const at::Tensor usable = (o.confidence > 0).unsqueeze(-1);
  const at::Tensor big = at::full_like(o.pixels, 1e30);
  const at::Tensor lo = std::get<0>(at::where(usable, o.pixels, big).min(1));
  const at::Tensor hi = std::get<0>(at::where(usable, o.pixels, -big).max(1));
  const at::Tensor enough = usable.squeeze(-1).sum(1) >= 2;
  const at::Tensor diagonal = at::where(enough.unsqueeze(-1), hi - lo, at::zeros_like(hi)).norm(2, -1);
  o.person_size = diagonal.clamp_min(kFitMinPersonPixels);
  o.intrinsics = intrinsics;
  return o;
}

at::Tensor project(const at::Tensor& points, const at::Tensor& intrinsics) {
  const at::Tensor z = points.select(2, 2).clamp_min(kDefaultNearPlane);
  const at::Tensor f = intrinsics.narrow(1, 0, 2).unsqueeze(1), c = intrinsics.narrow(1, 2, 2).unsqueeze(1);
  return points.narrow(2, 0, 2) / z.unsqueeze(-1) * f + c;
}

at::Tensor geman_mcclure(const at::Tensor& squared, double sigma) {
  const double s2 = sigma * sigma;
  return s2 * squared / (squared + s2);
}

at::Tensor group_weights(const std::map<body::KeypointGroup, double>& weights, const at::TensorOptions& options) {
  at::Tensor w = at::zeros({body::kWholeBodyKeypointCount}, options);
  for (const auto& [group, weight] : weights) {
    const body::KeypointRange r = body::keypoint_range(group);
    w.narrow(0, r.begin, r.size()).fill_(weight);
  }
  return w;
}

at::Tensor whole_body_keypoint_weights(const at::TensorOptions& options) {
  using body::KeypointGroup;
  return group_weights({{KeypointGroup::kBody, 1.0},
                        {KeypointGroup::kFeet, kFitFeetWeight},
                        {KeypointGroup::kFace, kFitFaceWeight},
                        {KeypointGroup::kLeftHand, 1.0},
                        {KeypointGroup::kRightHand, 1.0}},
                       options);
}

at::Tensor reprojection_loss(const at::Tensor& keypoints, const KeypointObservations& observed,
                             const at::Tensor& keypoint_weights, double sigma) {
  const at::Tensor residual =
      (project(keypoints, observed.intrinsics) - observed.pixels) / observed.person_size.view({-1, 1, 1});
  const at::Tensor robust = geman_mcclure(residual.square().sum(-1), sigma);
  return (robust * observed.confidence * keypoint_weights.unsqueeze(0)).sum(1);
}

std::pair<at::Tensor, at::Tensor> body_prior_centre_and_weights(const at::TensorOptions& options) {
  at::Tensor centre = at::zeros({body::kSmplxBodyJointCount, 3}, options);
  at::Tensor weight = at::ones({body::kSmplxBodyJointCount, 3}, options);
  centre[kLeftShoulder - 1][2] = -kFitHangingArmAngle;
  centre[kRightShoulder - 1][2] = kFitHangingArmAngle;
  for (int64_t arm : {kLeftShoulder, kRightShoulder, kLeftElbow, kRightElbow, kLeftWrist, kRightWrist})
    weight[arm - 1][0] = kFitTwistPriorFactor;
  for (int64_t leg : {kLeftHip, kRightHip, kLeftKnee, kRightKnee}) weight[leg - 1][1] = kFitTwistPriorFactor;
  for (int64_t stiff : {kSpine1, kSpine2, kSpine3, kNeck, kLeftCollar, kRightCollar})
    weight[stiff - 1] *= kFitSpinePriorFactor;
  // A twist of the spine shows in the shoulders' width and the face; a lean towards the camera hardly shows.
  for (int64_t spine : {kSpine1, kSpine2, kSpine3}) weight[spine - 1][1] = kFitSpineTwistPriorFactor;
  for (int64_t shoulder : {kLeftShoulder, kRightShoulder}) weight[shoulder - 1] *= kFitShoulderPriorFactor;
  // A leg swinging towards or away from the camera changes its image little: the hips' flexion weighs less.
  for (int64_t hip : {kLeftHip, kRightHip}) weight[hip - 1][0] = kFitHipFlexionPriorFactor;
  weight[kLeftKnee - 1][0] = 0;
  weight[kRightKnee - 1][0] = 0;
  weight[kLeftElbow - 1][1] = 0;
  weight[kRightElbow - 1][1] = 0;
  return {centre, weight};
}

at::Tensor body_pose_prior(const at::Tensor& body_pose) {
  const auto axis = [&](int64_t joint, int64_t a) { return body_pose.select(1, joint - 1).select(1, a); };
  // Knees are hinges that flex about +x; elbows flex about -y (left) and +y (right) with the arms along x.
  at::Tensor limits = at::zeros({body_pose.size(0)}, body_pose.options());
  for (int64_t knee : {kLeftKnee, kRightKnee})
    limits = limits + hinge2(-axis(knee, 0)) + axis(knee, 1).square() + axis(knee, 2).square();
  limits = limits + hinge2(axis(kLeftElbow, 1)) + hinge2(-axis(kRightElbow, 1));
  for (int64_t elbow : {kLeftElbow, kRightElbow}) limits = limits + axis(elbow, 2).square();
  const auto [centre, weight] = body_prior_centre_and_weights(body_pose.options());
  return ((body_pose - centre).square() * weight).sum({1, 2}) + kFitJointLimitWeight * limits;
}

at::Tensor hand_pose_prior(const at::Tensor& left_hand, const at::Tensor& right_hand) {
  // The first 12 hand joints are the four fingers (index, middle, pinky, ring), which curl about -z (left) and +z
  // (right); the thumb's joints turn about other axes and get no hinge.
  constexpr int64_t kFingerJoints = 12;
  const at::Tensor left_curl = left_hand.narrow(1, 0, kFingerJoints).select(2, 2);
  const at::Tensor right_curl = right_hand.narrow(1, 0, kFingerJoints).select(2, 2);
  const at::Tensor limits = hinge2(left_curl).sum(1) + hinge2(-right_curl).sum(1);
  return (left_hand.square().sum({1, 2}) + right_hand.square().sum({1, 2}) + kFitJointLimitWeight * limits).mean();
}

at::Tensor temporal_triples(const std::vector<int64_t>& frame_numbers) {
  std::vector<int64_t> gaps;
  for (size_t i = 1; i < frame_numbers.size(); ++i) gaps.push_back(frame_numbers[i] - frame_numbers[i - 1]);
  std::vector<int64_t> triples;
  if (gaps.size() >= 2) {
    std::vector<int64_t> sorted = gaps;
    std::nth_element(sorted.begin(), sorted.begin() + sorted.size() / 2, sorted.end());
    const int64_t largest = 2 * sorted[sorted.size() / 2];
    for (size_t i = 1; i + 1 < frame_numbers.size(); ++i)
      if (gaps[i - 1] <= largest && gaps[i] <= largest)
        triples.insert(triples.end(), {int64_t(i - 1), int64_t(i), int64_t(i + 1)});
  }
  return at::tensor(triples, at::kLong).view({-1, 3});
}

at::Tensor temporal_loss(const at::Tensor& points, const at::Tensor& triples, double sigma) {
  if (triples.size(0) == 0) return at::zeros({}, points.options());
  const at::Tensor t = triples.to(points.device());
  const at::Tensor acceleration = points.index_select(0, t.select(1, 2)) - 2 * points.index_select(0, t.select(1, 1)) +
                                  points.index_select(0, t.select(1, 0));
  return geman_mcclure(acceleration.square().sum(-1), sigma).sum(1).mean();
}

}  // namespace sfgs::fit
