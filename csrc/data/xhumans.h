#pragma once
// X-Humans subjects as ExAvatar and SFGS read them: {train,test}/TakeN/render/{image/color_%06d.png,
// depth/depth_%06d.tiff, cameras.npz}, TakeN/SMPLX/mesh-f%05d_smplx.json (converted once from the .pkl files by
// python/tools/convert_xhumans_smplx.py), optional DECA expressions in TakeN/render/flame_init/flame_params/ and
// the fitted shape in smplx_optimized/. Train takes form the train split, test takes the test split.
#include <string>

#include "data/dataset.h"

namespace sfgs::data {

Dataset read_xhumans(const std::string& subject_folder);

}  // namespace sfgs::data
