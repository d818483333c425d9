// The sfgs command: synthesise data, train an avatar, evaluate, render, export, run the ablation, the demo and the
// benchmark. `sfgs help` lists everything.
#include <algorithm>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <functional>
#include <iostream>
#include <map>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include <ATen/Parallel.h>
#include <c10/util/Exception.h>
#include <torch/version.h>

#include "common/host_memory.h"
#include "cli/commands.h"
#include "ops/splat/splat.h"

namespace {

constexpr const char* kUsage = R"(usage: sfgs <command> [options]

commands:
  demo     synthesise the built-in body walking, waving and turning, train an avatar on it, evaluate it on new
           motions (overhead, bend, guard, sit) and on held-out frames, render a novel-view/novel-pose video
           --out DIR (sfgs_demo)  --config FILE  --iterations N  --device cpu|cuda  --force
  synth    write a synthetic monocular video with ground truth in sfgs's dataset format
           --out DIR  --body SMPLX.npz (built-in body)  --texture PNG  --width W (256)  --height H (256)
           --motions M,M (sway)  --test-motions M,M (none: interleaved test frames)  --frames N (60 per motion)
           --fps F (30)  --light key|head (key)  --seed S (1)  --force
           --layout sfgs|neuman (sfgs; neuman: NeuMan/ExAvatar folders with smplx_optimized/ and ground_truth/)
           --pose-noise none|low|medium|high[,key=value] (none: exact fits; docs/fitting.md)
           --keypoint-noise detector|none (detector: whole-body keypoints as a detector reports them)
  fit      SMPL-X fits from whole-body keypoints (keypoints_whole_body/N.json, 133 x [x, y, score]) into
           OUT/smplx_optimized (NeuMan/ExAvatar layout; docs/fitting.md): --data DIR  --out DIR (DIR)
           --body SMPLX.npz (built-in body)  --device cpu|cuda  --threads N (1)
           --iterations G,B,D[,S] (80,600,1200,200)  --focal PX (the dataset's, else max(W, H))  --betas-from-data
           --start-from-data (DIR/smplx_optimized as the start)  --no-masks  --truth DIR (DIR/ground_truth)
           --log-every N (25)  --force  --quiet
  prepare  a dataset from a video of one person (or a folder of its frames; docs/prepare.md): tracks the person
           (MediaPipe's pose networks run in sfgs), writes frames, masks, whole-body keypoints and a camera in the
           NeuMan layout, then fits SMPL-X (sfgs fit): VIDEO|DIR --out DATASET  --device cpu|cuda  --focal PX
           (max(W, H))  --model lite|full|heavy (full)  --frames N (all)  --fps F (the video's, else 30)
           --body SMPLX.npz  --no-fit  --no-smoothing (landmarks as each frame gives them)
           --truth DIR (exact fits to measure the fit against)  --force  --quiet
  train    train an avatar: --data DATASET --out RUN  --config FILE  --iterations N  --device cpu|cuda
           --stop-at N (pause there, resumable)  --force  --quiet
           --start-fits RUN|FILE: the training frames start from an earlier run's refined fits (a second round
           on imperfect fits; docs/training.md)
           --resume: continue RUN with its own config and dataset (--data, --config optional; only schedule and
           logging keys may change)
  eval     evaluate a run on a split (ExAvatar/SFGS protocol), written to RUN/metrics_SPLIT.json with its
           provenance (split, dataset fingerprint, checkpoint iteration and CRC-32, command, time); training on
           removes results of the checkpoint it replaces: --run RUN  --data DATASET (the training one; moved)
           --other-dataset: evaluate on another dataset than the run's (RUN/metrics_SPLIT_FINGERPRINT.json)
           --split test|val|train (test)  --device cpu|cuda (the run's)  --eight-bit  --force
           --save-images (RUN/eval_images_SPLIT/)
           --no-observation-prior (trust every Gaussian's learned colour and offsets: the ablation;
           metrics_SPLIT_no_observation_prior.json)
           --no-sampling-filter (render finer than the training views without widening the Gaussians to the
           training's blur: the ablation; metrics_SPLIT_no_sampling_filter.json)
           --fit-test-poses: also fit each frame's pose to its image with the avatar frozen (NeuMan protocol;
           coarse to fine, never ending worse than the given fit on its loss), reported separately
           (metrics_SPLIT_fitted_poses.json)  --fit-iterations N (300 loss evaluations)
           --fit-keypoint-weight W (1; 0: the image alone) of the frames' keypoints_whole_body/ detections
  render   novel poses to PNG frames and an MP4: --run RUN --out DIR  --frames N (48; a file: all of it)
           --motion MOTION|DATASET|FILE.npz|FOLDER (overhead; motions: sway walk wave overhead bend guard turn
           sit; FILE.npz: AMASS SMPL-X or SMPL-H; FOLDER: ExAvatar smplx_params_smoothed; docs/motions.md)  --fps F (24)
           --camera orbit|fixed|follow (the dataset's camera orbiting; a motion file: follow)
           --distance M (2.8)  --height M (0)  --size WxH (the dataset's)
           --data DATASET (the training one)  --device cpu|cuda (the run's)
           --force: replace the earlier render in DIR (the files its render.json lists; a file no render
           wrote is an error naming it, --force or not)
  export   the avatar's Gaussians: --run RUN --out FILE.ply (3DGS) | FILE.splat (web viewers)  --frame K (canonical)
           --data DATASET (the training one, for --frame)  --force
           or the animated avatar for web browsers (DIR/index.html, WebGL2; docs/web_viewer.md): --run RUN --web DIR
           --motion as render's (overhead)  --frames N (48; a file: all of it)  --fps F (24)  --size WxH (the
           dataset's)  --distance M (2.8)  --height M (0)  --data DATASET  --force (replaces an earlier export)
  ablate   the paper's ablation table: --data DATASET --out DIR  --config FILE  --iterations N  --force
  bench    render the built-in Gaussian scene and print forward/backward timings
           --gaussians N (60000)  --width W (640)  --height H (480)  --repeats R (5)  --device cpu|cuda
           --out PNG  --force
  help     print this text (sfgs COMMAND --help: that command's alone)
  version  print sfgs's version, its LibTorch's and whether it has the CUDA backend (also --version)

Options take their value as the next argument or after '=' (--out=DIR); a value that starts with -- must use '='.
)";

// The usage of one command: its lines of kUsage and the note on options below them.
std::string command_usage(const std::string& command) {
  const std::string text = kUsage;
  const size_t start = text.find("\n  " + command + " ");
  if (start == std::string::npos) return text;
  // The command's lines: its own, then those indented further (up to a line that starts another command).
  size_t end = text.find('\n', start + 1);
  while (end != std::string::npos && text.compare(end + 1, 3, "   ") == 0) end = text.find('\n', end + 1);
  const size_t options = text.find("\nOptions take");
  return "usage: sfgs " + command + " [options]\n" + text.substr(start, end - start) + "\n" + text.substr(options);
}

}  // namespace

int main(int argc, char** argv) {
  sfgs::reuse_freed_host_memory();
  // Past a file size limit, writes should fail with EFBIG and be reported like a full disk, not kill the process.
  std::signal(SIGXFSZ, SIG_IGN);
  // Line-buffered even into a pipe or file, so the step messages interleave with the progress lines on stderr.
  std::setvbuf(stdout, nullptr, _IOLBF, 0);
  // OpenMP may start with one thread; use every core unless the user chose with OMP_NUM_THREADS.
  if (!std::getenv("OMP_NUM_THREADS")) at::set_num_threads(int(std::max(1u, std::thread::hardware_concurrency())));
  const std::string command = argc > 1 ? argv[1] : "help";
  const std::map<std::string, std::pair<std::function<int(sfgs::cli::Arguments&)>, std::set<std::string>>> commands = {
      {"demo", {sfgs::cli::run_demo, {"force"}}},
      {"synth", {sfgs::cli::run_synth, {"force"}}},
      {"fit", {sfgs::cli::run_fit, {"betas-from-data", "start-from-data", "no-masks", "force", "quiet"}}},
      {"prepare", {sfgs::cli::run_prepare, {"no-fit", "no-smoothing", "force", "quiet"}}},
      {"train", {sfgs::cli::run_train, {"resume", "force", "quiet"}}},
      {"eval",
       {sfgs::cli::run_eval,
        {"eight-bit", "save-images", "no-observation-prior", "no-sampling-filter", "fit-test-poses", "other-dataset",
         "force"}}},
      {"render", {sfgs::cli::run_render, {"force"}}},
      {"export", {sfgs::cli::run_export, {"force"}}},
      {"ablate", {sfgs::cli::run_ablate, {"force"}}},
      {"bench", {sfgs::cli::run_bench, {"force"}}},
  };
  const auto asks_for_help = [](const char* a) {
    return std::string(a) == "help" || std::string(a) == "--help" || std::string(a) == "-h";
  };
  if (command == "version" || command == "--version") {
    std::cout << "sfgs " << SFGS_VERSION << " (LibTorch " << TORCH_VERSION << ", CUDA backend "
              << (sfgs::cuda_backend_available() ? "built in" : "not built") << ")\n";
    return 0;
  }
  if (std::any_of(argv + 1, argv + std::max(argc, 1), asks_for_help) || argc < 2) {
    std::cout << (commands.count(command) ? command_usage(command) : std::string(kUsage));
    return 0;
  }
  const auto it = commands.find(command);
  if (it == commands.end()) {
    std::cerr << "sfgs: unknown command '" << command << "'\n" << kUsage;
    return 2;
  }
  try {
    std::vector<std::string> given(argv + 2, argv + argc);
    // `sfgs prepare VIDEO ...`: the input may come first, without its option name.
    if (command == "prepare" && !given.empty() && given[0].rfind("--", 0) != 0) given[0] = "--input=" + given[0];
    sfgs::cli::Arguments args(given, it->second.second);
    return it->second.first(args);
  } catch (const c10::Error& e) {
    std::cerr << "sfgs " << command << ": " << e.what_without_backtrace() << "\n";
    return 1;
  } catch (const std::exception& e) {
    std::cerr << "sfgs " << command << ": " << e.what() << "\n";
    return 1;
  }
}
