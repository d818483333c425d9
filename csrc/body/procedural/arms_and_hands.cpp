// An arm: elliptic rings from the hole in the trunk's shoulder rings to the wrist, a flat palm, four fingers
// from the knuckles and a thumb from the palm's front side. Fingers and thumb are tubes of rings along their
// direction, capped at the tip.
#include <array>
#include <cmath>
#include <utility>
#include <vector>

#include "body/procedural/body_cage.h"

namespace sfgs::body::procedural {
namespace {

// Finger f of the left hand in SMPL-X order (0 index, 1 middle, 2 pinky, 3 ring, 4 thumb), segment k = 0..2.
int64_t left_finger(int64_t f, int64_t k) { return J::kLeftHandFirst + 3 * f + k; }
constexpr int64_t kIndex = 0, kMiddle = 1, kPinky = 2, kRing = 3, kThumb = 4;

// Fingers splay at most 8 degrees from +x (cos > 0.99), the thumb leaves at about 60 degrees from it (cos 0.5): a
// digit whose direction has an x component above this is built as a finger.
constexpr double kFingerMinAlongX = 0.9;

// The palm's three rings, from the wrist to the knuckles.
struct Palm {
  std::vector<int64_t> wrist_side, thumb_base, knuckles;
};

// A finger (or thumb) tube from `base` (its loop on the palm) along `direction`; ring k sits at distance
// stations[k] with half width widths[k] and weights segment_weights[k]. The last ring is capped.
void build_digit(CageBuild& b, int side, const std::vector<int64_t>& base, const Vec3& direction,
                 const std::vector<std::array<double, 2>>& profile, const std::vector<double>& stations,
                 const std::vector<double>& widths, const std::vector<JointWeights>& segment_weights,
                 const std::vector<size_t>& joint_rings, const std::vector<int64_t>& joints) {
  Cage& cage = b.cage;
  const Vec3 origin = left_centroid(cage, side, base);
  const Vec3 d = normalized(direction);
  const Vec3 along = normalized(Vec3{1, 0, 0} - dot(Vec3{1, 0, 0}, d) * d);
  const Vec3 up_raw = Vec3{0, 1, 0} - dot(Vec3{0, 1, 0}, d) * d;
  const Vec3 up = normalized(up_raw - dot(up_raw, along) * along);
  // For fingers (direction ~ x) the in-plane side axis is horizontal; for the thumb the "along" axis is.
  const bool finger = std::abs(d[0]) > kFingerMinAlongX;
  const Vec3 ea = finger ? normalized(cross(d, up)) : along;
  const int64_t chart = cage.chart(side, {true, origin, d, finger ? Vec3{0, 1, 0} : up, ea});
  const int64_t tip_chart = cage.chart(side, {false, origin + stations.back() * d, {0, 0, 0}, ea, up});
  std::vector<int64_t> previous = base;
  std::vector<std::vector<int64_t>> rings;
  for (size_t k = 0; k < stations.size(); ++k) {
    std::vector<std::array<double, 2>> offsets;
    // Fingers are a little flatter than wide.
    for (const auto& [a, u] : profile) offsets.push_back({widths[k] * a, 0.92 * widths[k] * u});
    rings.push_back(frame_ring(cage, side, origin + stations[k] * d, ea, up, offsets, segment_weights[k]));
    cage.bridge(previous, rings.back(), chart);
    previous = rings.back();
  }
  cage.face(previous, tip_chart);
  b.regressor[joint(side, joints[0])] = base;
  for (size_t k = 1; k < joints.size(); ++k) b.regressor[joint(side, joints[k])] = rings[joint_rings[k - 1]];
}

// The arm tube from the hole in the trunk to the wrist; returns the wrist ring.
std::vector<int64_t> build_arm_tube(CageBuild& b, int side, const std::vector<std::vector<int64_t>>& trunk) {
  using W = JointWeights;
  Cage& cage = b.cage;
  const int64_t arm_chart = cage.chart(side, {true, at_height(0, kArmHeight, 0), {1, 0, 0}, {0, 1, 0}, {0, 0, 1}});
  // The hole in the trunk: front of the middle ring, the upper ring front to back, back of the middle ring, the
  // lower ring back to front. Slot i of every arm ring sits at angle 30 i around the arm (0 = front, 90 = up).
  const auto& lower = trunk[5];
  const auto& middle = trunk[6];
  const auto& upper = trunk[7];
  std::vector<int64_t> hole = {middle[slot_on(side, 2)]};
  for (size_t s : {2, 3, 4, 5, 6}) hole.push_back(upper[slot_on(side, s)]);
  hole.push_back(middle[slot_on(side, 6)]);
  for (size_t s : {6, 5, 4, 3, 2}) hole.push_back(lower[slot_on(side, s)]);
  b.regressor[joint(side, J::kLeftShoulder)] = hole;

  std::vector<double> angles;
  for (int i = 0; i < 12; ++i) angles.push_back(30.0 * i);
  struct ArmRing {
    double x, ry, rz;
    W w;
  };
  const std::vector<ArmRing> arm = {{0.212, 0.055, 0.058, {{J::kLeftCollar, 0.3}, {J::kLeftShoulder, 0.7}}},
                                    {0.28, 0.048, 0.050, {{J::kLeftShoulder, 1}}},
                                    {0.36, 0.043, 0.045, {{J::kLeftShoulder, 1}}},
                                    {0.45, 0.037, 0.039, {{J::kLeftShoulder, 0.5}, {J::kLeftElbow, 0.5}}},
                                    {0.53, 0.036, 0.040, {{J::kLeftElbow, 1}}},
                                    {0.61, 0.029, 0.033, {{J::kLeftElbow, 1}}},
                                    {0.683, 0.020, 0.028, {{J::kLeftElbow, 0.4}, {J::kLeftWrist, 0.6}}}};
  std::vector<int64_t> previous = hole;
  for (size_t r = 0; r < arm.size(); ++r) {
    const ArmRing& ring = arm[r];
    const std::vector<int64_t> built = frame_ring(cage, side, at_height(ring.x, kArmHeight, 0), {0, 0, 1}, {0, 1, 0},
                                                  ellipse(angles, ring.rz, ring.ry), ring.w);
    cage.bridge(previous, built, arm_chart);
    if (r == 3) b.regressor[joint(side, J::kLeftElbow)] = built;
    if (r == 6) b.regressor[joint(side, J::kLeftWrist)] = built;
    previous = built;
  }
  return previous;
}

// Knuckle weights: half the wrist, the given shares of the fingers' first segments, the rest the wrist again.
JointWeights knuckle(const std::vector<std::pair<int64_t, double>>& fingers) {
  JointWeights w = {{J::kLeftWrist, 0.5}};
  for (const auto& [f, share] : fingers) w.push_back({left_finger(f, 0), share});
  double total = 0;
  for (const auto& entry : w) total += entry.second;
  w[0].second += 1 - total;
  return w;
}

// The palm: a flat box, fingers along +x, thumb towards the front (+z), palm facing down.
Palm build_palm(CageBuild& b, int side, const std::vector<int64_t>& wrist) {
  using W = JointWeights;
  Cage& cage = b.cage;
  const int64_t palm_chart = cage.chart(side, {true, at_height(0, kArmHeight, 0), {1, 0, 0}, {0, 0, 1}, {0, 1, 0}});
  const std::vector<std::array<double, 2>> box = {{1, 0},  {0.8, 1},   {0.4, 1},   {0, 1},  {-0.4, 1}, {-0.8, 1},
                                                  {-1, 0}, {-0.8, -1}, {-0.4, -1}, {0, -1}, {0.4, -1}, {0.8, -1}};
  const auto palm_ring = [&](double x, double ry, double rz, const std::vector<W>& w) {
    std::vector<int64_t> ring;
    for (size_t i = 0; i < box.size(); ++i)
      ring.push_back(cage.add(side, at_height(x, kArmHeight + ry * box[i][1], rz * box[i][0]), w[i]));
    return ring;
  };
  const W wrist_weights = {{J::kLeftWrist, 1}};
  Palm palm;
  palm.wrist_side = palm_ring(0.712, 0.017, 0.038, std::vector<W>(12, wrist_weights));
  palm.thumb_base = palm_ring(0.757, 0.016, 0.044, std::vector<W>(12, wrist_weights));
  palm.knuckles =
      palm_ring(0.800, 0.012, 0.045,
                {knuckle({{kIndex, 0.25}}), knuckle({{kIndex, 0.5}}), knuckle({{kIndex, 0.25}, {kMiddle, 0.25}}),
                 knuckle({{kMiddle, 0.25}, {kRing, 0.25}}), knuckle({{kRing, 0.25}, {kPinky, 0.25}}),
                 knuckle({{kPinky, 0.5}}), knuckle({{kPinky, 0.25}}), knuckle({{kPinky, 0.5}}),
                 knuckle({{kPinky, 0.25}, {kRing, 0.25}}), knuckle({{kRing, 0.25}, {kMiddle, 0.25}}),
                 knuckle({{kMiddle, 0.25}, {kIndex, 0.25}}), knuckle({{kIndex, 0.5}})});
  const std::vector<int64_t>& p1 = palm.wrist_side;
  const std::vector<int64_t>& p2 = palm.thumb_base;
  const std::vector<int64_t>& p3 = palm.knuckles;
  cage.bridge(wrist, p1, palm_chart);
  cage.bridge(p1, p2, palm_chart, {11, 0});  // the thumb leaves from the front faces of this segment
  cage.bridge(p2, p3, palm_chart);
  cage.face({p3[0], p3[1], p3[11]}, palm_chart);
  cage.face({p3[5], p3[6], p3[7]}, palm_chart);
  return palm;
}

// Index, middle, ring and pinky from the four quads between the knuckle ring's top and bottom slots.
void build_fingers(CageBuild& b, int side, const std::vector<int64_t>& knuckles) {
  using W = JointWeights;
  struct Finger {
    int64_t id;
    std::array<size_t, 4> base;  // top-front, top-back, bottom-back, bottom-front slots of the knuckle ring
    double splay_degrees;
    std::array<double, 3> lengths;
    double base_width, tip_width;
  };
  const std::vector<Finger> fingers = {{kIndex, {1, 2, 10, 11}, 5.0, {0.044, 0.026, 0.022}, 0.0088, 0.0072},
                                       {kMiddle, {2, 3, 9, 10}, 1.5, {0.048, 0.029, 0.024}, 0.0090, 0.0074},
                                       {kRing, {3, 4, 8, 9}, -2.5, {0.045, 0.027, 0.022}, 0.0084, 0.0070},
                                       {kPinky, {4, 5, 7, 8}, -8.0, {0.035, 0.021, 0.019}, 0.0072, 0.0060}};
  const std::vector<std::array<double, 2>> square = {{1, 1}, {-1, 1}, {-1, -1}, {1, -1}};
  for (const Finger& f : fingers) {
    const double l1 = f.lengths[0], l2 = f.lengths[1], l3 = f.lengths[2];
    const auto w = [&](int64_t k) { return W{{left_finger(f.id, k), 1}}; };
    const auto half = [&](int64_t k) { return W{{left_finger(f.id, k), 0.5}, {left_finger(f.id, k + 1), 0.5}}; };
    const double mid = 0.5 * (f.base_width + f.tip_width);
    build_digit(b, side, {knuckles[f.base[0]], knuckles[f.base[1]], knuckles[f.base[2]], knuckles[f.base[3]]},
                {std::cos(radians(f.splay_degrees)), 0, std::sin(radians(f.splay_degrees))}, square,
                {0.5 * l1, l1, l1 + l2, l1 + l2 + 0.55 * l3, l1 + l2 + 0.92 * l3},
                {f.base_width, 0.5 * (f.base_width + mid), mid, f.tip_width, 0.7 * f.tip_width},
                {w(0), half(0), half(1), w(2), w(2)}, {1, 2},
                {left_finger(f.id, 0), left_finger(f.id, 1), left_finger(f.id, 2)});
  }
}

// The thumb from the hexagon of the palm's front faces left open between the wrist-side and thumb-base rings,
// pointing forward, out and a little down.
void build_thumb(CageBuild& b, int side, const Palm& palm) {
  using W = JointWeights;
  const std::vector<int64_t>& p1 = palm.wrist_side;
  const std::vector<int64_t>& p2 = palm.thumb_base;
  const auto thumb = [&](int64_t k) { return W{{left_finger(kThumb, k), 1}}; };
  const auto thumb_half = [&](int64_t k) {
    return W{{left_finger(kThumb, k), 0.5}, {left_finger(kThumb, k + 1), 0.5}};
  };
  build_digit(b, side, {p1[1], p2[1], p2[0], p2[11], p1[11], p1[0]}, {0.50, -0.25, 0.83},
              {{-0.7, 1}, {0.7, 1}, {1, 0}, {0.7, -1}, {-0.7, -1}, {-1, 0}}, {0.016, 0.040, 0.070, 0.090, 0.101},
              {0.0115, 0.0105, 0.0095, 0.0085, 0.006}, {thumb(0), thumb_half(0), thumb_half(1), thumb(2), thumb(2)},
              {1, 2}, {left_finger(kThumb, 0), left_finger(kThumb, 1), left_finger(kThumb, 2)});
}

}  // namespace

void build_arm(CageBuild& b, int side, const std::vector<std::vector<int64_t>>& trunk) {
  const std::vector<int64_t> wrist = build_arm_tube(b, side, trunk);
  const Palm palm = build_palm(b, side, wrist);
  build_fingers(b, side, palm.knuckles);
  build_thumb(b, side, palm);
}

}  // namespace sfgs::body::procedural
