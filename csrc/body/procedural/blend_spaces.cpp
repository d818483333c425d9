#include "body/procedural/blend_spaces.h"

#include <utility>
#include <vector>

#include <ATen/Functions.h>
#include <ATen/TensorOperators.h>

#include "body/skeleton.h"
#include "body/constants.h"

namespace sfgs::body::procedural {
namespace {

at::Tensor gaussian(const at::Tensor& p, const at::Tensor& centre, double sigma) {
  return (-(p - centre).pow(2).sum(1, /*keepdim=*/true) / (2 * sigma * sigma)).exp();
}

// The summed weight of `joints` per vertex, (V, 1).
at::Tensor column_sum(const at::Tensor& weights, const std::vector<int64_t>& joints) {
  return weights.index_select(1, at::tensor(joints, at::kLong)).sum(1, /*keepdim=*/true);
}

at::Tensor vec(double x, double y, double z) { return at::tensor(std::vector<double>{x, y, z}, at::kDouble); }

// Shape column 1, girth: each vertex pushed away from the bones it is skinned to, in proportion to its weights.
// A joint's bone runs to its child; joints without one (head, jaw, eyes) push away from the joint itself.
at::Tensor girth_direction(const at::Tensor& p, const at::Tensor& w, const at::Tensor& joints) {
  std::vector<int64_t> child(kSmplxJointCount, -1);
  for (int64_t j = 1; j < kSmplxJointCount; ++j)
    if (child[kSmplxParents[j]] < 0) child[kSmplxParents[j]] = j;
  child[J::kPelvis] = J::kSpine1;  // not a hip: the trunk's bone is vertical, and symmetric
  child[J::kSpine3] = J::kNeck;
  child[J::kLeftWrist] = J::kLeftHandFirst + 3;  // middle1
  child[J::kRightWrist] = J::kRightHandFirst + 3;
  child[J::kHead] = child[J::kJaw] = child[J::kLeftEye] = child[J::kRightEye] = -1;
  // Relative girth added per unit, by body region: trunk 12 %, legs 10 %, arms 8 %.
  std::vector<double> girth(kSmplxJointCount, 0.02);
  for (int64_t j : {J::kPelvis, J::kSpine1, J::kSpine2, J::kSpine3}) girth[j] = 0.12;
  for (int64_t j : {J::kLeftHip, J::kRightHip, J::kLeftKnee, J::kRightKnee}) girth[j] = 0.10;
  for (int64_t j :
       {J::kLeftCollar, J::kRightCollar, J::kLeftShoulder, J::kRightShoulder, J::kLeftElbow, J::kRightElbow})
    girth[j] = 0.08;
  for (int64_t j : {J::kLeftAnkle, J::kRightAnkle, J::kLeftFoot, J::kRightFoot, J::kNeck}) girth[j] = 0.05;
  for (int64_t j : {J::kHead, J::kJaw}) girth[j] = 0.03;
  girth[J::kLeftEye] = girth[J::kRightEye] = 0.0;
  at::Tensor girth_push = at::zeros_like(p);
  for (int64_t j = 0; j < kSmplxJointCount; ++j) {
    const at::Tensor a = joints[j];
    at::Tensor nearest = a.unsqueeze(0).expand_as(p);
    if (child[j] >= 0) {
      const at::Tensor bone = joints[child[j]] - a;
      const at::Tensor t = ((p - a) * bone).sum(1, /*keepdim=*/true).div(bone.dot(bone)).clamp(0, 1);
      nearest = a + t * bone;
    }
    girth_push = girth_push + girth[j] * w.select(1, j).unsqueeze(1) * (p - nearest);
  }
  return girth_push;
}

}  // namespace

at::Tensor shape_directions(const at::Tensor& p, const at::Tensor& w, const at::Tensor& joints) {
  const at::Tensor x = p.select(1, 0).unsqueeze(1), y = p.select(1, 1).unsqueeze(1), z = p.select(1, 2).unsqueeze(1);
  const at::Tensor h = y - kFloorY, zero = at::zeros_like(x);
  const auto on_x = [&](const at::Tensor& d) { return at::cat({d, zero, zero}, 1); };
  const auto on_y = [&](const at::Tensor& d) { return at::cat({zero, d, zero}, 1); };
  const auto on_z = [&](const at::Tensor& d) { return at::cat({zero, zero, d}, 1); };
  const auto smoothstep = [](const at::Tensor& t) { return t * t * (3 - 2 * t); };
  std::vector<at::Tensor> columns;
  columns.push_back(on_y(0.04 * h));                 // 0: height, about +7 cm per unit
  columns.push_back(girth_direction(p, w, joints));  // 1: girth

  const at::Tensor head_group = column_sum(w, {J::kHead, J::kJaw, J::kLeftEye, J::kRightEye});
  const at::Tensor upper = smoothstep(((h - 1.15) / 0.25).clamp(0, 1));
  columns.push_back(on_x(0.03 * (x / 0.04).tanh() * upper * (1 - head_group - column_sum(w, {J::kNeck}))));  // 2
  columns.push_back(on_y(-0.05 * ((0.86 - h) / 0.86).clamp_min(0)));                                         // 3: legs
  columns.push_back(on_x(0.04 * x.sign() * ((x.abs() - 0.2) / 0.5).clamp_min(0)));                           // 4: arms
  columns.push_back(0.08 * head_group * (p - joints[J::kHead]));                                             // 5: head
  at::Tensor hands = at::zeros_like(p), fingers = at::zeros_like(p);
  for (Side side : {Side::kLeft, Side::kRight}) {
    std::vector<int64_t> hand, digits;
    for (int64_t k = 0; k < kManoJointCount; ++k) hand.push_back(smplx_hand_joint(side, k));
    digits.assign(hand.begin() + 1, hand.end());
    const at::Tensor wrist = joints[smplx_hand_joint(side, 0)];
    hands = hands + 0.10 * column_sum(w, hand) * (p - wrist);
    fingers = fingers + on_x(0.12 * column_sum(w, digits) * (x - wrist[0]));
  }
  columns.push_back(hands);    // 6: hand size
  columns.push_back(fingers);  // 7: finger length
  const at::Tensor front = (z / 0.1).clamp(0, 1);
  columns.push_back(on_z(0.035 * (-((h - 1.05) / 0.09).pow(2)).exp() * (-(x / 0.11).pow(2)).exp() * front));  // 8
  columns.push_back(on_z(0.025 * (-((h - 1.25) / 0.07).pow(2)).exp() * (-(x / 0.13).pow(2)).exp() * front));  // 9
  return at::stack(columns, 2);
}

at::Tensor expression_directions(const at::Tensor& p, const at::Tensor& w, const CageBuild& b) {
  // Fades from nothing where head and jaw hold half the weight to everything where they hold all of it.
  const at::Tensor t = ((column_sum(w, {J::kHead, J::kJaw}) - 0.5) / 0.5).clamp(0, 1);
  const at::Tensor face = t * t * (3 - 2 * t);
  const at::Tensor jaw = column_sum(w, {J::kJaw});
  const auto at_vertex = [&](int64_t i) { return p[i]; };
  const at::Tensor mouth = vec(0.0, kMouthHeight + kFloorY, p[b.upper_lip][2].item<double>());
  const at::Tensor head = vec(b.head_centre[0], b.head_centre[1], b.head_centre[2]);
  std::array<at::Tensor, 2> smile, pucker, puff, frown, brows;
  for (int s = 0; s < 2; ++s) {
    const double out = s == 0 ? 1.0 : -1.0;  // towards the side of the corner
    const at::Tensor corner = at_vertex(b.mouth_corners[s]);
    smile[s] = 0.006 * vec(0.5 * out, 1.0, -0.5) * gaussian(p, corner, 0.012);
    pucker[s] = 0.004 * vec(-out, 0.0, 0.3) * gaussian(p, corner, 0.010);
    frown[s] = 0.005 * vec(0.0, -1.0, 0.0) * gaussian(p, corner, 0.012);
    brows[s] = 0.006 * vec(0.0, 1.0, 0.0) * gaussian(p, at_vertex(b.brows[s]), 0.015);
    at::Tensor radial = p - head;
    radial.select(1, 1).zero_();
    puff[s] = 0.006 * radial / radial.norm(2, 1, /*keepdim=*/true).clamp_min(kMinCheekPuffRadialLength) *
              gaussian(p, at_vertex(b.cheeks[s]), 0.018);
  }
  const std::vector<at::Tensor> columns = {
      face * jaw * vec(0.0, -0.010, -0.002),                                                    // 0: mouth open
      face * (smile[0] + smile[1]),                                                             // 1: smile
      face * smile[0],                                                                          // 2: left smile
      face * smile[1],                                                                          // 3: right smile
      face * (brows[0] + brows[1]),                                                             // 4: brows up
      face * (0.006 * vec(0.0, 0.0, 1.0) * gaussian(p, mouth, 0.014) + pucker[0] + pucker[1]),  // 5: pucker
      face * (puff[0] + puff[1]),                                                               // 6: cheeks puffed
      face * (frown[0] + frown[1]),                                                             // 7: frown
      face * brows[0],                                                                          // 8: left brow up
      face * brows[1]};                                                                         // 9: right brow up
  return at::stack(columns, 2);
}

// Curl, spread and thumb opposition seed the left hand's basis, completed by Gram-Schmidt over the identity; the
// right hand's is its mirror image (x, -y, -z per joint).
HandPoseSpace hand_pose_space() {
  std::vector<std::vector<double>> seeds(3, std::vector<double>(kHandPoseSize, 0.0));
  const Vec3 thumb_flexion = normalized(Vec3{0.83, 0.0, -0.5});
  for (int64_t j = 0; j < kHandJointCount; ++j) {
    const bool thumb = j >= 12;
    const Vec3 curl = thumb ? thumb_flexion : Vec3{0, 0, -1};
    for (int k = 0; k < 3; ++k) seeds[0][3 * j + k] = curl[k];
  }
  for (const auto& [j, amount] : std::vector<std::pair<int64_t, double>>{{0, -1.0}, {3, -0.3}, {6, 1.0}, {9, 0.3}})
    seeds[1][3 * j + 1] = amount;
  for (const auto& [j, axis] : std::vector<std::pair<int64_t, Vec3>>{{12, {0.4, 0.6, 0.0}}, {13, {0.3, 0.0, -0.3}}})
    for (int k = 0; k < 3; ++k) seeds[2][3 * j + k] = axis[k];
  std::vector<at::Tensor> rows;
  const auto add = [&](at::Tensor r) {
    for (const at::Tensor& q : rows) r = r - (r * q).sum() * q;
    const double n = r.norm().item<double>();
    if (n > kMinHandPoseBasisNorm && static_cast<int64_t>(rows.size()) < kHandPoseSize) rows.push_back(r / n);
  };
  for (const auto& s : seeds) add(at::tensor(s, at::kDouble));
  const at::Tensor identity = at::eye(kHandPoseSize, at::kDouble);
  for (int64_t i = 0; i < kHandPoseSize; ++i) add(identity[i]);
  const at::Tensor left_components = at::stack(rows);
  // A relaxed hand: every finger joint curled a little.
  const at::Tensor left_mean = 0.15 * at::tensor(seeds[0], at::kDouble);
  const at::Tensor flip = at::tensor(std::vector<double>{1, -1, -1}, at::kDouble).repeat({kHandJointCount});
  return {left_components, left_components * flip, left_mean, left_mean * flip};
}

}  // namespace sfgs::body::procedural
