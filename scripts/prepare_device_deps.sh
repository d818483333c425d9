#!/usr/bin/env bash
# Fills the git-ignored .device/ folder with what a GPU machine's image lacks (headers, small libraries, GoogleTest's
# sources, the shared body models and LPIPS weights, the MediaPipe models), from this Debian machine's packages;
# scripts/device_check.sh uses it there. Run once from the repository root:
# bash scripts/prepare_device_deps.sh [SHARED_DIR (../shared)]
set -euo pipefail
cd "$(dirname "$0")/.."
shared=${1:-../shared}
lib=/usr/lib/x86_64-linux-gnu
rm -rf .device && mkdir -p .device/include .device/lib .device/libdeps .device/shared
# zlib's own zconf.h (other packages ship copies of theirs under /usr/include that do not match zlib.h).
cp -r /usr/include/{glm,stb,nlohmann,flatbuffers} /usr/include/zip.h /usr/include/zlib.h /usr/include/zconf.h \
  .device/include/
cp "$(find /usr/include -name zipconf.h | head -n 1)" .device/include/
# Libraries with relative links only: the machine's own system libraries may have other versions.
cp "$lib/libzip.so.4.0" .device/lib/
(cd .device/lib && ln -sf libzip.so.4.0 libzip.so.4 && ln -sf libzip.so.4 libzip.so)
zlib=$(readlink -f "$lib/libz.so")
cp "$zlib" .device/lib/ && (cd .device/lib && ln -sf "$(basename "$zlib")" libz.so)
cp -a "$lib"/libbz2.so.1.0* "$lib"/libcrypto.so.3 .device/libdeps/
cp -r /usr/src/googletest .device/googletest
if [ -d "$shared/bodies" ]; then cp -r "$shared/bodies" "$shared/lpips" .device/shared/; fi
# The MediaPipe models sfgs prepare runs (scripts/fetch_mediapipe_models.py), without the package's tarball and the
# heavy pose model, which the device steps do not use.
if [ -f models/mediapipe/models.json ]; then
  mkdir -p .device/mediapipe
  find models/mediapipe -maxdepth 1 -name '*.tflite' ! -name 'pose_landmark_heavy.tflite' -exec cp {} .device/mediapipe/ \;
  cp models/mediapipe/models.json .device/mediapipe/
fi
du -sh .device
