#include "body/procedural/body_cage.h"

namespace sfgs::body::procedural {

CageBuild build_cage() {
  CageBuild b;
  Cage& cage = b.cage;
  const int64_t trunk_chart = cage.chart(1, {true, {0, 0, 0}, {0, 1, 0}, {0, 0, 1}, {1, 0, 0}});
  const int64_t head_chart =
      cage.chart(1, {true, at_height(0, kHeadCentreHeight, kHeadCentreZ), {0, 1, 0}, {0, 0, 1}, {1, 0, 0}});
  const int64_t top_chart = cage.chart(1, {false, {0, 0, kHeadCentreZ}, {0, 0, 0}, {1, 0, 0}, {0, 0, -1}});
  const int64_t mouth_chart = cage.chart(1, {false, at_height(0, kMouthHeight, 0), {0, 0, 0}, {1, 0, 0}, {0, 1, 0}});
  const auto trunk = build_trunk(b, trunk_chart);
  build_head(b, trunk.back(), head_chart, top_chart, mouth_chart);
  const int64_t crotch =
      cage.add_midline(at_height(0, 0.78, 0.0), {{J::kPelvis, 0.6}, {J::kLeftHip, 0.2}, {J::kRightHip, 0.2}});
  for (int side : {1, -1}) {
    build_leg(b, side, trunk.front(), crotch);
    build_arm(b, side, trunk);
  }
  return b;
}

}  // namespace sfgs::body::procedural
