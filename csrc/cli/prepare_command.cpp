// `sfgs prepare`: a video of one person (or a folder of its frames) to a dataset `sfgs train` reads
// (prepare/prepare.h, docs/prepare.md).
#include <c10/util/Exception.h>

#include <cmath>
#include <cstdio>
#include <filesystem>

#include "cli/commands.h"
#include "cli/video.h"
#include "prepare/prepare.h"
#include "prepare/video_metadata.h"

namespace sfgs::cli {

int run_prepare(Arguments& args) {
  const std::string input = args.required("input");
  prepare::PrepareOptions o;
  o.out = args.required("out");
  o.device = args.text("device", o.device);
  o.focal = args.real("focal", 0.0, 0.0, 1e7);
  const std::string model = args.text("model", "full");
  TORCH_CHECK(model == "lite" || model == "full" || model == "heavy", "--model: expected lite, full or heavy, got '",
              model, "'");
  o.model = model == "lite"    ? detect::PoseModel::kLite
            : model == "heavy" ? detect::PoseModel::kHeavy
                               : detect::PoseModel::kFull;
  o.max_frames = args.integer("frames", 0, 0, 10000000);
  const bool folder = std::filesystem::is_directory(input);
  // A phone's video may state its lens; a given --focal wins.
  if (o.focal == 0 && !folder) o.focal_35mm = prepare::focal_length_35mm(input).value_or(0.0);
  const double stated = folder ? 0.0 : video_frame_rate(input);
  o.frames_per_second = args.real("fps", stated > 0 ? stated : 30.0, 1e-3, 1e4);
  o.fit = !args.flag("no-fit");
  o.smooth = !args.flag("no-smoothing");
  o.fit_options.body_model = args.text("body", "");
  o.fit_options.truth = args.text("truth", "");
  o.overwrite = args.flag("force");
  o.quiet = args.flag("quiet");
  args.finish();
  const prepare::FrameSource frames = folder ? prepare::image_folder(input) : read_video(input);
  const prepare::PrepareReport r = prepare::prepare_dataset(frames, o);
  std::string focal_from = "given";
  if (r.focal_source == "metadata")
    focal_from = "from the video's " + std::to_string(std::lround(o.focal_35mm)) + " mm-equivalent lens";
  else if (r.focal_source == "default")
    focal_from = "the default, max(width, height)";
  std::printf("sfgs prepare: %lld of %lld frames show a person (%lld x %lld, focal %.0f px, %s); detection %.1f s",
              (long long)r.frames_with_person, (long long)r.frames, (long long)r.width, (long long)r.height, r.focal,
              focal_from.c_str(), r.detection_seconds);
  if (r.fit) std::printf(", fit %.1f s", r.fit->seconds);
  std::printf("\n");
  if (r.frames_with_several > 0)
    std::printf("sfgs prepare: %lld frames show several people; each followed the largest (prepare_log.jsonl)\n",
                (long long)r.frames_with_several);
  if (r.fit && r.fit->accuracy)
    std::printf("sfgs prepare: the fit against %s: MPJPE %.1f mm (PA %.1f), hands %.1f mm, pelvis depth %.1f mm\n",
                r.fit->accuracy->reference.c_str(), r.fit->accuracy->mpjpe_mm, r.fit->accuracy->pa_mpjpe_mm,
                r.fit->accuracy->hand_mpjpe_mm, r.fit->accuracy->depth_error_mm);
  if (o.fit)
    std::printf("sfgs prepare: wrote %s; train on it with: sfgs train --data %s --out RUN\n", o.out.c_str(),
                o.out.c_str());
  else
    std::printf("sfgs prepare: wrote %s (no fits: sfgs fit --data %s makes them)\n", o.out.c_str(), o.out.c_str());
  return 0;
}

}  // namespace sfgs::cli
