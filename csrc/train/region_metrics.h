#pragma once
// Where the error is: image metrics per body region (body, face, hands) and per observation class (surface the
// training frames showed, "seen", and surface they never or rarely showed, "unseen"), from the ground-truth
// geometry a synthetic dataset carries (meshes/faces.npy, regions.npy, observation.npy; docs/dataset_format.md).
// docs/metrics.md defines them.
#include <array>
#include <map>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <ATen/core/Tensor.h>

#include "data/dataset.h"
#include "metrics/image_metrics.h"
#include "model/constants.h"
#include "train/constants.h"

namespace sfgs::train {

struct RegionTruth {
  at::Tensor faces;        // (F, 3) int64
  at::Tensor face_region;  // (F) int64: 0 body, 1 face, 2 hands (the majority of its corners; ties: the first's)
  at::Tensor face_seen;    // (F) bool: every corner seen in at least kWellObservedFraction of the training frames
};

// The dataset's region ground truth: from the folder of its first frame's ground-truth mesh, when faces.npy,
// regions.npy and observation.npy are all there (nullopt otherwise). Files of the wrong shape or type are errors
// naming the file.
std::optional<RegionTruth> read_region_truth(const data::Dataset& dataset);

// Region masks (H, W) bool of one frame: the ground-truth mesh `vertices` (V, 3) rasterised with `camera`, each
// pixel labelled by its visible face, restricted to the evaluation mask (> 0.5). Names: body, face, hands, seen,
// unseen.
std::vector<std::pair<std::string, at::Tensor>> region_masks(const RegionTruth& truth, const at::Tensor& vertices,
                                                             const Camera& camera, const at::Tensor& eval_mask);

// Metrics of one group of frames (a motion) or of one region over the frames that show it.
struct GroupScore {
  std::string name;
  int64_t frames = 0;
  double pixels = 0;  // mean region pixels per counted frame (regions only)
  double psnr = 0, ssim = 0;
  std::optional<double> lpips;  // motions only
  // Of the person's pixels (a motion's) or the region's (body, face, hands), the share the training never or rarely
  // showed ("unseen"), over all the frames; where the dataset has ground-truth geometry.
  std::optional<double> unseen_share;
  // Regions only: the mean of render minus truth over the region's pixels, per channel (R, G, B, in the image's
  // units), averaged over the counted frames: a region rendered too bright or too dark shows as a bias.
  std::array<double, 3> signed_error{};
};

// Unseen and labelled pixels counted over frames: the share of a motion or a region the training never or rarely
// showed.
struct UnseenCount {
  double unseen = 0, labelled = 0;
  void add(const at::Tensor& mask, const at::Tensor& unseen_mask);
  std::optional<double> share() const;
};

// Averages PSNR (over the region's pixels) and SSIM (the SSIM map averaged over them) per region over the frames in
// which the region has at least kMinRegionPixels pixels.
class RegionAccumulator {
 public:
  explicit RegionAccumulator(metrics::SsimBorder border) : border_(border) {}
  // prediction and target (H, W, 3) as the evaluation compares them (composited on white).
  // Where the masks hold region_masks' "unseen", also counts how much of each body region (body, face, hands) is.
  void add(const at::Tensor& prediction, const at::Tensor& target,
           const std::vector<std::pair<std::string, at::Tensor>>& masks);
  std::vector<GroupScore> summary() const;

 private:
  metrics::SsimBorder border_;
  std::vector<GroupScore> sums_;               // running sums, in the order regions first appear
  std::map<std::string, UnseenCount> unseen_;  // per body region
};

// The labelled person (seen or unseen) and the unseen pixels of region_masks' masks.
at::Tensor labelled_person(const std::vector<std::pair<std::string, at::Tensor>>& masks);
const at::Tensor& region_mask(const std::vector<std::pair<std::string, at::Tensor>>& masks, const std::string& name);

}  // namespace sfgs::train
