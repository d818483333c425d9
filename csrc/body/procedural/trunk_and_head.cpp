// The body's centre line: trunk and neck rings from the hips up, the head on top, and the mouth bag behind the
// lips. Every ring is symmetric: its left slots are computed and mirrored.
#include <algorithm>
#include <array>
#include <cmath>
#include <functional>
#include <vector>

#include "body/procedural/body_cage.h"

namespace sfgs::body::procedural {
namespace {

// Angles (degrees, 90 = front, -90 = back) of the left slots 0..8 of the trunk and head rings.
constexpr std::array<double, 9> kTrunkAngles = {90, 62, 35, 15, 0, -15, -35, -62, -90};
constexpr std::array<double, 9> kHeadAngles = {90, 73, 50, 25, 0, -25, -50, -73, -90};

// The outline of a ring: heights of its front and back, half width, depths in front of and behind its centre.
struct RingShape {
  double h_front, h_back, half_width, depth_front, depth_back, z_centre;
};

Vec3 ring_point(const RingShape& r, double angle_degrees) {
  const double s = std::sin(radians(angle_degrees)), c = std::cos(radians(angle_degrees));
  const double front = std::pow(0.5 * (1.0 + s), 2.0);
  const double h = r.h_back + (r.h_front - r.h_back) * front;
  return at_height(std::abs(angle_degrees) == 90.0 ? 0.0 : r.half_width * c, h,
                   r.z_centre + (s > 0 ? r.depth_front : r.depth_back) * s);
}

// A symmetric ring; `left_point(slot)` and `left_weights(slot, point)` describe slots 0..8 on the left side,
// `missing` lists left slots (1..7) left out on both sides.
std::vector<int64_t> symmetric_ring(Cage& cage, const std::function<Vec3(size_t)>& left_point,
                                    const std::function<JointWeights(size_t, const Vec3&)>& left_weights,
                                    const std::vector<size_t>& missing = {}) {
  std::vector<int64_t> ring(kRingSize, -1);
  for (size_t slot = 0; slot <= kRingBack; ++slot) {
    if (std::find(missing.begin(), missing.end(), slot) != missing.end()) continue;
    const Vec3 p = left_point(slot);
    const JointWeights w = left_weights(slot, p);
    if (slot == 0 || slot == kRingBack) {
      ring[slot] = cage.add_midline(p, w);
    } else {
      ring[slot] = cage.add(1, p, w);
      ring[mirrored_slot(slot)] = cage.add(-1, p, w);
    }
  }
  return ring;
}

// Linear ramp from 0 at `from` to 1 at `to`, clamped.
double ramp(double x, double from, double to) { return std::clamp((x - from) / (to - from), 0.0, 1.0); }

// Trunk weights blend from the midline joints to the side joints between these distances from x = 0 (metres).
constexpr double kTrunkSideBlendStart = 0.07;
constexpr double kTrunkSideBlendEnd = 0.16;

struct TrunkRing {
  RingShape shape;
  std::function<JointWeights(double lateral)> weights;  // lateral: 0 at the midline .. 1 at the side
};

// The trunk and neck from the hips up; ring 6 is the middle shoulder ring, ring 8 the neck, ring 9 the skull base.
std::vector<TrunkRing> trunk_rings() {
  using W = JointWeights;
  return {
      {{0.80, 0.80, 0.158, 0.092, 0.105, 0.0},
       [](double l) {
         return W{{J::kPelvis, 1 - 0.45 * l}, {J::kLeftHip, 0.45 * l}};
       }},
      {{0.90, 0.90, 0.168, 0.100, 0.112, -0.005},
       [](double) {
         return W{{J::kPelvis, 1}};
       }},
      {{1.00, 1.00, 0.143, 0.092, 0.092, 0.0},
       [](double) {
         return W{{J::kPelvis, 0.35}, {J::kSpine1, 0.65}};
       }},
      {{1.11, 1.11, 0.150, 0.102, 0.094, 0.005},
       [](double) {
         return W{{J::kSpine1, 0.45}, {J::kSpine2, 0.55}};
       }},
      {{1.23, 1.23, 0.163, 0.112, 0.098, 0.010},
       [](double) {
         return W{{J::kSpine2, 0.45}, {J::kSpine3, 0.55}};
       }},
      {{1.335, 1.335, 0.172, 0.104, 0.094, 0.0},
       [](double l) {
         return W{{J::kSpine3, 1 - 0.35 * l}, {J::kLeftCollar, 0.35 * l}};
       }},
      {{kArmHeight, kArmHeight, 0.184, 0.090, 0.086, 0.0},
       [](double l) {
         return W{{J::kSpine3, 1 - 0.6 * l}, {J::kLeftCollar, 0.6 * l}};
       }},
      {{1.468, 1.468, 0.168, 0.074, 0.074, 0.0},
       [](double l) {
         return W{{J::kSpine3, 0.6 - 0.35 * l}, {J::kNeck, 0.4 * (1 - l)}, {J::kLeftCollar, 0.75 * l}};
       }},
      {{1.497, 1.497, 0.066, 0.058, 0.058, -0.005},
       [](double) {
         return W{{J::kSpine3, 0.25}, {J::kNeck, 0.75}};
       }},
      {{1.550, 1.550, 0.055, 0.055, 0.057, -0.010},
       [](double) {
         return W{{J::kNeck, 0.5}, {J::kHead, 0.5}};
       }},
  };
}

// The head rings from the chin to the crown: ring 1 is the lower lip, ring 2 the mouth corners, ring 3 the upper
// lip and cheeks, ring 4 the nose tip, ring 5 the eyes, ring 6 the brows.
constexpr std::array<RingShape, 10> kHeadRings = {{{1.507, 1.585, 0.060, 0.066, 0.060, kHeadCentreZ},
                                                   {1.541, 1.600, 0.067, 0.082, 0.076, kHeadCentreZ},
                                                   {1.547, 1.615, 0.071, 0.078, 0.085, kHeadCentreZ},
                                                   {1.553, 1.630, 0.074, 0.088, 0.090, kHeadCentreZ},
                                                   {1.588, 1.650, 0.076, 0.093, 0.095, kHeadCentreZ},
                                                   {1.627, 1.670, 0.078, 0.087, 0.098, kHeadCentreZ},
                                                   {1.660, 1.695, 0.078, 0.093, 0.098, kHeadCentreZ},
                                                   {1.703, 1.725, 0.073, 0.087, 0.092, kHeadCentreZ},
                                                   {1.738, 1.750, 0.055, 0.063, 0.068, kHeadCentreZ},
                                                   {1.758, 1.762, 0.026, 0.030, 0.032, kHeadCentreZ}}};
// How far the lips' middle stands in front of the head's centre.
constexpr double kLipDepth = kHeadCentreZ + 0.086;

// Left slot `slot` of head ring `r`: the ring's outline, moved where the face has features.
Vec3 head_point(size_t r, size_t slot) {
  Vec3 p = ring_point(kHeadRings[r], kHeadAngles[slot]);
  const double y_mouth = kMouthHeight + kFloorY;
  if ((r == 1 || r == 3) && slot <= 1) {  // lips: a closed slit
    const double sign = r == 1 ? -1.0 : 1.0;
    p[1] = y_mouth + sign * (slot == 0 ? 0.002 : 0.001);
    p[2] = slot == 0 ? kLipDepth : kHeadCentreZ + 0.079;
  }
  if (r == 2 && slot == 1) p = {0.024, y_mouth, kHeadCentreZ + 0.074};  // mouth corner
  if (r == 4 && slot == 0) p[2] += 0.028;                               // nose tip
  if (r == 4 && slot == 1) p[2] += 0.006;
  if (r == 5 && slot == 0) p[2] += 0.010;                 // bridge of the nose
  if (r == 5 && (slot == 1 || slot == 2)) p[2] -= 0.012;  // eye sockets
  if ((r == 4 || r == 5) && slot == 4) p[0] += 0.012;     // ears
  return p;
}

JointWeights head_weights(size_t r, size_t slot) {
  // Jaw share per left slot of the chin ring, lower lip ring and mouth-corner ring; the rest follows the head.
  static const std::array<std::array<double, 9>, 3> jaw_share = {{{1.0, 0.9, 0.7, 0.4, 0.15, 0, 0, 0, 0},
                                                                  {1.0, 0.9, 0.5, 0.2, 0.05, 0, 0, 0, 0},
                                                                  {0.0, 0.5, 0.25, 0.1, 0, 0, 0, 0, 0}}};
  const double jaw = r < 3 ? jaw_share[r][slot] : 0.0;
  if (r == 0 && slot >= 5) return {{J::kHead, 0.7}, {J::kNeck, 0.3}};
  return {{J::kHead, 1 - jaw}, {J::kJaw, jaw}};
}

// The mouth: the hole's rim leads into a bag, upper half on the head, lower half on the jaw.
void build_mouth_bag(CageBuild& b, const std::vector<std::vector<int64_t>>& rings, int64_t mouth_chart) {
  using W = JointWeights;
  const std::vector<int64_t> rim = {rings[3][15], rings[3][0], rings[3][1],  rings[2][1],
                                    rings[1][1],  rings[1][0], rings[1][15], rings[2][15]};
  std::vector<int64_t> previous = rim;
  const double y_mouth = kMouthHeight + kFloorY;
  for (const auto& [half_width, half_height, depth] :
       {std::array<double, 3>{0.019, 0.001, kLipDepth - 0.010}, {0.016, 0.011, kLipDepth - 0.036}}) {
    const W upper = {{J::kHead, 1}}, lower = {{J::kJaw, 1}}, corner = {{J::kHead, 0.5}, {J::kJaw, 0.5}};
    const double side = 0.6 * half_width;
    std::vector<int64_t> loop(8);
    loop[1] = b.cage.add_midline({0, y_mouth + half_height, depth}, upper);
    loop[5] = b.cage.add_midline({0, y_mouth - half_height, depth}, lower);
    for (int s : {1, -1}) {
      loop[s > 0 ? 2 : 0] = b.cage.add(s, {side, y_mouth + 0.9 * half_height, depth}, upper);
      loop[s > 0 ? 3 : 7] = b.cage.add(s, {half_width, y_mouth, depth + 0.002}, corner);
      loop[s > 0 ? 4 : 6] = b.cage.add(s, {side, y_mouth - 0.9 * half_height, depth}, lower);
    }
    b.cage.bridge(previous, loop, mouth_chart);
    previous = loop;
  }
  b.cage.face(previous, mouth_chart);
}

}  // namespace

std::vector<std::vector<int64_t>> build_trunk(CageBuild& b, int64_t chart) {
  const std::vector<TrunkRing> rings = trunk_rings();
  std::vector<std::vector<int64_t>> built;
  for (size_t r = 0; r < rings.size(); ++r) {
    // The middle shoulder ring leaves out three side vertices: the arm holes.
    const std::vector<size_t> missing = r == 6 ? std::vector<size_t>{3, 4, 5} : std::vector<size_t>{};
    built.push_back(symmetric_ring(
        b.cage, [&](size_t slot) { return ring_point(rings[r].shape, kTrunkAngles[slot]); },
        [&](size_t, const Vec3& p) { return rings[r].weights(ramp(p[0], kTrunkSideBlendStart, kTrunkSideBlendEnd)); },
        missing));
    if (r > 0) b.cage.bridge(built[r - 1], built[r], chart);
  }
  b.regressor[J::kPelvis] = built[1];
  b.regressor[J::kSpine1] = built[2];
  b.regressor[J::kSpine2] = built[3];
  b.regressor[J::kSpine3] = built[4];
  b.regressor[J::kNeck] = built[8];
  b.regressor[J::kHead] = built[9];
  for (int side : {1, -1}) {
    b.regressor[joint(side, J::kLeftCollar)] = {built[7][slot_on(side, 1)], built[7][slot_on(side, 7)],
                                                built[8][slot_on(side, 4)]};
  }
  return built;
}

void build_head(CageBuild& b, const std::vector<int64_t>& neck, int64_t head_chart, int64_t top_chart,
                int64_t mouth_chart) {
  std::vector<std::vector<int64_t>> rings;
  for (size_t r = 0; r < kHeadRings.size(); ++r) {
    // The mouth-corner ring has no front vertex: the mouth opens there.
    const std::vector<size_t> missing = r == 2 ? std::vector<size_t>{0} : std::vector<size_t>{};
    rings.push_back(symmetric_ring(
        b.cage, [&](size_t slot) { return head_point(r, slot); },
        [&](size_t slot, const Vec3&) { return head_weights(r, slot); }, missing));
    b.cage.bridge(r == 0 ? neck : rings[r - 1], rings[r], head_chart);
  }
  b.cage.face(rings.back(), top_chart);
  b.regressor[J::kJaw] = {rings[2][4], rings[2][mirrored_slot(4)]};
  b.mouth_corners = {rings[2][1], rings[2][mirrored_slot(1)]};
  b.brows = {rings[6][2], rings[6][mirrored_slot(2)]};
  b.cheeks = {rings[3][3], rings[3][mirrored_slot(3)]};
  b.upper_lip = rings[3][0];
  b.head_centre = at_height(0.0, kHeadCentreHeight, kHeadCentreZ);
  build_mouth_bag(b, rings, mouth_chart);
}

}  // namespace sfgs::body::procedural
