#pragma once
// What the person-detection tests share: whether the MediaPipe models are fetched (scripts/install_deps.sh), the
// skip that says how to fetch them, and the synthetic videos of a person they detect in.
#include <cstdint>
#include <filesystem>
#include <string>

#include <gtest/gtest.h>

#include "data/synthetic.h"
#include "detect/models.h"

namespace sfgs::testing {

inline bool mediapipe_models_fetched() {
  return std::filesystem::exists(detect::mediapipe_models_dir() + "/models.json");
}

// A synthetic video of one person doing `motion` (written into `folder`, replacing it; exact keypoints): the CC0
// stand-in person of `bodies` (a ../shared bodies folder) when given, else the built-in body.
inline data::Dataset person_video(const std::filesystem::path& folder, const std::string& bodies,
                                  const std::string& motion, int64_t frames, int64_t width, int64_t height) {
  data::SyntheticVideoOptions o;
  if (!bodies.empty()) {
    o.body_model = bodies + "/anny_smplx_layout.npz";
    o.texture = bodies + "/anny_albedo.png";
  }
  o.motions = {motion};
  o.frames = frames;
  o.width = width;
  o.height = height;
  o.keypoint_noise.exact = true;
  o.overwrite = true;
  return data::write_synthetic_video(folder.string(), o);
}

}  // namespace sfgs::testing

#define SFGS_SKIP_WITHOUT_MEDIAPIPE_MODELS()                                        \
  if (!sfgs::testing::mediapipe_models_fetched())                                   \
  GTEST_SKIP() << "no MediaPipe models in " << sfgs::detect::mediapipe_models_dir() \
               << " (scripts/install_deps.sh fetches them; SFGS_MEDIAPIPE_DIR names another folder)"
