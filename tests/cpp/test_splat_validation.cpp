// Invalid inputs are errors with messages that say what was expected and what came (docs/splatting.md).
#include <array>
#include <cmath>
#include <functional>
#include <limits>
#include <string>

#include <gtest/gtest.h>

#include "splat_test_utils.h"

namespace sfgs::testing {
namespace {

void expect_spoiled_scene_error(const std::function<void(TestScene&)>& spoil, const std::string& message,
                                int64_t count = 4) {
  SceneSpec spec;
  spec.count = count;
  TestScene s = random_scene(spec, 2);
  spoil(s);
  try {
    render(s.gaussians, s.background, s.camera);
    ADD_FAILURE() << "expected an error containing '" << message << "'";
  } catch (const c10::Error& e) {
    EXPECT_NE(std::string(e.what_without_backtrace()).find(message), std::string::npos)
        << "message was: " << e.what_without_backtrace();
  }
}

TEST(SplatValidation, ShapesAreChecked) {
  expect_spoiled_scene_error([](TestScene& s) { s.gaussians.means = s.gaussians.means.narrow(1, 0, 2); },
                             "means must have shape (N, 3), got a Double tensor of shape [4, 2]");
  expect_spoiled_scene_error([](TestScene& s) { s.gaussians.scales = s.gaussians.scales.narrow(0, 0, 3); },
                             "scales must have shape (4, 3)");
  expect_spoiled_scene_error([](TestScene& s) { s.gaussians.rotations = s.gaussians.rotations.narrow(1, 0, 3); },
                             "rotations must have shape (4, 4)");
  expect_spoiled_scene_error(
      [](TestScene& s) {
        s.gaussians.opacities = s.gaussians.opacities.view({2, 2});
      },
      "opacities must have shape (N) or (N, 1) with N = 4");
  expect_spoiled_scene_error([](TestScene& s) { s.gaussians.features = s.gaussians.features.view({-1}); },
                             "features must have shape (4, C)");
  expect_spoiled_scene_error([](TestScene& s) { s.gaussians.features = s.gaussians.features.narrow(1, 0, 0); },
                             "features need at least one channel");
  expect_spoiled_scene_error([](TestScene& s) { s.background = s.background.narrow(0, 0, 2); },
                             "background must have shape (C) with C = 3");
}

TEST(SplatValidation, ExactlyOneCovarianceParameterisation) {
  expect_spoiled_scene_error(
      [](TestScene& s) {
        s.gaussians.covariances = at::zeros({4, 6}, at::kDouble);
      },
      "got both");
  expect_spoiled_scene_error(
      [](TestScene& s) {
        s.gaussians.scales = at::Tensor();
        s.gaussians.rotations = at::Tensor();
      },
      "got neither");
  expect_spoiled_scene_error([](TestScene& s) { s.gaussians.rotations = at::Tensor(); }, "rotations must be given");
}

TEST(SplatValidation, DtypesAndDevicesAreChecked) {
  expect_spoiled_scene_error([](TestScene& s) { s.gaussians.means = s.gaussians.means.to(at::kInt); },
                             "must be float32 or float64");
  expect_spoiled_scene_error([](TestScene& s) { s.gaussians.scales = s.gaussians.scales.to(at::kFloat); },
                             "scales must have the dtype of means (Double), got a Float tensor");
  expect_spoiled_scene_error([](TestScene& s) { s.background = s.background.to(at::kFloat); },
                             "background must have the dtype");
  expect_spoiled_scene_error(
      [](TestScene& s) {
        s.gaussians.means = at::empty({4, 3}, at::TensorOptions(at::kMeta).dtype(at::kDouble));
      },
      "must be on the CPU or a CUDA device");
}

TEST(SplatValidation, CameraIsChecked) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  expect_spoiled_scene_error([](TestScene& s) { s.camera.fx = 0; }, "focal lengths must be finite and positive");
  expect_spoiled_scene_error([nan](TestScene& s) { s.camera.fy = nan; }, "focal lengths must be finite and positive");
  expect_spoiled_scene_error([nan](TestScene& s) { s.camera.cx = nan; }, "principal point must be finite");
  expect_spoiled_scene_error([](TestScene& s) { s.camera.width = 0; }, "image sides must be in [1, 16384], got 0 x 29");
  expect_spoiled_scene_error([](TestScene& s) { s.camera.height = 20000; }, "image sides must be in [1, 16384]");
  expect_spoiled_scene_error([](TestScene& s) { s.camera.near_plane = 0; }, "near_plane must be finite and positive");
  expect_spoiled_scene_error([](TestScene& s) { s.camera.far_plane = s.camera.near_plane; },
                             "far_plane must exceed near_plane");
  expect_spoiled_scene_error([](TestScene& s) { s.camera.world_to_camera[14] = 1; },
                             "last row of world_to_camera must be");
  expect_spoiled_scene_error([nan](TestScene& s) { s.camera.world_to_camera[3] = nan; },
                             "world_to_camera must be finite");
  EXPECT_THROW(Camera::from_tensor(at::eye(3), 1, 1, 0, 0, 4, 4), c10::Error);
}

// The adversarial cases that used to render a wrong image without a word: R = 0, a zero row, rank 1, a scale, a
// mirror. Each is refused with the deviation and determinant it has.
TEST(SplatValidation, SingularOrImproperRotationsAreRefused) {
  const auto set_rotation = [](TestScene& s, std::array<double, 9> r) {
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) s.camera.world_to_camera[size_t(4 * i + j)] = r[size_t(3 * i + j)];
  };
  const std::string message = "rotation part of world_to_camera must be orthonormal with determinant +1";
  expect_spoiled_scene_error(
      [&](TestScene& s) {
        set_rotation(s, {0, 0, 0, 0, 0, 0, 0, 0, 0});
      },
      message + " (max |R R^T - I| <= 0.0001), got max |R R^T - I| = 1 and det R = 0");
  expect_spoiled_scene_error([&](TestScene& s) { set_rotation(s, {1, 0, 0, 0, 0, 0, 0, 0, 1}); }, message);
  expect_spoiled_scene_error([&](TestScene& s) { set_rotation(s, {1, 0, 0, 1, 0, 0, 1, 0, 0}); }, message);
  expect_spoiled_scene_error([&](TestScene& s) { set_rotation(s, {2, 0, 0, 0, 2, 0, 0, 0, 2}); }, message);
  expect_spoiled_scene_error([&](TestScene& s) { set_rotation(s, {-1, 0, 0, 0, 1, 0, 0, 0, 1}); }, "det R = -1");
  // A rotation stored with seven significant digits is accepted.
  SceneSpec spec;
  spec.count = 4;
  TestScene s = random_scene(spec, 2);
  const double c = std::cos(0.3), sn = std::sin(0.3);
  const auto rounded = [](double v) { return std::round(v * 1e7) / 1e7; };
  set_rotation(s, {rounded(c), 0, rounded(sn), 0, 1, 0, rounded(-sn), 0, rounded(c)});
  EXPECT_TRUE(camera_problem(s.camera).empty()) << camera_problem(s.camera);
}

// Opacities arrive activated: a value outside [0, 1] or not finite is a bug upstream, named with how many there are and
// the first of them.
TEST(SplatValidation, OpacitiesOutsideTheUnitIntervalAreErrors) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  expect_spoiled_scene_error(
      [nan](TestScene& s) {
        s.gaussians.opacities[17] = 5.0;
        s.gaussians.opacities[100] = nan;
        s.gaussians.opacities[3999] = -0.5;
      },
      "sfgs::render: opacities must be finite and in [0, 1]; 3 of 4000 are not (first: index 17, value 5)", 4000);
  expect_spoiled_scene_error(
      [](TestScene& s) {
        s.gaussians.opacities = s.gaussians.opacities.unsqueeze(1).clone();
        s.gaussians.opacities[2][0] = -std::numeric_limits<double>::infinity();
      },
      "opacities must be finite and in [0, 1]; 1 of 4 are not (first: index 2, value -inf)");
}

TEST(SplatValidation, ABadBinningBudgetIsAnError) {
  SceneSpec spec;
  spec.count = 4;
  const TestScene s = random_scene(spec, 2);
  const auto message = [&](const BinningBudget& budget) {
    RenderOptions options;
    options.budget = &budget;
    try {
      render(s.gaussians, s.background, s.camera, options);
    } catch (const c10::Error& e) {
      return std::string(e.what_without_backtrace());
    }
    return std::string("no error");
  };
  const at::Tensor counts = at::zeros({BinningBudget::kCounts}, at::kLong);
  EXPECT_NE(message(BinningBudget{-1, 10, counts}).find("budget must be non-negative, got -1 intersections"),
            std::string::npos);
  EXPECT_NE(message(BinningBudget{10, 10, counts}).find("counts must be a contiguous CUDA int64 tensor of 3 values"),
            std::string::npos);
}

TEST(SplatValidation, NonFiniteBackgroundIsAnError) {
  expect_spoiled_scene_error([](TestScene& s) { s.background[1] = std::numeric_limits<double>::infinity(); },
                             "background must be finite");
}

}  // namespace
}  // namespace sfgs::testing
