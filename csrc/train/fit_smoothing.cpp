#include "train/fit_smoothing.h"

#include <algorithm>
#include <cmath>
#include <set>

#include <ATen/ATen.h>

#include "body/rotations.h"
#include "train/constants.h"

namespace sfgs::train {
namespace {

// The weights w_k with sum_k w_k y_k = the value at time 0 of the polynomial of degree `order` fitted to (u_k, y_k)
// by least squares with Gaussian weights exp(-u_k^2 / 2): row 0 of (X^T W X)^-1 X^T W, X = [1, u, u^2, ...].
// `u` are the neighbours' time offsets in standard deviations; `order` is at most their distinct times less one.
at::Tensor regression_weights(const at::Tensor& u, int64_t order) {
  const at::Tensor gaussian = at::exp(-0.5 * u * u);
  std::vector<at::Tensor> columns;
  for (int64_t p = 0; p <= order; ++p) columns.push_back(u.pow(double(p)));
  const at::Tensor x = at::stack(columns, 1);                // (K, order + 1)
  const at::Tensor weighted = x.transpose(0, 1) * gaussian;  // X^T W
  return at::linalg_solve(weighted.matmul(x), weighted)[0];  // (K)
}

// Of each axis-angle of `a` (R, 3), the representative nearest the same row of `near`: a or the same rotation the
// other way round its axis, a - 2 pi a / |a| (matrix_to_axis_angle gives angles in [0, pi]; an estimator may write
// -3.1 rad about x where the smoothed rotation reads 3.1).
at::Tensor nearest_representatives(const at::Tensor& a, const at::Tensor& near) {
  const at::Tensor angle = a.norm(2, 1, true);
  const at::Tensor other = a * ((angle - 2 * M_PI) / angle.clamp_min(kFitSmoothingSmallAngle));
  const at::Tensor closer = (other - near).norm(2, 1, true) < (a - near).norm(2, 1, true);
  return at::where(closer, other, a);
}

}  // namespace

at::Tensor smooth_fits(const at::Tensor& fits, int64_t rotations, const std::vector<double>& times,
                       const std::vector<int64_t>& sequences, double sigma_seconds) {
  TORCH_CHECK(fits.dim() == 2 && rotations >= 0 && fits.size(1) >= 3 * rotations,
              "smooth_fits: fits must be (F, 3 R + L) with R = ", rotations, " axis-angles, got shape ", fits.sizes());
  const int64_t frames = fits.size(0);
  TORCH_CHECK(int64_t(times.size()) == frames && int64_t(sequences.size()) == frames, "smooth_fits: ", frames,
              " fits need as many times and sequences, got ", times.size(), " and ", sequences.size());
  TORCH_CHECK(std::isfinite(sigma_seconds) && sigma_seconds >= 0,
              "smooth_fits: sigma_seconds must be finite and >= 0, got ", sigma_seconds);
  if (sigma_seconds == 0 || frames < 2) return fits.clone();
  const at::Tensor rows = fits.detach().to(at::kCPU, at::kDouble).contiguous();
  const at::Tensor axis_angles = rows.narrow(1, 0, 3 * rotations).view({frames, rotations, 3});
  const at::Tensor linear = rows.narrow(1, 3 * rotations, rows.size(1) - 3 * rotations);
  const at::Tensor matrices = body::axis_angle_to_matrix(axis_angles);  // (F, R, 3, 3)
  at::Tensor smoothed = rows.clone();
  const double reach = kFitSmoothingWindowSigmas * sigma_seconds;
  for (int64_t c = 0; c < frames; ++c) {
    std::vector<int64_t> near;
    std::set<double> distinct;
    for (int64_t k = 0; k < frames; ++k)
      if (sequences[size_t(k)] == sequences[size_t(c)] && std::abs(times[size_t(k)] - times[size_t(c)]) <= reach) {
        near.push_back(k);
        distinct.insert(times[size_t(k)]);
      }
    if (distinct.size() < 2) continue;  // nothing beside it in time
    const at::Tensor index = at::tensor(near, at::kLong);
    std::vector<double> offsets;
    for (const int64_t k : near) offsets.push_back((times[size_t(k)] - times[size_t(c)]) / sigma_seconds);
    const int64_t order = std::min<int64_t>(kFitSmoothingOrder, int64_t(distinct.size()) - 1);
    const at::Tensor w = regression_weights(at::tensor(offsets, at::kDouble), order);  // (K)
    smoothed[c].narrow(0, 3 * rotations, linear.size(1)).copy_(w.matmul(linear.index_select(0, index)));
    if (rotations == 0) continue;
    // Each neighbour's rotation as a turn from this frame's, regressed in that tangent space and applied back.
    const at::Tensor own = matrices[c];  // (R, 3, 3)
    const at::Tensor turns = body::matrix_to_axis_angle(own.transpose(1, 2).matmul(matrices.index_select(0, index)));
    const at::Tensor turn = (w.view({-1, 1, 1}) * turns).sum(0);  // (R, 3)
    const at::Tensor result = body::matrix_to_axis_angle(own.matmul(body::axis_angle_to_matrix(turn)));
    smoothed[c].narrow(0, 0, 3 * rotations).copy_(nearest_representatives(result, axis_angles[c]).reshape({-1}));
  }
  return smoothed.to(fits.options());
}

}  // namespace sfgs::train
