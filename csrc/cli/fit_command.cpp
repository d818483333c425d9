// `sfgs fit`: SMPL-X fits of a video from whole-body keypoints (fit/fit.h).
#include <c10/util/Exception.h>

#include <cstdio>
#include <sstream>
#include <vector>

#include "cli/commands.h"
#include "fit/fit.h"

namespace sfgs::cli {
namespace {

// "--iterations G,B,D[,S]": Adam steps of the global, body, detail (and silhouette) stages; one number sets all.
fit::FitStageLengths parse_stage_lengths(const std::string& text) {
  std::vector<int64_t> numbers;
  std::stringstream stream(text);
  for (std::string part; std::getline(stream, part, ',');) {
    size_t used = 0;
    int64_t value = -1;
    try {
      value = std::stoll(part, &used);
    } catch (const std::exception&) {
      used = 0;
    }
    TORCH_CHECK(used == part.size() && value >= 0 && value <= 1000000, "--iterations '", text,
                "': expected counts in [0, 1000000] for the stages global,body,detail[,silhouette] (or one count "
                "for all)");
    numbers.push_back(value);
  }
  TORCH_CHECK(numbers.size() >= 1 && numbers.size() <= 4 && numbers.size() != 2, "--iterations '", text,
              "': expected one count or three or four (global,body,detail[,silhouette])");
  fit::FitStageLengths l;
  if (numbers.size() == 1) numbers.assign(4, numbers[0]);
  l.global = numbers[0];
  l.body = numbers[1];
  l.detail = numbers[2];
  if (numbers.size() == 4) l.silhouette = numbers[3];
  return l;
}

}  // namespace

int run_fit(Arguments& args) {
  fit::FitOptions o;
  o.data = args.required("data");
  o.out = args.text("out", "");
  o.body_model = args.text("body", "");
  o.device = args.text("device", o.device);
  o.threads = args.integer("threads", o.threads, 1, 1024);
  o.truth = args.text("truth", "");
  o.focal = args.real("focal", 0.0, 0.0, 1e7);
  o.betas_from_data = args.flag("betas-from-data");
  o.start_from_data = args.flag("start-from-data");
  o.use_masks = !args.flag("no-masks");
  const std::string iterations = args.text("iterations", "");
  if (!iterations.empty()) o.iterations = parse_stage_lengths(iterations);
  o.log_every = args.integer("log-every", o.log_every, 1, 1000000);
  o.overwrite = args.flag("force");
  o.quiet = args.flag("quiet");
  args.finish();
  const fit::FitReport r = fit::run_fit(o);
  const std::string out = o.out.empty() ? o.data : o.out;
  std::printf("sfgs fit: fitted %lld frames in %.1f s (", static_cast<long long>(r.frames), r.seconds);
  for (size_t i = 0; i < r.stages.size(); ++i)
    std::printf("%s%s %.1f s", i ? ", " : "", r.stages[i].name.c_str(), r.stages[i].seconds);
  std::printf("); wrote %s/smplx_optimized\n", out.c_str());
  if (r.trainable_dataset)
    std::printf("sfgs fit: train on these fits with: sfgs train --data %s --out RUN\n", out.c_str());
  if (r.accuracy)
    std::printf(
        "sfgs fit: against %s (%lld frames): MPJPE %.1f mm (absolute %.1f, PA %.1f), hands %.1f mm, "
        "vertices %.1f mm (absolute %.1f), pelvis depth %.1f mm\n",
        r.accuracy->reference.c_str(), static_cast<long long>(r.accuracy->frames), r.accuracy->mpjpe_mm,
        r.accuracy->mpjpe_absolute_mm, r.accuracy->pa_mpjpe_mm, r.accuracy->hand_mpjpe_mm, r.accuracy->vertex_error_mm,
        r.accuracy->vertex_error_absolute_mm, r.accuracy->depth_error_mm);
  return 0;
}

}  // namespace sfgs::cli
