#pragma once
// When a frame happens, as the avatar's time branch (the hexplane) sees it.
#include <optional>

namespace sfgs::model {

// The frame's time on the hexplane's axis, normalised to [-1, 1] over the training frames; or none (std::nullopt):
// a pose of a new motion, or a moment the training video did not cover. Without a time the time branch is left
// out, which training prepares the avatar for (AvatarConfig::time_dropout); docs/avatar.md, "Time".
using FrameTime = std::optional<double>;

}  // namespace sfgs::model
