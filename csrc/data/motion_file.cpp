#include "data/motion_file.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <limits>
#include <sstream>

#include <ATen/ATen.h>
#include <nlohmann/json.hpp>

#include "body/rotations.h"
#include "body/skeleton.h"
#include "common/tensor_description.h"
#include "data/json_values.h"
#include "data/neuman.h"
#include "io/npz.h"
#include "ops/splat/splat.h"

namespace sfgs::data {
namespace fs = std::filesystem;

namespace {

constexpr int64_t kAmassSmplxPoseSize = 165;       // root, 21 body joints, jaw, two eyes, 2 x 15 hand joints
constexpr int64_t kAmassSmplhPoseSize = 156;       // root, 21 body joints, 2 x 15 hand joints
constexpr double kExavatarFramesPerSecond = 30.0;  // the frame rate of ExAvatar's (NeuMan's) videos
// What a motion may hold, checked before any per-frame work: frame rates of capture systems and videos, and frame
// counts that a render takes in seconds (a clip's poses cost about 7 kB a frame in memory).
constexpr double kMinMotionFrameRate = 1.0;
constexpr double kMaxMotionFrameRate = 1000.0;
constexpr int64_t kMaxMotionFrames = 200000;
// Joint rotations (axis-angle, radians) and translations (metres) beyond these are not a body's pose.
constexpr double kMaxMotionAngle = 100.0;
constexpr double kMaxMotionTranslation = 10000.0;

const char* const kExavatarParams = "smplx_optimized/smplx_params_smoothed";

std::string key_list(const io::NpzArchive& npz) {
  std::ostringstream list;
  for (size_t k = 0; k < npz.keys().size(); ++k) list << (k ? ", " : "") << npz.keys()[k];
  return list.str();
}

// The array `key` as float64 (frames, columns), every value finite; undefined when absent and not required.
at::Tensor frames_array(const io::NpzArchive& npz, const std::string& key, int64_t columns, int64_t frames,
                        bool required) {
  if (!npz.contains(key)) {
    TORCH_CHECK(!required, "motion file '", npz.path(), "' lacks '", key, "' (expected shape (T, ", columns,
                "); keys: ", key_list(npz), ")");
    return at::Tensor();
  }
  const at::Tensor a = npz.read(key);
  TORCH_CHECK(at::isFloatingType(a.scalar_type()) && a.dim() == 2 && a.size(1) == columns &&
                  (frames < 0 || a.size(0) == frames),
              "motion file '", npz.path(), "': '", key, "' must be a floating array of shape (",
              frames < 0 ? std::string("T") : std::to_string(frames), ", ", columns, "), got ", describe(a));
  const at::Tensor values = a.to(at::kDouble);
  TORCH_CHECK(values.isfinite().all().item<bool>(), "motion file '", npz.path(), "': '", key,
              "' holds NaN or infinite values");
  const double bound = key == "trans" ? kMaxMotionTranslation : kMaxMotionAngle;
  const double largest = values.numel() > 0 ? values.abs().max().item<double>() : 0.0;
  TORCH_CHECK(largest <= bound, "motion file '", npz.path(), "': '", key, "' holds ", largest,
              key == "trans" ? " m; translations beyond " : " rad; joint rotations beyond ", bound,
              key == "trans" ? " m" : " rad", " are not a body's motion");
  return values;
}

// The frames of a clip at `frames_per_second` that `seconds` of it need (all of them for infinity), refused beyond
// kMaxMotionFrames before any is read.
int64_t frames_needed(int64_t frames, double frames_per_second, double seconds, const std::string& source) {
  TORCH_CHECK(seconds > 0, "motion '", source, "': the seconds to read must be positive, got ", seconds);
  const double wanted = std::floor(seconds * frames_per_second) + 2;  // the interpolation's last neighbour too
  const int64_t keep = wanted < double(frames) ? int64_t(wanted) : frames;
  TORCH_CHECK(keep <= kMaxMotionFrames, "motion '", source, "' holds ", frames, " frames; at most ", kMaxMotionFrames,
              " are read at once (", double(kMaxMotionFrames) / frames_per_second, " s at its ", frames_per_second,
              " frames/s): render fewer frames (--frames)");
  return keep;
}

double frame_rate(const io::NpzArchive& npz) {
  const char* key = npz.contains("mocap_frame_rate")  ? "mocap_frame_rate"
                    : npz.contains("mocap_framerate") ? "mocap_framerate"
                                                      : nullptr;
  TORCH_CHECK(key, "motion file '", npz.path(),
              "' lacks its frame rate: expected 'mocap_frame_rate' (AMASS SMPL-X) "
              "or 'mocap_framerate' (AMASS SMPL-H); keys: ",
              key_list(npz));
  const at::Tensor rate = npz.read(key);
  const bool numeric = at::isFloatingType(rate.scalar_type()) || at::isIntegralType(rate.scalar_type(), false);
  TORCH_CHECK(rate.numel() == 1 && numeric, "motion file '", npz.path(), "': '", key, "' must be one number, got ",
              describe(rate));
  const double fps = rate.to(at::kDouble).item<double>();
  TORCH_CHECK(std::isfinite(fps) && fps >= kMinMotionFrameRate && fps <= kMaxMotionFrameRate, "motion file '",
              npz.path(), "': '", key, "' must be a frame rate in [", kMinMotionFrameRate, ", ", kMaxMotionFrameRate,
              "] frames/s, got ", fps);
  return fps;
}

// AMASS is Z-up, the avatar Y-up: the rotation taking +Z to +Y (and +Y to -Z), about the X axis.
at::Tensor z_up_to_y_up() {
  return at::tensor({1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, -1.0, 0.0}, at::kDouble).view({3, 3});
}

// `a` rotated a fraction `w` of the shortest arc towards `b`: axis-angle (..., 3).
at::Tensor rotation_between(const at::Tensor& a, const at::Tensor& b, double w) {
  const at::Tensor ra = body::axis_angle_to_matrix(a), rb = body::axis_angle_to_matrix(b);
  const at::Tensor relative = body::matrix_to_axis_angle(ra.transpose(-1, -2).matmul(rb));
  return body::matrix_to_axis_angle(ra.matmul(body::axis_angle_to_matrix(relative * w)));
}

body::SmplxPose blend(const body::SmplxPose& a, const body::SmplxPose& b, double w) {
  body::SmplxPose out;
  for (const body::SmplxPose::Field& f : body::SmplxPose::fields()) {
    const at::Tensor &x = a.*(f.member), &y = b.*(f.member);
    if (!x.defined()) continue;
    const std::string name = f.name;
    const bool linear = name == "expression" || name == "transl";
    out.*(f.member) =
        linear ? x * (1 - w) + y * w : rotation_between(x.reshape({-1, 3}), y.reshape({-1, 3}), w).reshape(x.sizes());
  }
  return out;
}

}  // namespace

bool is_motion_file(const std::string& path) {
  return fs::path(path).extension() == ".npz" || fs::is_directory(fs::path(path) / kExavatarParams);
}

MotionClip read_motion(const std::string& path, double seconds) {
  if (fs::path(path).extension() == ".npz") return read_amass(path, seconds);
  TORCH_CHECK(fs::is_directory(fs::path(path) / kExavatarParams), "motion '", path,
              "' is neither an AMASS .npz nor "
              "an ExAvatar motion folder (with ",
              kExavatarParams, "/)");
  return read_exavatar_motion(path, seconds);
}

// The rigid transform [R | t] of an ExAvatar camera file: "R" (3, 3) and "t" (3), float64.
std::pair<at::Tensor, at::Tensor> read_camera(const std::string& path) {
  const nlohmann::json j = read_json_file(path);
  for (const char* key : {"R", "t"})
    TORCH_CHECK(j.contains(key), "camera file '", path, "' lacks '", key, "' (R: (3, 3) world to camera, t: (3))");
  const at::Tensor r = json_numbers(j.at("R"), {3, 3}, path + ": R").to(at::kDouble).contiguous();
  const at::Tensor t = json_numbers(j.at("t"), {3}, path + ": t").to(at::kDouble).contiguous();
  std::array<double, 16> world_to_camera{0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1};
  for (int row = 0; row < 3; ++row) {
    for (int column = 0; column < 3; ++column)
      world_to_camera[size_t(4 * row + column)] = r[row][column].item<double>();
    world_to_camera[size_t(4 * row + 3)] = t[row].item<double>();
  }
  const std::string problem = world_to_camera_problem(world_to_camera);
  TORCH_CHECK(problem.empty(), "camera file '", path, "': ", problem);
  return {r, t};
}

MotionClip read_exavatar_motion(const std::string& folder, double seconds) {
  const fs::path params = fs::path(folder) / kExavatarParams;
  TORCH_CHECK(fs::is_directory(params), "motion folder '", folder, "' lacks ", kExavatarParams, "/");
  std::vector<std::pair<int64_t, fs::path>> files;
  for (const fs::directory_entry& e : fs::directory_iterator(params)) {
    const std::string stem = e.path().stem().string();
    if (e.path().extension() != ".json" || stem.empty() || stem.find_first_not_of("0123456789") != std::string::npos)
      continue;
    files.emplace_back(std::stoll(stem), e.path());
  }
  TORCH_CHECK(!files.empty(), "motion folder '", folder, "': ", params.string(), " holds no frame file like 0.json");
  std::sort(files.begin(), files.end());
  for (size_t k = 1; k < files.size(); ++k)
    TORCH_CHECK(files[k].first == files[k - 1].first + 1, "motion folder '", folder, "': ", params.string(),
                " jumps from frame ", files[k - 1].first, " to ", files[k].first, " (", files[k - 1].first + 1,
                ".json is missing); the frames of a motion follow one another");
  files.resize(size_t(frames_needed(int64_t(files.size()), kExavatarFramesPerSecond, seconds, folder)));
  const fs::path cameras = fs::path(folder) / "cam_params";
  const bool has_cameras = fs::is_directory(cameras);

  MotionClip clip;
  clip.source = folder;
  clip.format = "exavatar";
  clip.frames_per_second = kExavatarFramesPerSecond;
  clip.absolute_hands = false;
  // The camera frame (x right, y down, z forward) to the avatar's (y up; the body facing the camera faces +z).
  const at::Tensor flip = at::tensor({1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0}, at::kDouble).view({3, 3});
  at::Tensor first_rotation, first_translation;
  for (const auto& [number, file] : files) {
    body::SmplxPose p = read_exavatar_pose(file.string()).to(at::TensorOptions().dtype(at::kDouble));
    at::Tensor rotation = flip, translation = at::zeros({3}, at::kDouble);  // camera k -> avatar frame
    if (has_cameras) {
      const fs::path camera = cameras / (std::to_string(number) + ".json");
      TORCH_CHECK(fs::is_regular_file(camera), "motion folder '", folder, "': frame ", number, " has no ",
                  camera.string(), " (the folder's other frames have cameras)");
      const auto [r, t] = read_camera(camera.string());
      if (!first_rotation.defined()) {
        first_rotation = r;
        first_translation = t;
      }
      // Camera k to the first camera: p0 = R0 Rk^T (pk - tk) + t0.
      const at::Tensor to_first = first_rotation.matmul(r.t());
      rotation = flip.matmul(to_first);
      translation = flip.matmul(first_translation - to_first.matmul(t));
    }
    p.global_orient = body::matrix_to_axis_angle(rotation.matmul(body::axis_angle_to_matrix(p.global_orient)));
    p.transl = rotation.matmul(p.transl) + translation;
    clip.poses.push_back(std::move(p));
  }
  return clip;
}

MotionClip read_amass(const std::string& path, double seconds) {
  TORCH_CHECK(fs::is_regular_file(path), "motion file '", path, "' does not exist or is not a file");
  const io::NpzArchive npz(path);
  MotionClip clip;
  clip.source = path;
  clip.frames_per_second = frame_rate(npz);
  at::Tensor root, body, jaw, eyes, hands;
  if (npz.contains("poses")) {
    const at::Tensor probe = npz.read("poses");
    TORCH_CHECK(probe.dim() == 2 && (probe.size(1) == kAmassSmplxPoseSize || probe.size(1) == kAmassSmplhPoseSize),
                "motion file '", path, "': 'poses' must have shape (T, ", kAmassSmplxPoseSize, ") (SMPL-X) or (T, ",
                kAmassSmplhPoseSize, ") (SMPL-H), got ", describe(probe));
    const bool smplx = probe.size(1) == kAmassSmplxPoseSize;
    const at::Tensor poses = frames_array(npz, "poses", probe.size(1), -1, true);
    root = poses.narrow(1, 0, 3);
    body = poses.narrow(1, 3, 63);
    if (smplx) {
      jaw = poses.narrow(1, 66, 3);
      eyes = poses.narrow(1, 69, 6);
      hands = poses.narrow(1, 75, 90);
      clip.format = "amass-smplx";
    } else {
      hands = poses.narrow(1, 66, 90);
      clip.format = "amass-smplh";
      clip.note = "SMPL-H motion: body and hands taken, jaw and eyes left at rest";
    }
  } else {
    root = frames_array(npz, "root_orient", 3, -1, true);
    const int64_t t = root.size(0);
    body = frames_array(npz, "pose_body", 63, t, true);
    hands = frames_array(npz, "pose_hand", 90, t, true);
    jaw = frames_array(npz, "pose_jaw", 3, t, false);
    eyes = frames_array(npz, "pose_eye", 6, t, false);
    clip.format = "amass-smplx";
    if (!jaw.defined() || !eyes.defined()) clip.note = "no 'pose_jaw' or 'pose_eye': jaw and eyes left at rest";
  }
  TORCH_CHECK(root.size(0) > 0, "motion file '", path, "' holds no frame");
  at::Tensor trans = frames_array(npz, "trans", 3, root.size(0), false);
  if (!trans.defined()) trans = at::zeros({root.size(0), 3}, at::kDouble);
  const int64_t frames = frames_needed(root.size(0), clip.frames_per_second, seconds, path);
  for (at::Tensor* a : {&root, &body, &jaw, &eyes, &hands, &trans})
    if (a->defined()) *a = a->narrow(0, 0, frames);

  const at::Tensor up = z_up_to_y_up();
  const at::Tensor orient = body::matrix_to_axis_angle(up.matmul(body::axis_angle_to_matrix(root)));
  trans = trans.matmul(up.t());
  for (int64_t t = 0; t < frames; ++t) {
    body::SmplxPose p;
    p.global_orient = orient[t].clone();
    p.body_pose = body[t].reshape({body::kSmplxBodyJointCount, 3}).clone();
    p.left_hand_pose = hands[t].narrow(0, 0, body::kHandPoseSize).reshape({body::kHandJointCount, 3}).clone();
    p.right_hand_pose =
        hands[t].narrow(0, body::kHandPoseSize, body::kHandPoseSize).reshape({body::kHandJointCount, 3}).clone();
    p.jaw_pose = jaw.defined() ? jaw[t].clone() : at::zeros({3}, at::kDouble);
    p.leye_pose = eyes.defined() ? eyes[t].narrow(0, 0, 3).clone() : at::zeros({3}, at::kDouble);
    p.reye_pose = eyes.defined() ? eyes[t].narrow(0, 3, 3).clone() : at::zeros({3}, at::kDouble);
    p.transl = trans[t].clone();
    clip.poses.push_back(std::move(p));
  }
  return clip;
}

MotionClip resample(const MotionClip& clip, double frames_per_second) {
  TORCH_CHECK(std::isfinite(frames_per_second) && frames_per_second > 0,
              "resample: the frame rate must be positive, got ", frames_per_second);
  TORCH_CHECK(!clip.poses.empty() && clip.frames_per_second > 0, "resample: the clip '", clip.source,
              "' holds no frame or has no frame rate");
  MotionClip out = clip;
  out.poses.clear();
  out.frames_per_second = frames_per_second;
  const int64_t n = static_cast<int64_t>(clip.poses.size());
  const double last = double(n - 1) / clip.frames_per_second;  // the time of the last source frame
  const double frames = std::floor(last * frames_per_second + 1e-9) + 1;
  TORCH_CHECK(frames <= double(kMaxMotionFrames), "resample: '", clip.source, "' (", last, " s) at ", frames_per_second,
              " frames/s gives ", frames, " frames; at most ", kMaxMotionFrames,
              " (render fewer seconds or at a lower --fps)");
  const auto count = static_cast<int64_t>(frames);
  for (int64_t k = 0; k < count; ++k) {
    const double source = double(k) * clip.frames_per_second / frames_per_second;
    const int64_t i = std::min<int64_t>(static_cast<int64_t>(std::floor(source + 1e-9)), n - 1);
    const double w = source - double(i);
    out.poses.push_back(w < 1e-9 || i + 1 >= n ? clip.poses[size_t(i)]
                                               : blend(clip.poses[size_t(i)], clip.poses[size_t(i + 1)], w));
  }
  return out;
}

}  // namespace sfgs::data
