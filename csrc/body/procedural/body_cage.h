#pragma once
// The procedural body's cage and what the model needs besides it: the vertex sets each joint is regressed from
// and the landmarks the expression directions centre on. build_cage() assembles the parts, each built in its own
// file: trunk_and_head.cpp, legs.cpp, arms_and_hands.cpp.
#include <array>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "body/procedural/cage.h"
#include "body/procedural/vec3.h"
#include "body/skeleton.h"

namespace sfgs::body::procedural {

// Heights above the floor of the arms' axis and of the mouth slit, and the head's centre (height and depth).
inline constexpr double kArmHeight = 1.405;
inline constexpr double kMouthHeight = 1.547;
inline constexpr double kHeadCentreHeight = 1.64;
inline constexpr double kHeadCentreZ = 0.012;

// Vertices of the trunk, neck and head rings: the front (slot 0) and back (slot 8) lie on x = 0, slots 1..7 run
// down the left side from front to back, slot 16 - s mirrors slot s.
inline constexpr size_t kRingSize = 16;
inline constexpr size_t kRingBack = 8;
inline size_t mirrored_slot(size_t slot) { return (kRingSize - slot) % kRingSize; }
inline size_t slot_on(int side, size_t left_slot) { return side > 0 ? left_slot : mirrored_slot(left_slot); }

// The cage vertex sets whose centroids define each joint (the rows of the joint regressor).
using RegressorSets = std::array<std::vector<int64_t>, kSmplxJointCount>;

struct CageBuild {
  Cage cage;
  RegressorSets regressor;
  std::vector<int64_t> mouth_corners, brows, cheeks;  // left, right cage vertices for the expression directions
  int64_t upper_lip = -1;
  Vec3 head_centre;
};

// The whole cage: trunk, neck and head with the mouth, then both legs and both arms with their hands.
CageBuild build_cage();

// The trunk and neck rings from the hips up (the middle shoulder ring has the arm holes); returns them bottom up.
std::vector<std::vector<int64_t>> build_trunk(CageBuild& b, int64_t chart);
// The head on top of the neck ring, with the mouth opening into a mouth bag.
void build_head(CageBuild& b, const std::vector<int64_t>& neck, int64_t head_chart, int64_t top_chart,
                int64_t mouth_chart);
// A leg from the trunk's bottom ring on `side` and the crotch vertex, with its foot.
void build_leg(CageBuild& b, int side, const std::vector<int64_t>& bottom, int64_t crotch);
// An arm from the hole in the trunk's shoulder rings, with the palm, four fingers and the thumb.
void build_arm(CageBuild& b, int side, const std::vector<std::vector<int64_t>>& trunk);

}  // namespace sfgs::body::procedural
