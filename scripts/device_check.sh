#!/usr/bin/env bash
# Checks the CUDA backend on a GPU machine: configures and builds against the machine's CUDA LibTorch, runs the CUDA
# tests, compute-sanitizer memcheck and racecheck on the small *CudaSanitizer.* cases (and memcheck on the recorded
# training steps, StepGraphsCuda.*), and the benchmark with its regression guard (SFGS_DEVICE_BENCH_BASELINE names
# another baseline file than bench/baselines/splat_h200.json).
#
#   bash scripts/device_check.sh [build] [test] [python] [pip] [sanitize] [bench] [profile] [avatar] [animate]
#                                [train-step] [animate-trained] [stage-profile] [step-profile] [train] [ablate] [novel]
#                                [sizes] [resolution] [fits] [render-path] [refine-cost] [fit-profile] [prepare]
#   (no argument: build, test, sanitize, bench, profile, in this order)
#
# python: the pytest suite against the module built with the machine's pip torch and pybind11 (CUDA included).
# pip: `python3 -m pip install --no-build-isolation --no-deps --target /tmp/sfgs-pip .` (setup.py; it reuses the
# build step's folder, so only the module is built, or configures a fresh one), then the pytest suite against that
# installed copy, run from /tmp: no PYTHONPATH to the build folder and, like the python step, no preload.
# profile: GPU time of every kernel of three forward + backward steps at 167,390 and 1M Gaussians, 800 x 1200
# (Nsight Compute, clocks left alone), as CSV.
#
# Logs go to $OUT (the device tool's output folder) or ./device-logs. The device image lacks some dependencies; they
# travel in the git-ignored .device folder (name it in the device tool's carry), which scripts/prepare_device_deps.sh
# fills:
#   .device/include     /usr/include/glm, /usr/include/stb, /usr/include/nlohmann, zip.h and zipconf.h, zlib.h and zconf.h
#   .device/lib         libzip.so.4.0 with its links libzip.so.4 and libzip.so, libz.so
#   .device/libdeps     libbz2.so.1.0 and libcrypto.so.3 (libzip's own dependencies), used only where the image
#                       lacks them
#   .device/googletest  /usr/src/googletest
#   .device/shared      ../shared/bodies and ../shared/lpips (avatar and train steps)
#   .device/include/flatbuffers and .device/mediapipe (the MediaPipe models): sfgs prepare (prepare step)
#
# avatar: the avatar benchmark on the GPU and the avatar and trainer tests (CPU, with the GPU build).
# animate: the animation path's CUDA tests (skinning kernel, fused gathered MLP, binning budget, Animator graph and
# fast frames; the small ones under compute-sanitizer memcheck) and bench_animate on the Anny body (800x1200 and 540x960) and the procedural one.
# train-step: bench_train_step on the Anny scene at SFGS_DEVICE_STEP_SIZE (default 800x1200), 40 frames.
# stage-profile: Nsight Compute over one eager and one graph frame (bench_animate --profile 1, Anny, 800x1200; the
# trained avatar of render-path or animate-trained when one of them ran; replayed frames at SFGS_DEVICE_PROFILE_TIME
# when set): every kernel's GPU time and DRAM bytes, summed per stage (scripts/kernel_profile_summary.py).
# step-profile: the same over one training step (bench_train_step --profile 1, the train-step scene).
# fit-profile: the same over one eager pose-fit evaluation (bench_pose_fit --profile 1: an alignment pass's fine
# stage on the person's crop of the first training frame) of an avatar refine-cost trained (the refined one, else the
# plain one), else render-path's.
# train: synthesise the Anny scene (SFGS_DEVICE_TRAIN_SIZE, default 800x1200; SFGS_DEVICE_TRAIN_FRAMES, default
# 80) and train, evaluate (with LPIPS) and render it on CUDA with configs/device_anny.yaml
# (SFGS_DEVICE_TRAIN_ITERATIONS overrides its iterations).
# ablate: `sfgs ablate` on the Anny scene at SFGS_DEVICE_ABLATE_SIZE (default 400x600), 80 frames,
# SFGS_DEVICE_ABLATE_ITERATIONS (default 1500) per variant.
# novel: the novel-motion benchmark (docs/results.md): the Anny body filmed walking, waving and turning (train) and
# raising its arms, bending, guarding and sitting (test), SFGS_DEVICE_NOVEL_FRAMES (default 40) frames per motion at
# SFGS_DEVICE_NOVEL_SIZE (default 540x960), beside the interleaved Anny scene (sway, 80 frames) and, when named, the
# frontal scene (walking, waving and talking, never turned away, to train on; turning, bending, arms overhead, kicking,
# sitting and the guard to test on); SFGS_DEVICE_NOVEL_SCENES names the scenes, default "novel interleaved". Every
# variant of
# SFGS_DEVICE_NOVEL_VARIANTS ("name:key=value,..." separated by spaces, keys of the avatar section; default
# "default:") is trained on both scenes at once with configs/device_anny.yaml for SFGS_DEVICE_NOVEL_ITERATIONS
# (default 4000), then evaluated on test (new motions; interleaved test frames) and val (held-out frames of the
# training motions). SFGS_DEVICE_BASELINE_SRC=DIR also builds the sfgs in DIR (an earlier version, for a before /
# after) and trains it as variant "baseline" with that version's config. Every other variant's run is also
# evaluated on test with each eval ablation flag of SFGS_DEVICE_NOVEL_ABLATIONS (default "no-observation-prior";
# "" for none).
# SFGS_DEVICE_TARGETS replaces the build step's target list (e.g. "sfgs" for the novel step alone).
# The whole project is configured and built (sfgs_core holds every module). Should that build fail (another module's
# dependency missing or a module not compiling), a splat-only CMake project (the op, both backends, the CUDA tests
# and benchmark) is built instead so that the CUDA checks still run; the build step is reported failed either way.
# SFGS_DEVICE_SPLAT_ONLY=1 builds only the splat-only project (minutes faster). Each step has a time
# limit so that one call of the device tool (10 minutes) always returns its logs.
set -uo pipefail

root=$(cd "$(dirname "$0")/.." && pwd)
out=${OUT:-$root/device-logs}
build=${SFGS_DEVICE_BUILD:-/tmp/sfgs-device-build}
jobs=${SFGS_DEVICE_JOBS:-16}
mkdir -p "$out"
steps=("$@")
[ ${#steps[@]} -eq 0 ] && steps=(build test sanitize bench profile)
failed=()

# run NAME LIMIT_SECONDS COMMAND...: full log in $out/NAME.log, its end on stdout.
run() {
  local name=$1 limit=$2
  shift 2
  echo "== $name: $*"
  local start=$SECONDS
  timeout --kill-after=10 "$limit" "$@" >>"$out/$name.log" 2>&1
  local rc=$?
  echo "== $name: exit $rc after $((SECONDS - start)) s"
  [ $rc -eq 0 ] || failed+=("$name")
  return $rc
}

wants() {
  local s
  for s in "${steps[@]}"; do [ "$s" = "$1" ] && return 0; done
  return 1
}

# Carried libraries: libzip always, its dependencies only where the image has none.
if [ -d "$root/.device/lib" ]; then
  (cd "$root/.device/lib" && [ -e libzip.so.4.0 ] && ln -sf libzip.so.4.0 libzip.so.4 && ln -sf libzip.so.4 libzip.so)
  extra_libs=$root/.device/lib
  for dep in libbz2.so.1.0 libcrypto.so.3; do
    if ! ldconfig -p | grep -q "$dep" && [ -e "$root/.device/libdeps/$dep" ]; then
      extra_libs=$extra_libs:$root/.device/libdeps
      break
    fi
  done
  export LD_LIBRARY_PATH=$extra_libs${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}
fi

{
  nvidia-smi --query-gpu=name,driver_version,memory.total,clocks.sm,clocks.max.sm --format=csv
  nvcc --version | tail -n 2
  python3 -c 'import torch; print("torch", torch.__version__, "cuda", torch.version.cuda)'
  cmake --version | head -n 1
  echo "LD_LIBRARY_PATH=${LD_LIBRARY_PATH:-}"
} >"$out/environment.log" 2>&1
cat "$out/environment.log"

# The splat-only fallback project: the op, both backends and the CUDA tests and benchmark, nothing else.
write_splat_project() {
  local dir=$1
  mkdir -p "$dir"
  cat >"$dir/CMakeLists.txt" <<EOF
cmake_minimum_required(VERSION 3.22)
project(sfgs_splat_only LANGUAGES CXX CUDA)
set(CMAKE_CXX_STANDARD 17)
set(CMAKE_CUDA_STANDARD 17)
set(CMAKE_CUDA_ARCHITECTURES 90)
find_package(Torch REQUIRED)
file(GLOB SPLAT_SOURCES $root/csrc/ops/splat/*.cpp $root/csrc/ops/splat/cpu/*.cpp $root/csrc/ops/splat/cuda/*.cu
  $root/csrc/ops/splat/cuda/*.cpp $root/csrc/common/tensor_description.cpp)
add_library(sfgs_core STATIC \${SPLAT_SOURCES})
target_include_directories(sfgs_core PUBLIC $root/csrc $root/.device/include)
target_link_libraries(sfgs_core PUBLIC \${TORCH_LIBRARIES})
target_compile_options(sfgs_core PRIVATE "\$<\$<COMPILE_LANGUAGE:CUDA>:--expt-relaxed-constexpr;-diag-suppress=20012;-lineinfo>")
target_compile_definitions(sfgs_core PUBLIC SFGS_WITH_CUDA=1)
set(INSTALL_GTEST OFF CACHE BOOL "" FORCE)
add_subdirectory($root/.device/googletest \${CMAKE_BINARY_DIR}/googletest EXCLUDE_FROM_ALL)
add_executable(sfgs_cuda_tests $root/tests/cuda/test_splat_cuda.cpp $root/tests/cpp/splat_test_utils.cpp)
target_include_directories(sfgs_cuda_tests PRIVATE $root/tests/cpp)
target_link_libraries(sfgs_cuda_tests PRIVATE sfgs_core gtest_main)
add_executable(bench_splat_cuda $root/bench/bench_splat_cuda.cpp)
target_link_libraries(bench_splat_cuda PRIVATE sfgs_core)
set_target_properties(bench_splat_cuda PROPERTIES RUNTIME_OUTPUT_DIRECTORY \${CMAKE_BINARY_DIR}/bench)
set_target_properties(sfgs_cuda_tests PROPERTIES RUNTIME_OUTPUT_DIRECTORY \${CMAKE_BINARY_DIR}/tests)
EOF
}

tests=$build/tests/sfgs_cuda_tests
bench=$build/bench/bench_splat_cuda
if wants build; then
  torch_prefix=$(python3 -c 'import torch; print(torch.utils.cmake_prefix_path)')
  full_ok=0
  if [ "${SFGS_DEVICE_SPLAT_ONLY:-0}" != 1 ]; then
    # The Python module too (pip torch and pybind11): the python step runs the pytest suite on CUDA.
    pybind11_dir=$(python3 -m pybind11 --cmakedir 2>/dev/null)
    run build 330 cmake -S "$root" -B "$build" -G Ninja -DCMAKE_BUILD_TYPE=Release \
      -DCMAKE_PREFIX_PATH="$torch_prefix" -DSFGS_CUDA=ON -DSFGS_BUILD_PYTHON=ON \
      -DPython_EXECUTABLE="$(command -v python3)" -Dpybind11_DIR="$pybind11_dir" \
      -DSFGS_EXTRA_INCLUDE_DIRS="$root/.device/include" -DSFGS_GTEST_SOURCE_DIR="$root/.device/googletest" &&
      run build 400 cmake --build "$build" -j "$jobs" --target \
        ${SFGS_DEVICE_TARGETS:-sfgs_cuda_tests bench_splat_cuda sfgs sfgs_tests bench_avatar sfgs_python} -- -k 0 &&
      full_ok=1
    [ $full_ok -eq 1 ] || grep -E "error|Error|FAILED" "$out/build.log" | head -n 40
  fi
  if [ $full_ok -ne 1 ]; then
    echo "== building the splat-only project"
    splat=/tmp/sfgs-splat-build
    write_splat_project "$splat/src"
    run build-splat 300 cmake -S "$splat/src" -B "$splat" -G Ninja -DCMAKE_BUILD_TYPE=Release \
      -DCMAKE_PREFIX_PATH="$torch_prefix" &&
      run build-splat 300 cmake --build "$splat" -j "$jobs" --target sfgs_cuda_tests bench_splat_cuda ||
      { grep -E "error|Error|FAILED" "$out/build-splat.log" | head -n 40; exit 1; }
    tests=$splat/tests/sfgs_cuda_tests
    bench=$splat/bench/bench_splat_cuda
  fi
fi

if wants test; then
  # The detection tests read the carried MediaPipe models and the stand-in person.
  run test 150 env OMP_NUM_THREADS="$jobs" SFGS_MEDIAPIPE_DIR="$root/.device/mediapipe" \
    SFGS_SHARED_DIR="$root/.device/shared" "$tests" --gtest_color=no
  grep -E "^\[parity\]|^\[  FAILED|^\[  PASSED|Failure|Expected|Which is|actual|ms total\)" "$out/test.log" | cut -c1-400
fi

if wants python; then
  # The whole pytest suite with the pip stack; the op's opcheck and the avatar API also run on CUDA there. No
  # preload: the module builds yaml-cpp in (third_party/) and exports only PyInit__C (test_module_isolation.py).
  run python 300 env PYTHONPATH="$build/python" SFGS_EXECUTABLE="$build/sfgs" SFGS_SHARED_DIR="$root/.device/shared" \
    OMP_NUM_THREADS="$jobs" python3 -m pytest -q -rs -p no:cacheprovider -m "${SFGS_DEVICE_PYTEST_MARKS:-not cli}" \
    "$root/tests/python"
  tail -n 25 "$out/python.log"
fi

if wants pip; then
  # The build step's folder when there is one (only the module target is then built), else a folder of its own.
  pip_build=$build
  [ -f "$build/CMakeCache.txt" ] || pip_build=/tmp/sfgs-pip-build
  pip_target=/tmp/sfgs-pip
  rm -rf "$pip_target"
  python3 -c 'import setuptools; print("setuptools", setuptools.__version__)' >"$out/pip-install.log" 2>&1
  run pip-install 450 env SFGS_BUILD_DIR="$pip_build" SFGS_BUILD_JOBS="$jobs" \
    SFGS_CMAKE_ARGS="-DSFGS_CUDA=ON -DSFGS_EXTRA_INCLUDE_DIRS=$root/.device/include" \
    python3 -m pip install --no-build-isolation --no-deps --target "$pip_target" "$root"
  tail -n 5 "$out/pip-install.log"
  # From /tmp, so that nothing of the source tree or the build folder can stand in for the installed copy.
  run pip 300 env -C /tmp PYTHONPATH="$pip_target" SFGS_EXECUTABLE="$build/sfgs" \
    SFGS_SHARED_DIR="$root/.device/shared" OMP_NUM_THREADS="$jobs" \
    python3 -c 'import sfgs; print("testing the module at", sfgs._C.__file__)'
  run pip 300 env -C /tmp PYTHONPATH="$pip_target" SFGS_EXECUTABLE="$build/sfgs" \
    SFGS_SHARED_DIR="$root/.device/shared" OMP_NUM_THREADS="$jobs" \
    python3 -m pytest -q -rs -p no:cacheprovider -m "${SFGS_DEVICE_PYTEST_MARKS:-not cli}" "$root/tests/python"
  tail -n 25 "$out/pip.log"
fi

if wants sanitize; then
  for tool in memcheck racecheck; do
    run sanitize 150 compute-sanitizer --tool "$tool" --error-exitcode 99 "$tests" --gtest_filter='*CudaSanitizer.*' \
      --gtest_color=no
  done
  # Recorded training steps (capture, replay, a step beyond the budget) under memcheck.
  run sanitize 200 compute-sanitizer --tool memcheck --error-exitcode 99 "$tests" --gtest_filter='StepGraphsCuda.*' \
    --gtest_color=no
  grep -E "ERROR SUMMARY|RACECHECK SUMMARY|^\[  PASSED|^\[  FAILED|Invalid|Race reported" "$out/sanitize.log" | head -n 20
fi

# bench: the benchmark, then its regression guard (scripts/bench_guard.py): every figure against
# bench/baselines/splat_h200.json (fails beyond +10%) and the gsplat-comparable case.
if wants bench; then
  run bench 300 "$bench"
  cat "$out/bench.log"
  run bench-guard 30 python3 "$root/scripts/bench_guard.py" "$out/bench.log" \
    --baseline "${SFGS_DEVICE_BENCH_BASELINE:-$root/bench/baselines/splat_h200.json}"
  cat "$out/bench-guard.log"
fi

if wants profile; then
  ncu=$(command -v ncu || echo /usr/local/cuda/bin/ncu)
  for n in 167390 1000000; do
    run profile 120 "$ncu" --clock-control none --metrics gpu__time_duration.sum --csv \
      "$bench" --profile "$n" 800 1200
  done
  grep -c '"gpu__time_duration.sum"' "$out/profile.log"
  # The third step's projection, emission, tile sort and blends at 167,390 Gaussians, every section of the detailed
  # set (throughput, occupancy, warp stalls, instruction mix), and the blends' machine code.
  run profile-detail 150 "$ncu" --clock-control none --set detailed \
    -k 'regex:blend_|sort_tiles|emit_tile|project_kernel' --launch-skip 10 --launch-count 5 \
    "$bench" --profile 167390 800 1200
  cuobjdump -sass "$bench" | awk '/Function : .*blend_(forward|whole_tiles|backward)_kernelIfLi3E/ {p = 1} \
    /Function : / && !/blend_(forward|whole_tiles|backward)_kernelIfLi3E/ {p = 0} p' >"$out/sass.log" 2>&1
  wc -l "$out/sass.log"
fi

if wants avatar; then
  run avatar 200 "$build/bench/bench_avatar" --device cuda --repeats 20
  run avatar 200 "$build/bench/bench_avatar" --device cuda --repeats 20 --levels 1
  cat "$out/avatar.log"
  run avatar-tests 200 env SFGS_SHARED_DIR="$root/.device/shared" OMP_NUM_THREADS="$jobs" "$build/tests/sfgs_tests" \
    --gtest_color=no
  grep -E "^\[  FAILED|^\[  PASSED|Failure|^\[ RUN" "$out/avatar-tests.log" | tail -n 20
  if grep -q "Segmentation\|exit 139" "$out/avatar-tests.log" || ! grep -q "PASSED" "$out/avatar-tests.log"; then
    command -v gdb >/dev/null && gdb -batch -ex run -ex bt --args "$build/tests/sfgs_tests" --gtest_filter='Trainer*' \
      2>&1 | grep -E "^#|signal" | head -n 30
    for t in Trainer.ResumedRunEqualsUninterruptedRun Trainer.ErrorCurveHoldsEveryValidation \
      Trainer.NeverOverwritesARunUnasked; do
      "$build/tests/sfgs_tests" --gtest_filter="$t" >"$out/one-test.log" 2>&1
      echo "$t: exit $?"
      tail -n 4 "$out/one-test.log"
    done
  fi
fi

if wants animate; then
  run animate-tests 250 env OMP_NUM_THREADS="$jobs" "$tests" --gtest_color=no \
    --gtest_filter='SkinCuda*:GatheredMlpCuda*:KinematicChainCuda*:AxisAngleCuda*:VertexNormalsCuda*:BinningBudget.*:AnimatorCuda.*:AdamStepperCuda.*'
  grep -E "^\[  FAILED|^\[  PASSED|^\[       OK|Failure|Expected|Which is|actual" "$out/animate-tests.log" | cut -c1-300
  run animate-sanitize 250 compute-sanitizer --tool memcheck --error-exitcode 99 "$tests" --gtest_color=no \
    --gtest_filter='*CudaSanitizer.*:BinningBudget.*:AnimatorCuda.GraphFramesEqual*:AdamStepperCuda.FusedSteps*'
  grep -E "ERROR SUMMARY|^\[  PASSED|^\[  FAILED|Invalid" "$out/animate-sanitize.log" | head -n 10
  run animate-bench 250 "$build/bench/bench_animate" --device cuda --shared "$root/.device/shared" \
    --frames "${SFGS_DEVICE_ANIMATE_FRAMES:-300}"
  run animate-bench 150 "$build/bench/bench_animate" --device cuda --sizes 800x1200 \
    --frames "${SFGS_DEVICE_ANIMATE_FRAMES:-300}"
  cat "$out/animate-bench.log"
fi

# anny_scene STEP FOLDER WIDTHxHEIGHT FRAMES: the Anny scene synthesised into FOLDER/data and its training config
# (configs/device_anny.yaml pointed at the carried bodies) in FOLDER/config.yaml.
shared=$root/.device/shared
anny_scene() {
  local size=$3
  run "$1" 240 "$build/sfgs" synth --out "$2/data" --body "$shared/bodies/anny_smplx_layout.npz" \
    --texture "$shared/bodies/anny_albedo.png" --frames "$4" --width "${size%x*}" --height "${size#*x}" --force
  tail -n 1 "$out/$1.log"
  sed "s|@SHARED@|$shared|g" "$root/configs/device_anny.yaml" >"$2/config.yaml"
}

if wants train-step; then
  export SFGS_SHARED_DIR=$shared
  scene=/tmp/sfgs-anny-step
  anny_scene step-synth "$scene" "${SFGS_DEVICE_STEP_SIZE:-800x1200}" 40
  run train-step 300 "$build/bench/bench_train_step" --data "$scene/data" --config "$scene/config.yaml" \
    --warmup 20 --steps "${SFGS_DEVICE_STEP_COUNT:-400}"
  cat "$out/train-step.log"
fi

# animate-trained: a short training of the Anny scene (SFGS_DEVICE_ANIMATE_ITERATIONS, default 1000; 40 frames at
# 800x1200), then bench_animate on that trained avatar (its splatting work is a trained one's).
trained=/tmp/sfgs-anny-trained
if wants animate-trained; then
  export SFGS_SHARED_DIR=$shared
  anny_scene trained-synth "$trained" 800x1200 40
  run trained-train 400 "$build/sfgs" train --data "$trained/data" --out "$trained/run" --config "$trained/config.yaml" \
    --iterations "${SFGS_DEVICE_ANIMATE_ITERATIONS:-1000}" --force
  tail -n 3 "$out/trained-train.log"
  run animate-trained 250 "$build/bench/bench_animate" --device cuda --run "$trained/run" \
    --frames "${SFGS_DEVICE_ANIMATE_FRAMES:-300}"
  cat "$out/animate-trained.log"
fi

# render-path: the product paths on one trained avatar (issue 40): the Anny body filmed walking, waving and turning
# at 800x1200 (SFGS_DEVICE_RENDER_FRAMES frames a motion, default 20; new motions in test, held-out frames of the
# training motions in val), trained for SFGS_DEVICE_RENDER_ITERATIONS (default 1000); then bench_animate's graph frame
# (new-motion and replayed frames), `sfgs eval` on new motions (test) and replayed frames (val), `sfgs render` of 300
# frames and Avatar.render from Python (bench/python_render.py).
render_scene=/tmp/sfgs-render-path
make_render_scene() {
  [ -f "$render_scene/data/dataset.json" ] && return 0
  run render-synth 300 "$build/sfgs" synth --out "$render_scene/data" --body "$shared/bodies/anny_smplx_layout.npz" \
    --texture "$shared/bodies/anny_albedo.png" --motions walk,wave,turn --test-motions overhead,bend,guard,sit \
    --frames "${SFGS_DEVICE_RENDER_FRAMES:-20}" --width 800 --height 1200 --force
  sed "s|@SHARED@|$shared|g" "$root/configs/device_anny.yaml" >"$render_scene/config.yaml"
}
if wants render-path; then
  export SFGS_SHARED_DIR=$shared
  scene=$render_scene
  make_render_scene
  run render-train 400 "$build/sfgs" train --data "$scene/data" --out "$scene/run" --config "$scene/config.yaml" \
    --iterations "${SFGS_DEVICE_RENDER_ITERATIONS:-1000}" --force --quiet
  tail -n 3 "$out/render-train.log"
  run render-frame 200 "$build/bench/bench_animate" --device cuda --run "$scene/run" --sizes 800x1200 --frames 300 \
    --cull-cosines 1 --blend-segments 256
  run render-frame-replayed 200 "$build/bench/bench_animate" --device cuda --run "$scene/run" --sizes 800x1200 \
    --frames 300 --cull-cosines 1 --blend-segments 256 --blend-cut-shares 1.5 --time -0.5
  for split in test val; do
    run "render-eval-$split" 200 "$build/sfgs" eval --run "$scene/run" --split "$split" --device cuda --force
  done
  run render-video 200 "$build/sfgs" render --run "$scene/run" --out "$scene/render" --motion bend --frames 300 \
    --device cuda --force
  run render-python 200 env PYTHONUNBUFFERED=1 PYTHONPATH="$build/python" python3 "$root/bench/python_render.py" "$scene/run" --frames 200
  grep -h -E "frame|sfgs eval|render |encode|PSNR|median|python" "$out"/render-frame*.log "$out"/render-eval-*.log \
    "$out"/render-video.log "$out"/render-python.log | cut -c1-200
fi

# prepare: issue 45's pipeline on CUDA. The Anny body walking and waving (SFGS_DEVICE_PREPARE_FRAMES frames a motion,
# default 40, at SFGS_DEVICE_PREPARE_SIZE, default 540x960) in the NeuMan layout with its ground truth; `sfgs prepare`
# on its images with the camera's focal length, on CUDA (detection frames/s, keypoint and fit accuracy); then one
# avatar trained on the exact fits and one on the prepared ones (configs/device_anny.yaml,
# SFGS_DEVICE_PREPARE_ITERATIONS, default 2000), each evaluated on its own test frames (the prepared one also with its
# test poses fitted).
if wants prepare; then
  export SFGS_SHARED_DIR=$shared SFGS_MEDIAPIPE_DIR=$root/.device/mediapipe
  scene=/tmp/sfgs-prepare
  size=${SFGS_DEVICE_PREPARE_SIZE:-540x960}
  run prepare-synth 300 "$build/sfgs" synth --out "$scene/exact" --layout neuman \
    --body "$shared/bodies/anny_smplx_layout.npz" --texture "$shared/bodies/anny_albedo.png" --motions walk,wave \
    --frames "${SFGS_DEVICE_PREPARE_FRAMES:-40}" --width "${size%x*}" --height "${size#*x}" --force
  sed "s|@SHARED@|$shared|g" "$root/configs/device_anny.yaml" >"$scene/config.yaml"
  focal=$(awk -v h="${size#*x}" 'BEGIN { print 1.2 * h }')
  run prepare-cuda 400 "$build/sfgs" prepare "$scene/exact/images" --out "$scene/prepared" --focal "$focal" \
    --body "$shared/bodies/anny_smplx_layout.npz" --truth "$scene/exact/ground_truth" --device cuda --force
  grep -E "sfgs prepare|frames/s|median|IoU" "$out/prepare-cuda.log" | tail -n 12
  for variant in exact prepared; do
    run "prepare-train-$variant" 400 "$build/sfgs" train --data "$scene/$variant" --out "$scene/run-$variant" \
      --config "$scene/config.yaml" --iterations "${SFGS_DEVICE_PREPARE_ITERATIONS:-2000}" --force --quiet
    run "prepare-eval-$variant" 300 "$build/sfgs" eval --run "$scene/run-$variant" --split test --device cuda --force
    grep -E "PSNR|psnr" "$out/prepare-eval-$variant.log" | tail -n 3
  done
  run prepare-eval-prepared-fitted 400 "$build/sfgs" eval --run "$scene/run-prepared" --split test --device cuda \
    --fit-test-poses --force
  grep -E "PSNR|psnr" "$out/prepare-eval-prepared-fitted.log" | tail -n 3
fi

# refine-cost: what pose refinement costs a training (issue 40), on render-path's scene (made here if render-path did
# not run): trained plainly and with pose refinement at its defaults (configs/device_anny.yaml) for
# SFGS_DEVICE_REFINE_ITERATIONS (default 4000) each, and with refinement and every step and evaluation eager
# (schedule.cuda_graphs false) for SFGS_DEVICE_REFINE_EAGER_ITERATIONS (default 200; a pass costs the same in a run of
# any length). SFGS_DEVICE_REFINE_VARIANTS names the runs (default "plain refined refined-eager"). Prints each run's
# training seconds and each alignment pass's frames, loss evaluations and seconds; then bench_pose_fit on the refined
# (else the plain) run's first four training frames (an evaluation on the whole image, on the person's crop, without LPIPS, with the
# L1 stage loss; whole fits at the passes' 60 evaluations).
if wants refine-cost; then
  export SFGS_SHARED_DIR=$shared
  scene=$render_scene
  make_render_scene
  for variant in ${SFGS_DEVICE_REFINE_VARIANTS:-plain refined refined-eager}; do
    config=$scene/config-$variant.yaml
    cp "$scene/config.yaml" "$config"
    [ "$variant" != plain ] && printf 'pose_refinement:\n  enabled: true\n' >>"$config"
    iterations=${SFGS_DEVICE_REFINE_ITERATIONS:-4000}
    if [ "$variant" = refined-eager ]; then
      sed -i 's/^\( *cuda_graphs:\).*/\1 false/' "$config"
      grep -q 'cuda_graphs:' "$config" || sed -i 's/^schedule:$/schedule:\n  cuda_graphs: false/' "$config"
      iterations=${SFGS_DEVICE_REFINE_EAGER_ITERATIONS:-200}
    fi
    run "refine-$variant" 590 "$build/sfgs" train --data "$scene/data" --out "$scene/run-$variant" \
      --config "$config" --iterations "$iterations" --force --quiet
    python3 - "$scene/run-$variant/log.jsonl" "$variant" <<'PY'
import json, sys
entries = [json.loads(line) for line in open(sys.argv[1])]
for e in entries:
    if e.get("event") == "pose_alignment":
        print(f"  {sys.argv[2]} alignment at {e['iteration']}: {e['frames']} frames, {e['evaluations']} evaluations, "
              f"{e['seconds']:.1f} s ({1000 * e['seconds'] / max(1, e['evaluations']):.2f} ms each), "
              f"recorded {e['recorded']}, loss {e['loss_before']:.4f} -> {e['loss_after']:.4f}")
        if "pose_error" in e:
            r = e["pose_error"]["refined"]
            print(f"    refined fits against the exact ones: root {r['root_deg']:.2f} deg, body {r['body_deg']:.2f} deg, "
                  f"translation {r['translation_cm']:.2f} cm")
for e in entries:
    if e.get("event") == "end":
        print(f"  {sys.argv[2]}: {e['iteration']} iterations, training {e['training_seconds']:.1f} s, "
              f"val PSNR {e.get('val_psnr', float('nan')):.2f}")
PY
  done
  fit_run=$scene/run-refined
  [ -f "$fit_run/checkpoint.pt" ] || fit_run=$scene/run-plain
  if [ -f "$fit_run/checkpoint.pt" ]; then
    run refine-bench-fit 300 "$build/bench/bench_pose_fit" --run "$fit_run" --split train --frames 4
    cat "$out/refine-bench-fit.log"
  fi
fi

if wants stage-profile || wants step-profile || wants fit-profile; then
  export SFGS_SHARED_DIR=$shared
  ncu=$(command -v ncu || echo /usr/local/cuda/bin/ncu)
  metrics=gpu__time_duration.sum,dram__bytes_read.sum,dram__bytes_write.sum
  profile_stages() {
    local name=$1
    shift
    run "$name" 280 "$ncu" --profile-from-start off --nvtx --clock-control none --metrics "$metrics" -f \
      -o "/tmp/$name" "$@"
    "$ncu" --import "/tmp/$name.ncu-rep" --csv --page raw >"$out/$name-kernels.csv" 2>&1
    python3 "$root/scripts/kernel_profile_summary.py" "$out/$name-kernels.csv" >"$out/$name-summary.txt" 2>&1
    cat "$out/$name-summary.txt"
  }
  # The trained avatar of render-path or animate-trained when one ran, else the untrained Anny avatar.
  avatar_args=(--shared "$root/.device/shared")
  [ -f "$trained/run/checkpoint.pt" ] && avatar_args=(--run "$trained/run")
  [ -f /tmp/sfgs-render-path/run/checkpoint.pt ] && avatar_args=(--run /tmp/sfgs-render-path/run)
  [ -n "${SFGS_DEVICE_PROFILE_TIME:-}" ] && avatar_args+=(--time "$SFGS_DEVICE_PROFILE_TIME")
  wants stage-profile && profile_stages frame-profile "$build/bench/bench_animate" --device cuda "${avatar_args[@]}" \
    --sizes 800x1200 --profile 1
  if wants step-profile; then
    scene=/tmp/sfgs-anny-step
    [ -d "$scene/data" ] || anny_scene step-synth "$scene" "${SFGS_DEVICE_STEP_SIZE:-800x1200}" 40
    profile_stages step-profile "$build/bench/bench_train_step" --data "$scene/data" --config "$scene/config.yaml" \
      --warmup 5 --profile 1
  fi
  if wants fit-profile; then
    fit_run=/tmp/sfgs-render-path/run
    for candidate in run-plain run-refined; do
      [ -f "/tmp/sfgs-render-path/$candidate/checkpoint.pt" ] && fit_run=/tmp/sfgs-render-path/$candidate
    done
    profile_stages fit-profile "$build/bench/bench_pose_fit" --run "$fit_run" --split train --profile 1
  fi
fi

if wants train; then
  export SFGS_SHARED_DIR=$shared  # LPIPS weights for the loss and the evaluation
  scene=/tmp/sfgs-anny
  anny_scene train-synth "$scene" "${SFGS_DEVICE_TRAIN_SIZE:-800x1200}" "${SFGS_DEVICE_TRAIN_FRAMES:-80}"
  iterations=()
  [ -n "${SFGS_DEVICE_TRAIN_ITERATIONS:-}" ] && iterations=(--iterations "$SFGS_DEVICE_TRAIN_ITERATIONS")
  nvidia-smi --query-gpu=memory.used --format=csv,noheader -lms 500 >"$out/train-memory.log" &
  smi=$!
  run train "${SFGS_DEVICE_TRAIN_LIMIT:-420}" "$build/sfgs" train --data "$scene/data" --out "$scene/run" --config "$scene/config.yaml" \
    "${iterations[@]}" --force
  kill $smi
  tail -n 4 "$out/train.log"
  echo "peak GPU memory used during training (whole device): $(sort -n "$out/train-memory.log" | tail -n 1)"
  cp "$scene/run/log.jsonl" "$scene/run/curve.csv" "$out/" 2>/dev/null
  cp "$scene/run/curve.png" "$out/" 2>/dev/null
  run train-eval 200 "$build/sfgs" eval --run "$scene/run" --data "$scene/data" --device cuda --save-images --force
  tail -n 4 "$out/train-eval.log"
  cp "$scene/run/metrics_test.json" "$out/" 2>/dev/null
  run train-render 120 "$build/sfgs" render --run "$scene/run" --out "$scene/render" --frames 96 --device cuda --force
  tail -n 2 "$out/train-render.log"
  mkdir -p "$out/renders" && cp "$scene"/run/eval_images_test/*.png "$out/renders/" 2>/dev/null
  cp "$scene/render/frame_0000.png" "$scene/render/frame_0048.png" "$scene/render/render.mp4" "$out/renders/" 2>/dev/null
fi

if wants ablate; then
  export SFGS_SHARED_DIR=$shared
  scene=/tmp/sfgs-anny-ablate
  anny_scene ablate-synth "$scene" "${SFGS_DEVICE_ABLATE_SIZE:-400x600}" 80
  run ablate 540 "$build/sfgs" ablate --data "$scene/data" --out "$scene/ablation" --config "$scene/config.yaml" \
    --iterations "${SFGS_DEVICE_ABLATE_ITERATIONS:-1500}" --force
  grep -E "^\||sfgs ablate" "$out/ablate.log"
  cp "$scene/ablation/ablation.json" "$scene/ablation/ablation.md" "$out/" 2>/dev/null
fi

# fits: issue 16's benchmark (docs/results.md, "Imperfect fits"). The Anny body swaying (SFGS_DEVICE_FITS_FRAMES,
# default 80, at SFGS_DEVICE_FITS_SIZE, default 540x960) in the NeuMan layout with exact fits ("exact"), the same video
# with fits corrupted at SFGS_DEVICE_FITS_NOISE (default medium; "noisy"), and the fits `sfgs fit` makes on CUDA from
# its detector-like keypoints ("fitted"); the data are made once per machine. Each variant of
# SFGS_DEVICE_FITS_VARIANTS (default "exact noisy refined fitted fitted-refined"; "refined" and "fitted-refined" are
# noisy and fitted with pose refinement at its defaults, docs/training.md; "refined-round2" and "fitted-round2", listed
# after them, are second rounds started from their refined fits, `sfgs train --start-fits`) is trained for
# SFGS_DEVICE_FITS_ITERATIONS (default 2000) with configs/device_anny.yaml and evaluated on its test frames plainly and
# with test-time pose fitting (SFGS_DEVICE_FITS_FIT_ITERATIONS, default the command's); the exact variant also with the
# test fits of each dataset of SFGS_DEVICE_FITS_CROSS (default "noisy fitted"), the reference under the same test fits.
if wants fits; then
  export SFGS_SHARED_DIR=$shared
  scene=/tmp/sfgs-fits
  size=${SFGS_DEVICE_FITS_SIZE:-540x960}
  fits_synth() {  # NAME NOISE
    [ -f "$scene/$1/sparse/images.txt" ] && return 0
    run fits-synth 300 "$build/sfgs" synth --out "$scene/$1" --layout neuman --motions sway \
      --body "$shared/bodies/anny_smplx_layout.npz" --texture "$shared/bodies/anny_albedo.png" \
      --frames "${SFGS_DEVICE_FITS_FRAMES:-80}" --width "${size%x*}" --height "${size#*x}" --pose-noise "$2" --force
  }
  fits_synth exact none
  fits_synth noisy "${SFGS_DEVICE_FITS_NOISE:-medium}"
  if [ ! -f "$scene/fitted/smplx_optimized/shape_param.json.fitted" ]; then
    rm -rf "$scene/fitted" && cp -r "$scene/noisy" "$scene/fitted" &&
      run fits-fit 400 "$build/sfgs" fit --data "$scene/fitted" --body "$shared/bodies/anny_smplx_layout.npz" \
        --device cuda --force --quiet &&
      touch "$scene/fitted/smplx_optimized/shape_param.json.fitted"
    tail -n 8 "$out/fits-fit.log"
  fi
  sed "s|@SHARED@|$shared|g" "$root/configs/device_anny.yaml" >"$scene/config.yaml"
  { cat "$scene/config.yaml"; printf 'pose_refinement:\n  enabled: true\n'; } >"$scene/config-refined.yaml"
  fit_iterations=()
  [ -n "${SFGS_DEVICE_FITS_FIT_ITERATIONS:-}" ] && fit_iterations=(--fit-iterations "$SFGS_DEVICE_FITS_FIT_ITERATIONS")
  for variant in ${SFGS_DEVICE_FITS_VARIANTS:-exact noisy refined fitted fitted-refined}; do
    data=$scene/$variant config=$scene/config.yaml start=()
    case $variant in
      refined) data=$scene/noisy config=$scene/config-refined.yaml ;;
      fitted-refined) data=$scene/fitted config=$scene/config-refined.yaml ;;
      refined-round2) data=$scene/noisy config=$scene/config-refined.yaml start=(--start-fits "$scene/run-refined") ;;
      fitted-round2)
        data=$scene/fitted config=$scene/config-refined.yaml start=(--start-fits "$scene/run-fitted-refined")
        ;;
    esac
    run "fits-$variant" 600 "$build/sfgs" train --data "$data" --out "$scene/run-$variant" --config "$config" \
      "${start[@]}" --iterations "${SFGS_DEVICE_FITS_ITERATIONS:-2000}" --force --quiet &&
      run "fits-$variant" 300 "$build/sfgs" eval --run "$scene/run-$variant" --fit-test-poses "${fit_iterations[@]}"
    grep -E "steps|PSNR|sfgs eval" "$out/fits-$variant.log" | grep -v "fitted the pose" | tail -n 8
    grep -h '"pose_alignment"' "$scene/run-$variant/log.jsonl" 2>/dev/null | cut -c1-200
    grep -h '"validation"' "$scene/run-$variant/log.jsonl" 2>/dev/null | tail -n 1 | cut -c1-400
    [ "$variant" = exact ] || continue
    for cross in ${SFGS_DEVICE_FITS_CROSS:-noisy fitted}; do
      [ -d "$scene/$cross" ] || continue
      echo "exact avatar on the $cross test fits:"
      run "fits-exact-on-$cross" 300 "$build/sfgs" eval --run "$scene/run-exact" --data "$scene/$cross" \
        --fit-test-poses "${fit_iterations[@]}"
      grep -E "PSNR" "$out/fits-exact-on-$cross.log" | tail -n 2
    done
  done
fi

# sizes: run time against error over model sizes (docs/performance.md): the novel-motion scene (new motions on test)
# trained with each variant of SFGS_DEVICE_SIZES_VARIANTS (default: subdivision levels 0, 1, 2 and the default with
# 16 plane channels) for SFGS_DEVICE_SIZES_ITERATIONS (default 2000), then each run's animated frame (bench_animate
# --run, 800x1200); scripts/size_table.py prints the table (seconds to a validation PSNR, final PSNR, frames/s).
if wants sizes; then
  export SFGS_DEVICE_NOVEL_SCENES=novel SFGS_DEVICE_NOVEL_ABLATIONS=""
  export SFGS_DEVICE_NOVEL_ITERATIONS=${SFGS_DEVICE_SIZES_ITERATIONS:-2000}
  export SFGS_DEVICE_NOVEL_VARIANTS=${SFGS_DEVICE_SIZES_VARIANTS:-s0:subdivision_levels=0 s1:subdivision_levels=1 s2: s2-c16:plane_channels=16}
  steps+=(novel)
fi

# resolution: the novel step's scenes (SFGS_DEVICE_NOVEL_SCENES), each made again at twice its size, and the default
# run of each evaluated there with and without the sampling filter (issue 41; docs/results.md, "Any resolution").
wants resolution && ! wants novel && steps+=(novel)

if wants novel; then
  export SFGS_SHARED_DIR=$shared
  novel=/tmp/sfgs-novel
  size=${SFGS_DEVICE_NOVEL_SIZE:-540x960}
  iterations=${SFGS_DEVICE_NOVEL_ITERATIONS:-4000}
  variants=${SFGS_DEVICE_NOVEL_VARIANTS-default:}
  baseline_build=/tmp/sfgs-baseline-build
  if [ -n "${SFGS_DEVICE_BASELINE_SRC:-}" ]; then
    variants="$variants baseline:"
    (run baseline-build 400 cmake -S "$SFGS_DEVICE_BASELINE_SRC" -B "$baseline_build" -G Ninja -DCMAKE_BUILD_TYPE=Release \
      -DCMAKE_PREFIX_PATH="$(python3 -c 'import torch; print(torch.utils.cmake_prefix_path)')" -DSFGS_CUDA=ON \
      -DSFGS_BUILD_PYTHON=OFF -DSFGS_EXTRA_INCLUDE_DIRS="$root/.device/include" \
      -DSFGS_GTEST_SOURCE_DIR="$root/.device/googletest" &&
      run baseline-build 400 cmake --build "$baseline_build" -j "$jobs" --target sfgs) &
  fi
  scene_args=(--body "$shared/bodies/anny_smplx_layout.npz" --texture "$shared/bodies/anny_albedo.png"
    --width "${size%x*}" --height "${size#*x}" --force)
  scenes=${SFGS_DEVICE_NOVEL_SCENES:-novel interleaved}
  # The frontal benchmark (issue 41): motions that never show the back to learn from, new motions that do (turn), or
  # show the top of the head (bend), armpits and inner arms (overhead) and soles (kick) to be tested on.
  frames=${SFGS_DEVICE_NOVEL_FRAMES:-40}
  declare -A scene_motions=(
    [novel]="--motions walk,wave,turn --test-motions overhead,bend,guard,sit --frames $frames"
    [frontal]="--motions walk,wave,talk --test-motions turn,bend,overhead,kick,sit,guard --frames $frames"
    [interleaved]="--frames 80")
  for scene in $scenes; do
    # shellcheck disable=SC2086 # the scene's motions are words
    run "novel-synth-$scene" 300 "$build/sfgs" synth --out "$novel/$scene" "${scene_args[@]}" ${scene_motions[$scene]} &
  done
  wait
  tail -q -n 1 "$out"/novel-synth*.log
  # One run at a time: the GPU is the bottleneck (three runs at once take as long as three in a row).
  for variant in $variants; do
    name=${variant%%:*}
    binary=$build/sfgs
    config_source=$root/configs/device_anny.yaml
    [ "$name" = baseline ] && binary=$baseline_build/sfgs && config_source=$SFGS_DEVICE_BASELINE_SRC/configs/device_anny.yaml
    sed "s|@SHARED@|$shared|g" "$config_source" >"$novel/$name.yaml"
    IFS=, read -ra pairs <<<"${variant#*:}"
    for pair in "${pairs[@]}"; do
      [ -z "$pair" ] && continue
      # A key the config already sets is replaced (YAML keeps the last of duplicates), any other one added.
      if grep -q "^  ${pair%%=*}:" "$novel/$name.yaml"; then
        sed -i "s|^  ${pair%%=*}:.*|  ${pair%%=*}: ${pair#*=}|" "$novel/$name.yaml"
      else
        sed -i "s|^avatar:|avatar:\n  ${pair%%=*}: ${pair#*=}|" "$novel/$name.yaml"
      fi
    done
    # The size table times the climb to a PSNR: validate often.
    wants sizes && sed -i "s|^  validate_every:.*|  validate_every: ${SFGS_DEVICE_SIZES_VALIDATE_EVERY:-100}|" "$novel/$name.yaml"
    for scene in $scenes; do
      (run "train-$name-$scene" 580 "$binary" train --data "$novel/$scene" --out "$novel/runs/$name-$scene" \
        --config "$novel/$name.yaml" --iterations "$iterations" --quiet --force &&
        for split in test val; do
          run "eval-$name-$scene-$split" 200 "$binary" eval --run "$novel/runs/$name-$scene" --split "$split" \
            --device cuda --save-images --force &&
            # An earlier version (the baseline) wrote metrics.json for every split.
            { cp "$novel/runs/$name-$scene/metrics_$split.json" "$out/metrics-$name-$scene-$split.json" 2>/dev/null ||
              cp "$novel/runs/$name-$scene/metrics.json" "$out/metrics-$name-$scene-$split.json"; }
        done
        mkdir -p "$out/renders-$name-$scene"
        for frame in 000009 000079 000130 000190 000220 000270; do
          for images in eval_images_test eval_images_val eval_images; do
            cp "$novel/runs/$name-$scene/$images/$frame.png" "$out/renders-$name-$scene/" 2>/dev/null
          done
        done
        if [ "$name" != baseline ]; then
          for ablation in ${SFGS_DEVICE_NOVEL_ABLATIONS-no-observation-prior}; do
            run "eval-$name-$scene-test-$ablation" 200 "$binary" eval --run "$novel/runs/$name-$scene" \
              --device cuda "--$ablation" --force &&
              cp "$novel/runs/$name-$scene/metrics_test_${ablation//-/_}.json" \
                "$out/metrics-$name-$scene-test-$ablation.json"
          done
        fi
        cp "$novel/runs/$name-$scene/log.jsonl" "$out/log-$name-$scene.jsonl")
    done
  done
  grep -h -E "^sfgs eval|^  " "$out"/eval-*.log
  # resolution: each scene's default run on the same scene made at twice the size (the same geometry, twice the
  # pixels), evaluated with and without the sampling filter: PSNR and the person's pixels left uncovered.
  if wants resolution; then
    double_args=(--body "$shared/bodies/anny_smplx_layout.npz" --texture "$shared/bodies/anny_albedo.png"
      --width "$((2 * ${size%x*}))" --height "$((2 * ${size#*x}))" --force)
    for scene in $scenes; do
      [ -f "$novel/runs/default-$scene/checkpoint.pt" ] || continue
      # shellcheck disable=SC2086 # the scene's motions are words
      run "resolution-synth-$scene" 400 "$build/sfgs" synth --out "$novel/$scene-2x" "${double_args[@]}" \
        ${scene_motions[$scene]} || continue
      for flag in "" --no-sampling-filter; do
        run "resolution-eval-$scene${flag:+-unfiltered}" 300 "$build/sfgs" eval --run "$novel/runs/default-$scene" \
          --data "$novel/$scene-2x" --other-dataset --device cuda --force $flag
        grep -E "PSNR|uncovered" "$out/resolution-eval-$scene${flag:+-unfiltered}.log" | head -n 3
      done
    done
  fi
  "$build/sfgs" render --run "$novel/runs/default-novel" --out "$novel/render" --motion bend --frames 24 \
    --device cuda --force >"$out/novel-render.log" 2>&1
  mkdir -p "$out/renders" && cp "$novel/render/frame_0006.png" "$novel/render/frame_0018.png" "$out/renders/" 2>/dev/null
  if wants sizes; then
    names=()
    for variant in $variants; do
      names+=("${variant%%:*}")
      run "frame-${variant%%:*}" 200 "$build/bench/bench_animate" --device cuda --run "$novel/runs/${variant%%:*}-novel" \
        --sizes 800x1200 --frames 100
    done
    python3 "$root/scripts/size_table.py" "$out" "${names[@]}" | tee "$out/size-table.md"
  fi
fi

# The device tool returns only a few files: everything travels as one archive.
if [ "${SFGS_DEVICE_PACK:-1}" = 1 ]; then
  (cd "$out" && tar czf /tmp/device-results.tgz --exclude=device-results.tgz . && find . -mindepth 1 -delete &&
    mv /tmp/device-results.tgz .)
fi

if [ ${#failed[@]} -ne 0 ]; then
  echo "device_check: failed steps: ${failed[*]}"
  exit 1
fi
echo "device_check: all steps passed"
