#pragma once
// sfgs prepare's numbers, named once.

namespace sfgs::prepare {

// A 35 mm-equivalent focal length a video's metadata states is believed within this range (millimetres): phones' lenses
// run from about 13 (ultra-wide) to 120 (telephoto); anything outside is taken as a damaged value and ignored.
inline constexpr double kMin35mmFocal = 8.0;
inline constexpr double kMax35mmFocal = 400.0;

}  // namespace sfgs::prepare
