#pragma once
// The motion library of synthetic videos: named, periodic SMPL-X motions for training an avatar on some and testing
// it on others (the novel-motion benchmark, docs/results.md). Every motion also moves the fingers, jaw, eyes and
// expression, so hands and face are exercised whatever the body does.
#include <cstdint>
#include <string>
#include <vector>

#include "body/smplx_pose.h"

namespace sfgs::data {

// sway: the original synthetic motion (arms swinging low, stepping, twisting, nodding)
// walk: walking in place, arms swinging in opposition
// wave: the right arm raised and waving, weight shifting
// overhead: both arms raised overhead, stretching to the sides
// bend: a deep forward bend from the hips and spine, arms hanging
// guard: a crouched boxing guard, fists up at the chin, bobbing
// turn: turning in place to either side (about 70 degrees), showing the flanks
// sit: squatting down as if to sit and standing up again
const std::vector<std::string>& motion_names();

// Whether `name` is in motion_names().
bool is_motion(const std::string& name);

// Comma-separated motion names ("walk,wave") as a list; an unknown or repeated name is an error naming the choices.
std::vector<std::string> parse_motion_list(const std::string& text, const char* option);

// The SMPL-X parameters of `motion` at `seconds` since its start, for a model with `expression_count` expression
// coefficients (axis-angle hands, relative to a flat hand). Deterministic; unknown motions are errors.
body::SmplxPose motion_pose(const std::string& motion, double seconds, int64_t expression_count);

}  // namespace sfgs::data
