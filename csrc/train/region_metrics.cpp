#include "train/region_metrics.h"

#include <algorithm>
#include <cmath>
#include <filesystem>

#include <ATen/ATen.h>

#include "body/tensor_checks.h"
#include "common/constants.h"
#include "data/mesh_renderer.h"
#include "io/npz.h"
#include "model/constants.h"
#include "train/constants.h"

namespace sfgs::train {
namespace fs = std::filesystem;

namespace {

constexpr int64_t kHandsRegion = 2;  // both hands (body::BodyPart 2 and 3) count as one region

at::Tensor read_checked(const fs::path& path, at::ScalarType dtype, int64_t length, const char* what) {
  const at::Tensor t = io::read_npy(path.string());
  TORCH_CHECK(t.scalar_type() == dtype && t.dim() == 1 && (length < 0 || t.size(0) == length), "'", path.string(),
              "': expected ", what, " of ", length, " ", c10::toString(dtype), " values, got ", describe(t));
  return t;
}

}  // namespace

std::optional<RegionTruth> read_region_truth(const data::Dataset& dataset) {
  if (dataset.frames.empty() || dataset.frames[0].mesh_path.empty()) return std::nullopt;
  const fs::path folder = fs::path(dataset.frames[0].mesh_path).parent_path();
  for (const char* file : {"faces.npy", "regions.npy", "observation.npy"})
    if (!fs::exists(folder / file)) return std::nullopt;
  RegionTruth truth;
  truth.faces = io::read_npy((folder / "faces.npy").string());
  TORCH_CHECK(truth.faces.scalar_type() == at::kLong && truth.faces.dim() == 2 && truth.faces.size(1) == 3, "'",
              (folder / "faces.npy").string(), "': expected int64 (F, 3) triangles, got ", describe(truth.faces));
  const at::Tensor regions = read_checked(folder / "regions.npy", at::kLong, -1, "a body region per vertex");
  const int64_t vertices = regions.size(0);
  const at::Tensor observation =
      read_checked(folder / "observation.npy", at::kFloat, vertices, "an observation share per vertex");
  TORCH_CHECK(truth.faces.numel() == 0 || truth.faces.max().item<int64_t>() < vertices, "'",
              (folder / "faces.npy").string(), "' names vertices beyond the ", vertices, " of regions.npy");
  const at::Tensor corner = regions.clamp_max(kHandsRegion).index_select(0, truth.faces.flatten()).view({-1, 3});
  const at::Tensor a = corner.select(1, 0), b = corner.select(1, 1), c = corner.select(1, 2);
  truth.face_region = at::where((b == c) & (b != a), b, a);  // the majority, or the first corner's
  truth.face_seen =
      std::get<0>(observation.index_select(0, truth.faces.flatten()).view({-1, 3}).min(1)) >= kWellObservedFraction;
  return truth;
}

std::vector<std::pair<std::string, at::Tensor>> region_masks(const RegionTruth& truth, const at::Tensor& vertices,
                                                             const Camera& camera, const at::Tensor& eval_mask) {
  data::TexturedMesh mesh;
  mesh.vertices = vertices;
  mesh.faces = truth.faces;
  const at::Tensor face = data::render_mesh(mesh, camera, at::ones({3})).face;
  const at::Tensor covered = (face >= 0) & (eval_mask.cpu() > 0.5);
  const at::Tensor index = face.clamp_min(0).flatten();
  const at::Tensor region = truth.face_region.index_select(0, index).view_as(face);
  const at::Tensor seen = truth.face_seen.index_select(0, index).view_as(face);
  return {{"body", covered & (region == 0)},
          {"face", covered & (region == 1)},
          {"hands", covered & (region == kHandsRegion)},
          {"seen", covered & seen},
          {"unseen", covered & seen.logical_not()}};
}

void UnseenCount::add(const at::Tensor& mask, const at::Tensor& unseen_mask) {
  labelled += double(mask.sum().item<int64_t>());
  unseen += double((mask & unseen_mask).sum().item<int64_t>());
}

std::optional<double> UnseenCount::share() const {
  if (labelled <= 0) return std::nullopt;
  return unseen / labelled;
}

namespace {

const at::Tensor* find_mask(const std::vector<std::pair<std::string, at::Tensor>>& masks, const std::string& name) {
  for (const auto& [mask_name, mask] : masks)
    if (mask_name == name) return &mask;
  return nullptr;
}

}  // namespace

const at::Tensor& region_mask(const std::vector<std::pair<std::string, at::Tensor>>& masks, const std::string& name) {
  const at::Tensor* mask = find_mask(masks, name);
  TORCH_CHECK(mask, "region_mask: no mask named '", name, "'");
  return *mask;
}

at::Tensor labelled_person(const std::vector<std::pair<std::string, at::Tensor>>& masks) {
  return region_mask(masks, "seen") | region_mask(masks, "unseen");
}

void RegionAccumulator::add(const at::Tensor& prediction, const at::Tensor& target,
                            const std::vector<std::pair<std::string, at::Tensor>>& masks) {
  if (const at::Tensor* unseen = find_mask(masks, "unseen"))
    for (const char* region : {"body", "face", "hands"})
      if (const at::Tensor* mask = find_mask(masks, region)) unseen_[region].add(*mask, *unseen);
  const at::Tensor p = prediction.detach().cpu().to(at::kDouble), t = target.detach().cpu().to(at::kDouble);
  const at::Tensor difference = p - t;
  const at::Tensor squared_error = difference.pow(2).mean(2);
  at::Tensor ssim = metrics::ssim_map(p, t, border_);
  const int64_t crop = (p.size(0) - ssim.size(0)) / 2;  // the valid border's map is smaller
  for (const auto& [name, mask] : masks) {
    auto it = std::find_if(sums_.begin(), sums_.end(), [&](const GroupScore& s) { return s.name == name; });
    if (it == sums_.end()) {
      GroupScore fresh;
      fresh.name = name;
      sums_.push_back(fresh);
      it = sums_.end() - 1;
    }
    const int64_t pixels = mask.sum().item<int64_t>();
    if (pixels < kMinRegionPixels) continue;
    const double mse = squared_error.masked_select(mask).mean().item<double>();
    const at::Tensor inner = mask.slice(0, crop, mask.size(0) - crop).slice(1, crop, mask.size(1) - crop);
    it->frames += 1;
    it->pixels += double(pixels);
    it->psnr += 10.0 * std::log10(kImageDataRange * kImageDataRange / std::max(mse, kMinRegionMse));
    it->ssim += inner.any().item<bool>() ? ssim.masked_select(inner).mean().item<double>() : 1.0;
    const at::Tensor bias = difference.masked_select(mask.unsqueeze(2)).view({-1, 3}).mean(0);
    for (int64_t c = 0; c < 3; ++c) it->signed_error[size_t(c)] += bias[c].item<double>();
  }
}

std::vector<GroupScore> RegionAccumulator::summary() const {
  std::vector<GroupScore> out;
  for (GroupScore s : sums_) {
    if (s.frames > 0) {
      s.pixels /= double(s.frames);
      s.psnr /= double(s.frames);
      s.ssim /= double(s.frames);
      for (double& e : s.signed_error) e /= double(s.frames);
    }
    if (const auto it = unseen_.find(s.name); it != unseen_.end()) s.unseen_share = it->second.share();
    out.push_back(s);
  }
  return out;
}

}  // namespace sfgs::train
