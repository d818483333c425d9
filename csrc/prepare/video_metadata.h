#pragma once
// What a video file says about its camera. Phones write the lens as a 35 mm-equivalent focal length into QuickTime
// metadata (iPhones: the item com.apple.quicktime.camera.focal_length.35mm_equivalent of a `meta` atom's `keys` and
// `ilst`, in the movie's or the video track's `meta`); `sfgs prepare` takes the camera's focal length from it when no
// --focal is given.
#include <cstdint>
#include <optional>
#include <string>

namespace sfgs::prepare {

// The 35 mm-equivalent focal length (millimetres) the file states, or none: no such item, a value outside
// [kMin35mmFocal, kMax35mmFocal], or a file that is not QuickTime / MP4 (nothing is read beyond the atoms' headers
// but the movie atom; a damaged file gives none, never an error).
std::optional<double> focal_length_35mm(const std::string& path);

// The focal length in pixels of a width x height picture taken with that 35 mm-equivalent lens: the equivalence is
// defined on the 43.27 mm diagonal of a full-frame sensor, so it is that share of the picture's diagonal.
double focal_pixels_from_35mm(double focal_35mm, int64_t width, int64_t height);

}  // namespace sfgs::prepare
