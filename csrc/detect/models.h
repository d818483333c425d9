#pragma once
// Where the MediaPipe Holistic models are (scripts/fetch_mediapipe_models.py writes them; docs/prepare.md):
// $SFGS_MEDIAPIPE_DIR, else models/mediapipe beside the source tree this build came from.
#include <string>

namespace sfgs::detect {

std::string mediapipe_models_dir();
// The model file `name` (e.g. "pose_detection.tflite") in that folder; an error saying how to fetch it if missing.
std::string mediapipe_model(const std::string& name);

}  // namespace sfgs::detect
