#pragma once
// Shared fixtures of the avatar tests: small avatars on the procedural body, deterministic poses, parameter
// randomisation (the output layers start at zero, so an untouched avatar hides most of its network) and copying
// parameters between avatars of different switches.
#include <cstdint>

#include <ATen/core/Tensor.h>

#include "body/smplx_pose.h"
#include "model/avatar.h"

namespace sfgs::testing {

// The procedural body as an AvatarBody, built once per process.
const model::AvatarBody& procedural_avatar_body();
// (10) betas of a plausible subject.
at::Tensor subject_betas();

// A config small enough for tests: no subdivision, 4-channel 16^2 planes, 16-wide MLPs.
model::AvatarConfig small_config();

// The normalised time the avatar tests render at unless a test is about time.
inline constexpr double kTestTime = 0.25;

// A deterministic pose: every joint rotated by up to `angle` radians, an expression, a translation; hand poses
// only when `hands`.
body::SmplxPose test_pose(int64_t seed, double angle, bool hands);

// Every parameter replaced by N(0, std^2) noise from a generator seeded with `seed` (the shared light plus 1 in its
// constant term).
void randomise_parameters(model::AvatarImpl& avatar, double std, int64_t seed);
// Every parameter of `to` set to the parameter of the same name in `from` (which must have it).
void copy_parameters(const model::AvatarImpl& from, model::AvatarImpl& to);

double max_abs_difference(const at::Tensor& a, const at::Tensor& b);

}  // namespace sfgs::testing
