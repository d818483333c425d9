#pragma once
// What the person-detection tests share: whether the MediaPipe models are fetched (scripts/install_deps.sh), and the
// skip that says how to fetch them.
#include <filesystem>

#include <gtest/gtest.h>

#include "detect/models.h"

namespace sfgs::testing {

inline bool mediapipe_models_fetched() {
  return std::filesystem::exists(detect::mediapipe_models_dir() + "/models.json");
}

}  // namespace sfgs::testing

#define SFGS_SKIP_WITHOUT_MEDIAPIPE_MODELS()                                        \
  if (!sfgs::testing::mediapipe_models_fetched())                                   \
  GTEST_SKIP() << "no MediaPipe models in " << sfgs::detect::mediapipe_models_dir() \
               << " (scripts/install_deps.sh fetches them; SFGS_MEDIAPIPE_DIR names another folder)"
