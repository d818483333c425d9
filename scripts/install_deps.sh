#!/usr/bin/env bash
# Installs sfgs's build and test dependencies from Debian 12's packages (run as root or with sudo available), and
# fetches the MediaPipe Holistic models `sfgs prepare` runs (npm registry, pinned and checked; never committed).
set -euo pipefail
packages=(
  build-essential cmake ninja-build clang-format
  libtorch-dev python3-torch
  pybind11-dev python3-pybind11 python3-pytest
  libopencv-dev libglm-dev libgtest-dev
  nlohmann-json3-dev libstb-dev libzip-dev python3-numpy libflatbuffers-dev
  libopenblas0-openmp  # an optimised BLAS for LibTorch's CPU matrix products (Debian's default is the reference BLAS)
  chromium  # headless, for the web viewer's test (tests/python/test_web_viewer.py; WebGL2 on SwiftShader, no GPU)
)
sudo_cmd=()
if [ "$(id -u)" -ne 0 ]; then sudo_cmd=(sudo); fi
missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  "${sudo_cmd[@]}" apt-get update -qq
  DEBIAN_FRONTEND=noninteractive "${sudo_cmd[@]}" apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi
# Without the registry the build and the other tests still work: sfgs prepare and its tests then say what is missing.
python3 "$(dirname "$0")/fetch_mediapipe_models.py" ||
  echo "WARNING: the MediaPipe models could not be fetched; sfgs prepare needs them (run scripts/fetch_mediapipe_models.py)" >&2
echo "sfgs dependencies are installed"
