#include "data/synthetic.h"
#include "common/math_constants.h"
#include "data/constants.h"
#include "ops/splat/constants.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <random>

#include <ATen/ATen.h>
#include <ATen/CPUGeneratorImpl.h>

#include "body/parts.h"
#include "body/procedural_body.h"
#include "body/skeleton.h"
#include "body/smplx.h"
#include "body/wholebody_keypoints.h"
#include "data/keypoint_file.h"
#include "data/mesh_renderer.h"
#include "data/motions.h"
#include "data/synthetic_layouts.h"
#include "io/npz.h"

namespace sfgs::data {
namespace fs = std::filesystem;

namespace {

constexpr int64_t kSynthBetas = 10;        // shape coefficients drawn for the subject
constexpr int64_t kSynthExpressions = 10;  // expression coefficients animated
constexpr double kSubjectFill = 0.8;       // share of the image height the subject spans
constexpr double kFocalPerPixel = 1.2;     // focal length in units of the larger image side
constexpr double kOrbitRadians = 0.35;     // the camera drifts +-this far around the subject: mostly frontal
// The key light: from the front, above and the subject's left (world y up, the camera on +z), fixed in the world.
constexpr std::array<double, 3> kKeyLight{0.45, 0.8, 0.6};
constexpr double kHandShakeMetres = 0.02;  // amplitude of the camera's hand-held wobble
constexpr int64_t kPatternSize = 256;      // side of the generated texture

// A hand-held camera: a smooth, seeded wobble from a few incommensurate sinusoids.
struct HandShake {
  std::array<double, 9> phase, frequency;
  explicit HandShake(uint64_t seed) {
    std::mt19937_64 rng(seed);
    std::uniform_real_distribution<double> u(0.0, 1.0);
    for (size_t k = 0; k < phase.size(); ++k) {
      phase[k] = kTwoPi * u(rng);
      frequency[k] = 0.3 + 1.2 * u(rng);
    }
  }
  std::array<double, 3> at(double t) const {
    std::array<double, 3> offset{};
    for (size_t k = 0; k < phase.size(); ++k)
      offset[k % 3] += kHandShakeMetres / 3 * std::sin(kTwoPi * frequency[k] * t + phase[k]);
    return offset;
  }
};

// OpenCV look-at: z towards the target, x to the right, y down, for a world whose up is +y.
std::array<double, 16> look_at(const std::array<double, 3>& eye, const std::array<double, 3>& target) {
  auto normalise = [](std::array<double, 3> v) {
    const double n = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    return std::array<double, 3>{v[0] / n, v[1] / n, v[2] / n};
  };
  auto cross = [](const std::array<double, 3>& a, const std::array<double, 3>& b) {
    return std::array<double, 3>{a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
  };
  const auto z = normalise({target[0] - eye[0], target[1] - eye[1], target[2] - eye[2]});
  const auto x = normalise(cross(z, {0.0, 1.0, 0.0}));
  const auto y = cross(z, x);
  std::array<double, 16> m{};
  for (int c = 0; c < 3; ++c) {
    m[size_t(c)] = x[size_t(c)];
    m[size_t(4 + c)] = y[size_t(c)];
    m[size_t(8 + c)] = z[size_t(c)];
  }
  for (int r = 0; r < 3; ++r)
    m[size_t(4 * r + 3)] = -(m[size_t(4 * r)] * eye[0] + m[size_t(4 * r + 1)] * eye[1] + m[size_t(4 * r + 2)] * eye[2]);
  m[15] = 1;
  return m;
}

// A colourful pattern with detail at several scales, so the avatar has something to learn on any UV layout.
at::Tensor generated_texture() {
  const at::Tensor u = (at::arange(kPatternSize, at::kFloat) + 0.5f) / kPatternSize;
  const at::Tensor uu = u.unsqueeze(0).expand({kPatternSize, kPatternSize});
  const at::Tensor vv = u.flip(0).unsqueeze(1).expand({kPatternSize, kPatternSize});
  const at::Tensor checker = at::remainder(at::floor(uu * 16) + at::floor(vv * 16), 2.0);
  const at::Tensor r = 0.55 + 0.3 * at::sin(kTwoPi * 3 * uu) + 0.1 * checker;
  const at::Tensor g = 0.5 + 0.3 * at::sin(kTwoPi * 2 * vv + 1.0) - 0.1 * checker;
  const at::Tensor b = 0.5 + 0.3 * at::cos(kTwoPi * 2 * (uu + vv));
  return at::stack({r, g, b}, 2).clamp(0, 1).contiguous();
}

}  // namespace

namespace {

// Its layer (axis-angle hands: the motion gives the hands' rotations).
body::Smplx synthetic_body_layer(const body::SmplxModelData& model) {
  body::SmplxOptions layer_options;
  layer_options.num_betas = std::min<int64_t>(kSynthBetas, model.shapedirs.size(2));
  layer_options.num_expression_coeffs = std::min<int64_t>(kSynthExpressions, model.exprdirs.size(2));
  layer_options.use_pca = false;
  layer_options.flat_hand_mean = true;
  return body::Smplx(model, layer_options);
}

TexturedMesh subject_mesh(const body::Smplx& smplx, const SyntheticVideoOptions& options) {
  TexturedMesh mesh;
  mesh.faces = smplx->faces();
  if (smplx->uvs().defined()) {
    mesh.uvs = smplx->uvs();
    mesh.face_uvs = smplx->uv_faces();
    mesh.texture = options.texture.empty() ? generated_texture() : read_image_rgb(options.texture);
  } else {
    TORCH_CHECK(options.texture.empty(), "sfgs synth: '", options.body_model,
                "' has no UVs (vt/ft), so --texture cannot apply");
  }
  return mesh;
}

// The hand-held camera: it frames the subject over the whole video and keeps that distance while it drifts in front
// of it and shakes.
class SyntheticCamera {
 public:
  SyntheticCamera(const at::Tensor& all_vertices, const SyntheticVideoOptions& options, int64_t frames)
      : options_(options),
        shake_(options.seed),
        duration_(double(frames) / options.frames_per_second),
        focal_(kFocalPerPixel * double(std::max(options.width, options.height))) {
    const at::Tensor points = all_vertices.reshape({-1, 3});
    const at::Tensor lo = std::get<0>(points.min(0)), hi = std::get<0>(points.max(0));
    const at::Tensor centre = (lo + hi) / 2;
    const double extent_y = (hi[1] - lo[1]).item<double>(), extent_x = (hi[0] - lo[0]).item<double>();
    distance_ = focal_ * std::max(extent_y / (kSubjectFill * double(options.height)),
                                  extent_x / (kSubjectFill * double(options.width)));
    target_ = {centre[0].item<double>(), centre[1].item<double>(), centre[2].item<double>()};
  }

  Camera at(double t) const {
    const double phase = kTwoPi * t / std::max(duration_, kMinSpan);
    const double angle = kOrbitRadians * std::sin(phase);
    const auto wobble = shake_.at(t);
    const std::array<double, 3> eye{target_[0] + distance_ * std::sin(angle) + wobble[0],
                                    target_[1] + 0.1 * distance_ * std::sin(0.5 * phase) + wobble[1],
                                    target_[2] + distance_ * std::cos(angle) + wobble[2]};
    Camera camera = Camera::looking_forward(focal_, options_.width, options_.height);
    camera.world_to_camera = look_at(eye, {target_[0] + 0.3 * wobble[0], target_[1] + 0.3 * wobble[1], target_[2]});
    return camera;
  }

 private:
  const SyntheticVideoOptions& options_;
  HandShake shake_;
  double duration_, focal_, distance_ = 0;
  std::array<double, 3> target_{};
};

}  // namespace

namespace {

// Per model vertex: the number of frames among `frames` in which a face holding it covers a pixel centre.
void count_visible_vertices(const at::Tensor& face_ids, const at::Tensor& faces, at::Tensor& counts) {
  const at::Tensor visible_faces = std::get<0>(at::_unique(face_ids.flatten().masked_select(face_ids.flatten() >= 0)));
  at::Tensor seen = at::zeros({counts.size(0)}, at::kFloat);
  seen.index_fill_(0, faces.index_select(0, visible_faces).flatten(), 1.0f);
  counts += seen;
}

// The region of every model vertex (body::BodyPart codes): the model's own labels, or those its weights imply.
at::Tensor vertex_regions(const body::SmplxModelData& model) {
  return (model.part_labels.defined() ? model.part_labels : body::part_labels_from_weights(model.weights))
      .to(at::kLong);
}

// Test blocks are all test; training blocks hold out the interleaved split's validation frames and, in the
// interleaved split, its test frames.
Split split_of(bool test_block, int64_t index_in_block, bool interleaved) {
  if (test_block) return Split::kTest;
  const Split split = interleaved_split(index_in_block);
  return split == Split::kTest && !interleaved ? Split::kTrain : split;
}

void check_options(const SyntheticVideoOptions& options) {
  TORCH_CHECK(options.frames >= 1, "sfgs synth: --frames must be at least 1, got ", options.frames);
  TORCH_CHECK(
      options.width >= 16 && options.height >= 16 && options.width <= kMaxImageSide && options.height <= kMaxImageSide,
      "sfgs synth: image sides must be in [16, ", kMaxImageSide, "], got ", options.width, " x ", options.height);
  TORCH_CHECK(options.frames_per_second > 0, "sfgs synth: frames per second must be positive");
  TORCH_CHECK(!options.motions.empty(), "sfgs synth: at least one training motion is needed");
  for (const auto* list : {&options.motions, &options.test_motions})
    for (const std::string& m : *list) TORCH_CHECK(is_motion(m), "sfgs synth: unknown motion '", m, "'");
  for (const std::string& m : options.test_motions)
    TORCH_CHECK(std::find(options.motions.begin(), options.motions.end(), m) == options.motions.end(),
                "sfgs synth: motion '", m, "' is both a training and a test motion");
}

// Independent random streams of one seed: the subject's shape, the fits' noise and the detections.
uint64_t stream_seed(uint64_t seed, uint64_t stream) { return seed + kSeedStreamStride * stream; }

// The whole-body keypoints of every frame in its camera's coordinates, (B, 133, 3).
at::Tensor camera_keypoints(const body::WholeBodyKeypointMap& map, const body::SmplxOutput& posed,
                            const at::Tensor& rotations, const at::Tensor& translations) {
  const at::Tensor neck = posed.joint_transforms.select(1, body::smplx_joint::kNeck).narrow(1, 0, 3).narrow(2, 0, 3);
  const at::Tensor bins = body::contour_bins(rotations.to(neck.dtype()).matmul(neck), map.contour_bin_count());
  const at::Tensor world = map.evaluate_on_mesh(posed.vertices, posed.joints, bins).to(at::kDouble);
  return world.matmul(rotations.transpose(1, 2)) + translations.unsqueeze(1);
}

// Rotation (B, 3, 3) and translation (B, 3) blocks of the frames' world-to-camera matrices.
std::pair<at::Tensor, at::Tensor> camera_blocks(const std::vector<FrameRecord>& frames) {
  at::Tensor r = at::empty({int64_t(frames.size()), 3, 3}, at::kDouble);
  at::Tensor t = at::empty({int64_t(frames.size()), 3}, at::kDouble);
  for (size_t i = 0; i < frames.size(); ++i) {
    const auto& m = frames[i].camera.world_to_camera;
    for (int64_t row = 0; row < 3; ++row) {
      for (int64_t col = 0; col < 3; ++col) r[int64_t(i)][row][col] = m[size_t(4 * row + col)];
      t[int64_t(i)][row] = m[size_t(4 * row + 3)];
    }
  }
  return {r, t};
}

}  // namespace

Dataset write_synthetic_video(const std::string& folder, const SyntheticVideoOptions& options) {
  check_options(options);
  const bool sfgs_layout = options.layout == DatasetLayout::kSfgs;
  for (const char* sub : {"images", "masks", kKeypointFolder}) fs::create_directories(fs::path(folder) / sub);
  if (sfgs_layout) fs::create_directories(fs::path(folder) / "meshes");

  const body::SmplxModelData model = body::smplx_model_or_procedural(options.body_model);
  const body::Smplx smplx = synthetic_body_layer(model);
  const body::WholeBodyKeypointMap keypoint_map = body::wholebody_keypoint_map(model, options.body_model);
  at::Generator gen = at::make_generator<at::CPUGeneratorImpl>(options.seed);
  const at::Tensor betas = at::empty({smplx->options().num_betas}).normal_(0.0, 0.6, gen);
  std::vector<std::string> blocks = options.motions;
  blocks.insert(blocks.end(), options.test_motions.begin(), options.test_motions.end());
  const int64_t total = int64_t(blocks.size()) * options.frames;
  std::vector<SmplxPose> poses;
  for (const std::string& motion : blocks)
    for (int64_t i = 0; i < options.frames; ++i)
      poses.push_back(
          motion_pose(motion, double(i) / options.frames_per_second, smplx->options().num_expression_coeffs));
  body::SmplxInput input;
  input.betas = betas.unsqueeze(0).expand({total, -1}).contiguous();
  input.pose = SmplxPose::stack(poses);
  const body::SmplxOutput posed = smplx->forward(input);
  const at::Tensor vertices = posed.vertices.detach().to(at::kFloat);
  TexturedMesh mesh = subject_mesh(smplx, options);
  const SyntheticCamera camera(vertices, options, total);
  MeshShading shading;
  if (options.key_light) shading.key_light = kKeyLight;

  SyntheticVideo video;
  video.sequences = sfgs_layout ? blocks : std::vector<std::string>{fs::path(folder).filename().string()};
  video.hands_mean_left = model.hands_mean_left;
  video.hands_mean_right = model.hands_mean_right;
  for (int64_t i = 0; i < total; ++i) {
    FrameRecord r;
    char name[24];  // room for any int64 (the warning counts 19 digits and a sign)
    std::snprintf(name, sizeof(name), sfgs_layout ? "%06lld" : "%05lld", static_cast<long long>(i));
    r.name = name;
    r.time = double(i) / options.frames_per_second;
    r.sequence = sfgs_layout ? i / options.frames : 0;
    r.camera = camera.at(r.time);
    const SyntheticFramePaths paths = synthetic_frame_paths(folder, options.layout, i);
    r.image_path = paths.image;
    r.mask_path = paths.mask;
    r.mesh_path = paths.mesh;
    r.keypoints_path = paths.keypoints;
    video.frames.push_back(std::move(r));
  }
  const auto [rotations, translations] = camera_blocks(video.frames);
  const at::Tensor keypoints = camera_keypoints(keypoint_map, posed, rotations, translations);

  // The fits as written: exact, or corrupted about each frame's camera.
  at::Tensor times = at::empty({total}, at::kDouble);
  for (int64_t i = 0; i < total; ++i) times[i] = video.frames[size_t(i)].time;
  const NoisyFits noisy =
      corrupt_fits(input.pose, betas, times, rotations, options.pose_noise, stream_seed(options.seed, 1));
  video.betas = noisy.betas;
  video.true_rest_pelvis = posed.rest_joints.select(1, 0).detach().to(at::kDouble);
  video.rest_pelvis = video.true_rest_pelvis;
  if (!options.pose_noise.is_zero()) {
    video.true_betas = betas;
    body::SmplxInput noisy_rest;  // the written shape's pelvis, which the camera-frame fits turn about
    noisy_rest.betas = noisy.betas.unsqueeze(0).expand({total, -1}).contiguous();
    noisy_rest.pose.expression = input.pose.expression;
    video.rest_pelvis = smplx->forward(noisy_rest).rest_joints.select(1, 0).detach().to(at::kDouble);
  }

  const at::Tensor white = at::ones({3});
  at::Tensor seen_counts = at::zeros({vertices.size(1)}, at::kFloat);
  int64_t training_frames = 0;
  at::Generator detector = at::make_generator<at::CPUGeneratorImpl>(stream_seed(options.seed, 2));
  const at::Tensor on_surface = keypoint_map.on_surface();
  if (sfgs_layout) io::write_npy((fs::path(folder) / "meshes" / "faces.npy").string(), mesh.faces, options.overwrite);
  for (int64_t i = 0; i < total; ++i) {
    FrameRecord& r = video.frames[size_t(i)];
    r.pose = noisy.poses.frame(i);
    if (!options.pose_noise.is_zero()) r.true_pose = poses[size_t(i)];
    mesh.vertices = vertices[i];
    const MeshImage frame = render_mesh(mesh, r.camera, white, shading);
    write_png(r.image_path, frame.image, options.overwrite);
    write_png(r.mask_path, frame.mask, options.overwrite);
    if (sfgs_layout) io::write_npy(r.mesh_path, vertices[i], options.overwrite);
    const at::Tensor detections =
        simulate_detections(keypoints[i], r.camera, frame.depth, on_surface, options.keypoint_noise, detector);
    write_wholebody_keypoints(synthetic_frame_paths(folder, options.layout, i).keypoints, detections,
                              options.overwrite);
    const Split split = split_of(i / options.frames >= int64_t(options.motions.size()), i % options.frames,
                                 options.test_motions.empty());
    if (split == Split::kTrain) {
      count_visible_vertices(frame.face, mesh.faces, seen_counts);
      ++training_frames;
    }
    video.splits[split].push_back(i);
    if (options.progress) options.progress(i + 1, total);
  }
  if (!sfgs_layout) {
    write_neuman_layout_index(folder, video, options.overwrite);
    return read_dataset(folder);
  }
  io::write_npy((fs::path(folder) / "meshes" / "regions.npy").string(), vertex_regions(model), options.overwrite);
  io::write_npy((fs::path(folder) / "meshes" / "observation.npy").string(),
                seen_counts / double(std::max<int64_t>(training_frames, 1)), options.overwrite);
  write_sfgs_layout_index(folder, video, options.overwrite);
  return read_dataset(folder);
}

}  // namespace sfgs::data
