#include "data/pose_noise.h"

#include <ATen/ATen.h>
#include <ATen/CPUGeneratorImpl.h>

#include <cmath>
#include <map>
#include <sstream>

#include "body/rotations.h"
#include "body/skeleton.h"
#include "data/constants.h"

namespace sfgs::data {
namespace {

constexpr double kDegree = M_PI / 180.0;
constexpr double kCentimetre = 0.01;

const std::map<std::string, PoseNoiseLevel>& named_levels() {
  static const std::map<std::string, PoseNoiseLevel> levels = [] {
    std::map<std::string, PoseNoiseLevel> m;
    m["none"] = PoseNoiseLevel{};
    for (const auto& [name, scale] :
         {std::make_pair("low", 0.5), std::make_pair("medium", 1.0), std::make_pair("high", 2.0)}) {
      PoseNoiseLevel l;
      l.name = name;
      l.body_degrees = kPoseNoiseMediumBodyDegrees * scale;
      l.hand_degrees = kPoseNoiseMediumHandDegrees * scale;
      l.root_degrees = kPoseNoiseMediumRootDegrees * scale;
      l.lateral_cm = kPoseNoiseMediumLateralCm * scale;
      l.depth_cm = kPoseNoiseMediumDepthCm * scale;
      l.betas_sigma = kPoseNoiseMediumBetasSigma * scale;
      l.jitter_share = kPoseNoiseJitterShare;
      l.drift_seconds = kPoseNoiseDriftSeconds;
      l.hand_swap_rate = name == std::string("low") ? 0.0 : kPoseNoiseMediumHandSwapRate * scale;
      m[name] = l;
    }
    m["default"] = m["medium"];
    return m;
  }();
  return levels;
}

double parse_number(const std::string& key, const std::string& text, double lo, double hi, const std::string& spec) {
  double value = 0;
  size_t used = 0;
  try {
    value = std::stod(text, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  TORCH_CHECK(used == text.size() && !text.empty() && std::isfinite(value) && value >= lo && value <= hi,
              "--pose-noise '", spec, "': ", key, "=", text, " must be a number in [", lo, ", ", hi, "]");
  return value;
}

// A (frames, components) error process with RMS `sigma` per component: the sum of white jitter and an AR(1) drift
// whose correlation decays as exp(-gap / drift_seconds) over the gap to the previous frame's time.
at::Tensor drifting_errors(int64_t components, double sigma, const at::Tensor& times, const PoseNoiseLevel& level,
                           at::Generator& gen) {
  const int64_t frames = times.size(0);
  at::Tensor jitter = at::empty({frames, components}, at::kDouble).normal_(0.0, 1.0, gen);
  at::Tensor innovation = at::empty({frames, components}, at::kDouble).normal_(0.0, 1.0, gen);
  if (sigma == 0) return at::zeros({frames, components}, at::kDouble);
  const double jitter_sigma = sigma * std::sqrt(level.jitter_share);
  const double drift_sigma = sigma * std::sqrt(1 - level.jitter_share);
  at::Tensor drift = at::empty_like(innovation);
  const auto t = times.accessor<double, 1>();
  for (int64_t i = 0; i < frames; ++i) {
    const double gap = i == 0 ? INFINITY : t[i] - t[i - 1];
    const double rho = gap > 0 && level.drift_seconds > 0 ? std::exp(-gap / level.drift_seconds) : 0.0;
    drift[i] = i == 0 || gap <= 0 ? innovation[i] : rho * drift[i - 1] + std::sqrt(1 - rho * rho) * innovation[i];
  }
  return jitter * jitter_sigma + drift * drift_sigma;
}

// Left-multiplies local rotations (B, J, 3) axis-angle by error rotations (B, J, 3).
at::Tensor perturb_rotations(const at::Tensor& axis_angle, const at::Tensor& errors) {
  const at::Tensor r = body::axis_angle_to_matrix(errors).matmul(body::axis_angle_to_matrix(axis_angle));
  return body::matrix_to_axis_angle(r);
}

}  // namespace

bool PoseNoiseLevel::is_zero() const {
  return body_degrees == 0 && hand_degrees == 0 && root_degrees == 0 && lateral_cm == 0 && depth_cm == 0 &&
         betas_sigma == 0 && hand_swap_rate == 0;
}

PoseNoiseLevel pose_noise_level(const std::string& spec) {
  std::vector<std::string> parts;
  std::stringstream stream(spec);
  for (std::string part; std::getline(stream, part, ',');) parts.push_back(part);
  TORCH_CHECK(!parts.empty() && named_levels().count(parts[0]), "--pose-noise '", spec,
              "': expected a level none, low, medium (default) or high, optionally with overrides such as "
              "medium,hands=15,depth=10");
  PoseNoiseLevel level = named_levels().at(parts[0]);
  level.name = parts[0] == "default" ? "medium" : parts[0];
  const std::map<std::string, std::pair<double PoseNoiseLevel::*, double>> keys = {
      {"body", {&PoseNoiseLevel::body_degrees, 180}}, {"hands", {&PoseNoiseLevel::hand_degrees, 180}},
      {"root", {&PoseNoiseLevel::root_degrees, 180}}, {"lateral", {&PoseNoiseLevel::lateral_cm, 1000}},
      {"depth", {&PoseNoiseLevel::depth_cm, 1000}},   {"betas", {&PoseNoiseLevel::betas_sigma, 10}},
      {"jitter", {&PoseNoiseLevel::jitter_share, 1}}, {"drift", {&PoseNoiseLevel::drift_seconds, 1e6}},
      {"swap", {&PoseNoiseLevel::hand_swap_rate, 1}}};
  for (size_t i = 1; i < parts.size(); ++i) {
    const size_t eq = parts[i].find('=');
    const std::string key = parts[i].substr(0, eq);
    TORCH_CHECK(eq != std::string::npos && keys.count(key), "--pose-noise '", spec, "': '", parts[i],
                "' is not key=value with a key among body, hands, root (degrees), lateral, depth (cm), betas, "
                "jitter, swap (shares) and drift (seconds)");
    const auto& [member, hi] = keys.at(key);
    level.*member = parse_number(key, parts[i].substr(eq + 1), 0, hi, spec);
    level.name = level.name + "," + parts[i];
  }
  return level;
}

at::Tensor mirror_axis_angle(const at::Tensor& axis_angle) {
  const at::Tensor sign = at::tensor({1.0, -1.0, -1.0}, axis_angle.options());
  return axis_angle * sign;
}

NoisyFits corrupt_fits(const body::SmplxPose& truth, const at::Tensor& betas, const at::Tensor& times,
                       const at::Tensor& world_to_camera_rotations, const PoseNoiseLevel& level, uint64_t seed) {
  const int64_t frames = truth.body_pose.size(0);
  TORCH_CHECK(times.dim() == 1 && times.size(0) == frames, "corrupt_fits: expected (", frames, ") frame times, got ",
              times.sizes());
  TORCH_CHECK(world_to_camera_rotations.dim() == 3 && world_to_camera_rotations.size(0) == frames &&
                  world_to_camera_rotations.size(1) == 3 && world_to_camera_rotations.size(2) == 3,
              "corrupt_fits: expected (", frames, ", 3, 3) camera rotations, got ", world_to_camera_rotations.sizes());
  NoisyFits out{truth, betas, at::zeros({frames}, at::kBool)};
  if (level.is_zero()) return out;

  at::Generator gen = at::make_generator<at::CPUGeneratorImpl>(seed);
  const at::Tensor t = times.to(at::kDouble).contiguous();
  const at::Tensor to_camera = world_to_camera_rotations.to(at::kDouble);
  const auto rotation_errors = [&](int64_t joints, double degrees) {
    // Per-axis sigma so that the RMS rotation angle is `degrees`.
    return drifting_errors(3 * joints, degrees * kDegree / std::sqrt(3.0), t, level, gen).view({frames, joints, 3});
  };
  const auto joint_pose = [](const at::Tensor& field, int64_t joints) {
    return field.to(at::kDouble).reshape({field.size(0), joints, 3});
  };

  // Body joints: wrists take the hand level.
  at::Tensor body_errors = rotation_errors(body::kSmplxBodyJointCount, level.body_degrees);
  const at::Tensor wrist_errors = rotation_errors(2, level.hand_degrees);
  body_errors.select(1, body::smplx_joint::kLeftWrist - 1).copy_(wrist_errors.select(1, 0));
  body_errors.select(1, body::smplx_joint::kRightWrist - 1).copy_(wrist_errors.select(1, 1));
  const at::Tensor body = joint_pose(truth.body_pose, body::kSmplxBodyJointCount);
  out.poses.body_pose = perturb_rotations(body, body_errors).to(at::kFloat).view_as(truth.body_pose);
  for (at::Tensor body::SmplxPose::*field :
       {&body::SmplxPose::jaw_pose, &body::SmplxPose::leye_pose, &body::SmplxPose::reye_pose}) {
    const at::Tensor errors = rotation_errors(1, level.body_degrees);
    out.poses.*field = perturb_rotations(joint_pose(truth.*field, 1), errors).to(at::kFloat).view_as(truth.*field);
  }
  at::Tensor hands[2];
  for (int side = 0; side < 2; ++side) {
    const at::Tensor& given = side == 0 ? truth.left_hand_pose : truth.right_hand_pose;
    hands[side] = perturb_rotations(joint_pose(given, body::kHandJointCount),
                                    rotation_errors(body::kHandJointCount, level.hand_degrees));
  }

  // Orientation and translation errors are drawn about the camera's axes and turned into the fit's frame.
  const at::Tensor root_errors_camera = rotation_errors(1, level.root_degrees).squeeze(1);
  const at::Tensor camera_to_world = to_camera.transpose(1, 2);
  const at::Tensor root_errors = camera_to_world.matmul(root_errors_camera.unsqueeze(-1)).squeeze(-1);
  out.poses.global_orient = perturb_rotations(joint_pose(truth.global_orient, 1), root_errors.unsqueeze(1))
                                .to(at::kFloat)
                                .view_as(truth.global_orient);
  const at::Tensor lateral = drifting_errors(2, level.lateral_cm * kCentimetre, t, level, gen);
  const at::Tensor depth = drifting_errors(1, level.depth_cm * kCentimetre, t, level, gen);
  const at::Tensor shift_camera = at::cat({lateral, depth}, 1);
  const at::Tensor shift = camera_to_world.matmul(shift_camera.unsqueeze(-1)).squeeze(-1);
  out.poses.transl = (truth.transl.to(at::kDouble) + shift).to(at::kFloat).view_as(truth.transl);

  // A detector that confuses the hands gives each hand the other's (mirrored) pose.
  out.hands_swapped = at::empty({frames}, at::kDouble).uniform_(0.0, 1.0, gen) < level.hand_swap_rate;
  const at::Tensor swapped = out.hands_swapped.view({frames, 1, 1});
  const at::Tensor left = at::where(swapped, mirror_axis_angle(hands[1]), hands[0]);
  const at::Tensor right = at::where(swapped, mirror_axis_angle(hands[0]), hands[1]);
  out.poses.left_hand_pose = left.to(at::kFloat).view_as(truth.left_hand_pose);
  out.poses.right_hand_pose = right.to(at::kFloat).view_as(truth.right_hand_pose);
  const at::Tensor shape_error = at::empty({betas.size(0)}, at::kDouble).normal_(0.0, 1.0, gen) * level.betas_sigma;
  out.betas = (betas.to(at::kDouble) + shape_error).to(betas.scalar_type());
  return out;
}

}  // namespace sfgs::data
