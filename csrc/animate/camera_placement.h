#pragma once
// Where a camera stands to film a posed avatar: the cameras of `sfgs render` and `sfgs export --web` (orbiting the
// subject, fixed in front of it, following it as it moves) and of Python's sfgs.look_at_camera and friends. World +Y
// is up and the body model faces +Z; cameras keep OpenCV axes (image x to the right, y down, z forward).
#include <array>

#include "model/avatar.h"
#include "ops/splat/splat.h"

namespace sfgs::animate {

// The default framing: distance from the body's centre (m) and focal length as a multiple of the image height
// (about 45 degrees of vertical view).
inline constexpr double kFramingDistance = 2.8;
inline constexpr double kFramingFocalPerHeight = 1.2;

// `lens` (its intrinsics and size) placed at `eye` and looking at `target`, world +Y up, image x to the world's
// right. Errors for an eye on the target or straight above or below it.
Camera look_at_camera(const Camera& lens, const std::array<double, 3>& eye, const std::array<double, 3>& target);
// The camera circling the subject: at the distance and height of `base`'s centre around `centre`, `angle` radians
// on from base's own position, looking at the centre.
Camera orbit_camera(const Camera& base, const std::array<double, 3>& centre, double angle);
// `lens` looking at `target` from `distance` in front of it (+Z, where the body model faces), `height` above it,
// turned `angle` radians about the vertical.
Camera camera_in_front(const Camera& lens, const std::array<double, 3>& target, double distance, double height,
                       double angle);
// The centre of the posed body's bounding box (the mean of the Gaussians sits high: hands and face are dense).
std::array<double, 3> centre_of(const model::AvatarOutput& posed);

}  // namespace sfgs::animate
