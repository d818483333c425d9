// `sfgs synth`: a synthetic monocular video with exact ground truth (data/synthetic.h).
#include <cstdio>

#include "cli/commands.h"
#include "data/synthetic.h"

namespace sfgs::cli {

int run_synth(Arguments& args) {
  data::SyntheticVideoOptions o;
  const std::string out = args.required("out");
  o.body_model = args.text("body", "");
  o.texture = args.text("texture", "");
  o.frames = args.integer("frames", o.frames, 1, 100000);
  o.width = args.integer("width", o.width, 16, kMaxImageSide);
  o.height = args.integer("height", o.height, 16, kMaxImageSide);
  o.seed = uint64_t(args.integer("seed", int64_t(o.seed), 0, INT64_MAX));
  o.overwrite = args.flag("force");
  args.finish();
  const data::Dataset d = data::write_synthetic_video(out, o);
  std::printf("sfgs synth: wrote %lld frames (%lld train, %lld val, %lld test) of %lld x %lld to %s\n",
              (long long)d.size(), (long long)d.split(data::Split::kTrain).size(),
              (long long)d.split(data::Split::kVal).size(), (long long)d.split(data::Split::kTest).size(),
              (long long)o.width, (long long)o.height, out.c_str());
  return 0;
}

}  // namespace sfgs::cli
