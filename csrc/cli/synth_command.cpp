// `sfgs synth`: a synthetic monocular video with exact ground truth (data/synthetic.h).
#include <chrono>
#include <cstdio>

#include "cli/commands.h"
#include "data/motions.h"
#include "data/synthetic.h"
#include "ops/splat/constants.h"

namespace sfgs::cli {

int run_synth(Arguments& args) {
  data::SyntheticVideoOptions o;
  const std::string out = args.required("out");
  o.body_model = args.text("body", "");
  o.texture = args.text("texture", "");
  o.motions = data::parse_motion_list(args.text("motions", "sway"), "--motions");
  const std::string test_motions = args.text("test-motions", "");
  if (!test_motions.empty()) o.test_motions = data::parse_motion_list(test_motions, "--test-motions");
  o.frames = args.integer("frames", o.frames, 1, 100000);
  o.frames_per_second = args.real("fps", o.frames_per_second, 1e-3, 1e4);
  const std::string light = args.text("light", "key");
  TORCH_CHECK(light == "key" || light == "head",
              "--light: expected 'key' (fixed in the world, with shadows) or "
              "'head' (at the camera), got '",
              light, "'");
  o.key_light = light == "key";
  o.width = args.integer("width", o.width, 16, kMaxImageSide);
  o.height = args.integer("height", o.height, 16, kMaxImageSide);
  o.seed = uint64_t(args.integer("seed", int64_t(o.seed), 0, INT64_MAX));
  o.overwrite = args.flag("force");
  const std::string layout = args.text("layout", "sfgs");
  TORCH_CHECK(layout == "sfgs" || layout == "neuman",
              "--layout: expected 'sfgs' (dataset.json) or 'neuman' "
              "(NeuMan/ExAvatar folders), got '",
              layout, "'");
  o.layout = layout == "sfgs" ? data::DatasetLayout::kSfgs : data::DatasetLayout::kNeuman;
  o.pose_noise = data::pose_noise_level(args.text("pose-noise", "none"));
  const std::string keypoint_noise = args.text("keypoint-noise", "detector");
  TORCH_CHECK(keypoint_noise == "detector" || keypoint_noise == "none",
              "--keypoint-noise: expected 'detector' "
              "(noise, low scores, dropped points and outliers as a detector reports) or 'none' (exact), got '",
              keypoint_noise, "'");
  o.keypoint_noise.exact = keypoint_noise == "none";
  args.finish();
  // A line at every tenth of the frames (the rendering is most of the time).
  const auto started = std::chrono::steady_clock::now();
  int64_t last_tenth = 0;
  o.progress = [&](int64_t done, int64_t total) {
    const int64_t tenth = 10 * done / total;
    if (tenth == last_tenth || done == total) return;
    last_tenth = tenth;
    std::printf("sfgs synth: %lld of %lld frames rendered (%.0f s)\n", (long long)done, (long long)total,
                std::chrono::duration<double>(std::chrono::steady_clock::now() - started).count());
    std::fflush(stdout);
  };
  const data::Dataset d = data::write_synthetic_video(out, o);
  std::printf("sfgs synth: wrote %lld frames (%lld train, %lld val, %lld test%s) of %lld x %lld to %s\n",
              (long long)d.size(), (long long)d.split(data::Split::kTrain).size(),
              (long long)d.split(data::Split::kVal).size(), (long long)d.split(data::Split::kTest).size(),
              o.test_motions.empty() ? ", interleaved" : (": new motions " + test_motions).c_str(), (long long)o.width,
              (long long)o.height, out.c_str());
  if (!o.pose_noise.is_zero())
    std::printf("sfgs synth: fits corrupted at level %s (the exact ones in %s)\n", o.pose_noise.name.c_str(),
                o.layout == data::DatasetLayout::kSfgs ? "dataset.json: smplx_truth, betas_truth" : "ground_truth/");
  return 0;
}

}  // namespace sfgs::cli
