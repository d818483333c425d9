// A leg: elliptic rings from the hip down to the heel, with the foot leaving forward from the ankle.
#include <array>
#include <vector>

#include "body/procedural/body_cage.h"

namespace sfgs::body::procedural {
namespace {

// The legs' axis and the feet's centre line, at this distance from x = 0 (metres).
constexpr double kLegAxisX = 0.088;
constexpr double kFootAxisX = 0.092;

struct LegRings {
  std::vector<int64_t> ankle, heel;
};

// The leg tube from the hip loop to the heel ring, whose bottom is the sole. The foot leaves from the front
// of the lowest segment, which is left open there.
LegRings build_leg_tube(CageBuild& b, int side, const std::vector<int64_t>& hip_loop) {
  using W = JointWeights;
  Cage& cage = b.cage;
  const int64_t leg_chart = cage.chart(side, {true, {kLegAxisX, 0, 0}, {0, 1, 0}, {1, 0, 0}, {0, 0, 1}});
  const int64_t sole_chart = cage.chart(side, {false, {kLegAxisX, 0, 0}, {0, 0, 0}, {1, 0, 0}, {0, 0, 1}});
  const std::vector<double> angles = {144, 108, 72, 36, 0, -36, -72, -108, -144, 180};
  struct LegRing {
    double h, rx, rz, z;
    W w;
  };
  const std::vector<LegRing> rings = {{0.735, 0.080, 0.082, 0.0, {{J::kLeftHip, 0.8}, {J::kPelvis, 0.2}}},
                                      {0.62, 0.071, 0.074, 0.0, {{J::kLeftHip, 1}}},
                                      {0.48, 0.052, 0.056, 0.005, {{J::kLeftHip, 0.5}, {J::kLeftKnee, 0.5}}},
                                      {0.375, 0.052, 0.058, -0.005, {{J::kLeftKnee, 1}}},
                                      {0.22, 0.040, 0.044, 0.0, {{J::kLeftKnee, 1}}},
                                      {0.09, 0.033, 0.037, 0.0, {{J::kLeftKnee, 0.4}, {J::kLeftAnkle, 0.6}}},
                                      {0.012, 0.034, 0.046, -0.012, {{J::kLeftAnkle, 1}}}};
  std::vector<int64_t> previous = hip_loop;
  std::vector<std::vector<int64_t>> built;
  for (size_t r = 0; r < rings.size(); ++r) {
    const LegRing& ring = rings[r];
    built.push_back(frame_ring(cage, side, at_height(kLegAxisX, ring.h, ring.z), {1, 0, 0}, {0, 0, 1},
                               ellipse(angles, ring.rx, ring.rz), ring.w));
    // The foot leaves from the front of the lowest segment (intervals 0..2 of the ankle-to-heel bridge).
    cage.bridge(previous, built.back(), leg_chart,
                r == rings.size() - 1 ? std::vector<size_t>{0, 1, 2} : std::vector<size_t>{});
    previous = built.back();
  }
  LegRings out{built[5], built[6]};
  cage.face(out.heel, sole_chart);
  b.regressor[joint(side, J::kLeftKnee)] = built[2];
  b.regressor[joint(side, J::kLeftAnkle)] = out.ankle;
  return out;
}

// The foot: box rings forward from the opening at the front of the ankle, capped at the toes.
void build_foot(CageBuild& b, int side, const LegRings& leg) {
  using W = JointWeights;
  Cage& cage = b.cage;
  const int64_t foot_chart = cage.chart(side, {true, at_height(kFootAxisX, 0.03, 0), {0, 0, 1}, {0, 1, 0}, {1, 0, 0}});
  const int64_t toe_chart = cage.chart(side, {false, {kFootAxisX, 0, 0.2}, {0, 0, 0}, {1, 0, 0}, {0, 1, 0}});
  const std::vector<int64_t>& ankle = leg.ankle;
  const std::vector<int64_t>& heel = leg.heel;
  std::vector<int64_t> foot = {ankle[0], ankle[1], ankle[2], ankle[3], heel[3], heel[2], heel[1], heel[0]};
  struct FootRing {
    double z, half_width, top, bottom;
    W w;
  };
  const std::vector<FootRing> foot_rings = {{0.070, 0.040, 0.070, 0.0, {{J::kLeftAnkle, 1}}},
                                            {0.125, 0.046, 0.042, 0.0, {{J::kLeftAnkle, 0.5}, {J::kLeftFoot, 0.5}}},
                                            {0.175, 0.042, 0.030, 0.002, {{J::kLeftFoot, 1}}},
                                            {0.200, 0.030, 0.022, 0.006, {{J::kLeftFoot, 1}}}};
  for (size_t r = 0; r < foot_rings.size(); ++r) {
    const FootRing& f = foot_rings[r];
    const double dome = 0.15 * f.top;  // the instep rises a little between the foot's edges
    std::vector<int64_t> ring;
    for (const auto& [x, h] : std::vector<std::array<double, 2>>{{-1, f.top},
                                                                 {-1.0 / 3, f.top + dome},
                                                                 {1.0 / 3, f.top + dome},
                                                                 {1, f.top},
                                                                 {1, f.bottom},
                                                                 {1.0 / 3, f.bottom},
                                                                 {-1.0 / 3, f.bottom},
                                                                 {-1, f.bottom}})
      ring.push_back(cage.add(side, at_height(kFootAxisX + x * f.half_width, h, f.z), f.w));
    cage.bridge(foot, ring, foot_chart);
    if (r == 1) b.regressor[joint(side, J::kLeftFoot)] = ring;
    foot = ring;
  }
  cage.face(foot, toe_chart);
}

}  // namespace

void build_leg(CageBuild& b, int side, const std::vector<int64_t>& bottom, int64_t crotch) {
  // The top loop: the trunk's bottom ring from front to back on this side, then the crotch.
  std::vector<int64_t> hip_loop;
  for (size_t slot = 0; slot <= kRingBack; ++slot) hip_loop.push_back(bottom[slot_on(side, slot)]);
  hip_loop.push_back(crotch);
  b.regressor[joint(side, J::kLeftHip)] = hip_loop;
  build_foot(b, side, build_leg_tube(b, side, hip_loop));
}

}  // namespace sfgs::body::procedural
