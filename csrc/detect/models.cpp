#include "detect/models.h"

#include <cstdlib>
#include <filesystem>

#include <c10/util/Exception.h>

namespace sfgs::detect {

std::string mediapipe_models_dir() {
  if (const char* dir = std::getenv("SFGS_MEDIAPIPE_DIR"); dir && *dir) return dir;
  return std::string(SFGS_SOURCE_DIR) + "/models/mediapipe";
}

std::string mediapipe_model(const std::string& name) {
  const std::string path = mediapipe_models_dir() + "/" + name;
  TORCH_CHECK(std::filesystem::is_regular_file(path), "MediaPipe model '", path,
              "' is missing: run scripts/install_deps.sh (or python3 scripts/fetch_mediapipe_models.py DIR and set "
              "SFGS_MEDIAPIPE_DIR=DIR)");
  return path;
}

}  // namespace sfgs::detect
