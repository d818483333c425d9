#include "train/train_config.h"

#include <algorithm>
#include <fstream>
#include <functional>
#include <map>
#include <set>
#include <sstream>

#include <c10/util/Exception.h>
#include <cmath>
#include <yaml-cpp/yaml.h>

#include "train/constants.h"

namespace sfgs::train {
namespace {

// One table maps every key to its field, for reading and writing alike.
struct Field {
  std::function<void(const YAML::Node&)> read;
  std::function<void(YAML::Emitter&)> write;
};

template <typename T> Field field(T& target) {
  return Field{[&target](const YAML::Node& n) { target = n.as<T>(); }, [&target](YAML::Emitter& e) { e << target; }};
}

Field parts_field(PartWeights& p) {
  return Field{[&p](const YAML::Node& n) {
                 for (const auto& kv : n) {
                   const std::string key = kv.first.as<std::string>();
                   if (key == "body")
                     p.body = kv.second.as<double>();
                   else if (key == "face")
                     p.face = kv.second.as<double>();
                   else if (key == "hands")
                     p.hands = kv.second.as<double>();
                   else
                     TORCH_CHECK(false, "unknown part '", key, "' (expected body, face or hands)");
                 }
               },
               [&p](YAML::Emitter& e) {
                 e << YAML::Flow << YAML::BeginMap << YAML::Key << "body" << YAML::Value << p.body << YAML::Key
                   << "face" << YAML::Value << p.face << YAML::Key << "hands" << YAML::Value << p.hands << YAML::EndMap;
               }};
}

using Section = std::vector<std::pair<std::string, Field>>;

// Keys of earlier versions: renamed ones are read as their new name, retired ones (which nothing used) are ignored;
// both with a warning, so the configs saved in older runs still load.
const std::map<std::string, std::string>& renamed_keys() {
  static const std::map<std::string, std::string> keys = {{"avatar.use_color_offset", "use_colour_offset"}};
  return keys;
}
const std::set<std::string>& retired_keys() {
  static const std::set<std::string> keys = {"loss.face", "loss.joint_drift"};
  return keys;
}
// Per-step pose corrections were removed: Adam moved every number of a drawn frame by about its rate whatever the
// gradient, and the avatar, trained on poses that jitter by a degree, never sharpened (6-7 dB of the GPU benchmark's
// training PSNR on exact fits; docs/archive/results-history.md, "Per-step corrections"). Their keys still load: a
// positive rate is refused in a config to train with, and in a run's stored config (a run of a version that had them)
// it is ignored with a warning.
const std::set<std::string>& per_step_keys() {
  static const std::set<std::string> keys = {"pose_refinement.learning_rate",
                                             "pose_refinement.translation_learning_rate", "pose_refinement.prior",
                                             "pose_refinement.smoothness"};
  return keys;
}
bool is_per_step_rate(const std::string& key) {
  return key == "pose_refinement.learning_rate" || key == "pose_refinement.translation_learning_rate";
}

std::vector<std::pair<std::string, Section>> sections(TrainConfig& c) {
  model::AvatarConfig& a = c.avatar;
  LossWeights& l = c.loss;
  Schedule& s = c.schedule;
  BodyFiles& b = c.body;
  PoseRefinementConfig& p = c.pose_refinement;
  return {
      {"body",
       {{"smplx", field(b.smplx)},
        {"mano_left", field(b.mano_left)},
        {"mano_right", field(b.mano_right)},
        {"hand_vertex_ids", field(b.hand_vertex_ids)},
        {"face_vertex_ids", field(b.face_vertex_ids)}}},
      {"run",
       {{"seed", field(c.seed)},
        {"device", field(c.device)},
        {"log_every", field(c.log_every)},
        {"validate_every", field(c.validate_every)},
        {"checkpoint_every", field(c.checkpoint_every)},
        {"validation_frames", field(c.validation_frames)}}},
      {"avatar",
       {{"subdivision_levels", field(a.subdivision_levels)},
        {"plane_channels", field(a.plane_channels)},
        {"plane_resolution", field(a.plane_resolution)},
        {"time_resolution", field(a.time_resolution)},
        {"face_plane_resolution", field(a.face_plane_resolution)},
        {"hidden_width", field(a.hidden_width)},
        {"joint_embedding_size", field(a.joint_embedding_size)},
        {"num_betas", field(a.num_betas)},
        {"num_expression_coeffs", field(a.num_expression_coeffs)},
        {"use_hexplane", field(a.use_hexplane)},
        {"use_structure_offset", field(a.use_structure_offset)},
        {"use_colour_offset", field(a.use_colour_offset)},
        {"use_hand_residual", field(a.use_hand_residual)},
        {"use_face_planes", field(a.use_face_planes)},
        {"use_shading", field(a.use_shading)},
        {"colour_offset_on_new_motions", field(a.colour_offset_on_new_motions)},
        {"time_dropout", field(a.time_dropout)}}},
      {"loss",
       {{"image", field(l.image)},
        {"lab", field(l.lab)},
        {"gradient", field(l.gradient)},
        {"use_lpips", field(l.use_lpips)},
        {"lpips_weights", field(l.lpips_weights)},
        {"lpips_every", field(l.lpips_every)},
        {"lpips_bfloat16", field(l.lpips_bfloat16)},
        {"mean_offset", field(l.mean_offset)},
        {"mean_offset_parts", parts_field(l.mean_offset_parts)},
        {"scale", field(l.scale)},
        {"scale_parts", parts_field(l.scale_parts)},
        {"laplacian_mean", field(l.laplacian_mean)},
        {"laplacian_mean_parts", parts_field(l.laplacian_mean_parts)},
        {"laplacian_scale", field(l.laplacian_scale)}}},
      {"schedule",
       {{"iterations", field(s.iterations)},
        {"warmup_iterations", field(s.warmup_iterations)},
        {"decay_at", field(s.decay_at)},
        {"decay_factor", field(s.decay_factor)},
        {"learning_rate", field(s.learning_rate)},
        {"colour_learning_rate", field(s.colour_learning_rate)},
        {"adam_epsilon", field(s.adam_epsilon)},
        {"fused_adam", field(s.fused_adam)},
        {"tf32_matmul", field(s.tf32_matmul)},
        {"cuda_graphs", field(s.cuda_graphs)}}},
      {"pose_refinement",
       {{"enabled", field(p.enabled)},
        {"start", field(p.start)},
        {"align_at", field(p.align_at)},
        {"align_iterations", field(p.align_iterations)},
        {"align_joints_from", field(p.align_joints_from)},
        {"align_orientation_from", field(p.align_orientation_from)},
        {"keypoint_weight", field(p.keypoint_weight)},
        {"smoothing_seconds", field(p.smoothing_seconds)},
        {"rounds", field(p.rounds)}}},
  };
}

}  // namespace

namespace {
// Reads `text` over `c` (keys it lacks keep c's values) and validates the result; `stored`: a run's own config.
TrainConfig read_yaml_over(TrainConfig c, const std::string& text, const std::string& source, bool stored) {
  YAML::Node root;
  try {
    root = YAML::Load(text);
  } catch (const YAML::Exception& e) {
    TORCH_CHECK(false, "config '", source, "' is not valid YAML: ", e.what());
  }
  if (root.IsNull()) return c;
  TORCH_CHECK(root.IsMap(), "config '", source,
              "' must be a mapping of sections (body, run, avatar, loss, schedule, pose_refinement)");
  auto table = sections(c);
  // YAML keeps a repeated key as a second entry, which would silently override the first: refused, by line.
  const auto once = [&](std::set<std::string>& seen, const YAML::Node& key, const std::string& name) {
    TORCH_CHECK(seen.insert(name).second, "config '", source, "': '", name, "' is given twice (again on line ",
                key.Mark().line + 1, "); give each section and key once");
  };
  std::set<std::string> seen_sections, seen_keys;
  for (const auto& kv : root) {
    const std::string section = kv.first.as<std::string>();
    once(seen_sections, kv.first, section);
    auto it = std::find_if(table.begin(), table.end(), [&](const auto& s) { return s.first == section; });
    TORCH_CHECK(it != table.end(), "config '", source, "': unknown section '", section,
                "' (expected body, run, avatar, loss, schedule or pose_refinement)");
    TORCH_CHECK(kv.second.IsMap(), "config '", source, "': section '", section, "' must be a mapping");
    for (const auto& entry : kv.second) {
      std::string key = entry.first.as<std::string>();
      const std::string full = section + "." + key;
      once(seen_keys, entry.first, full);
      if (retired_keys().count(full)) {
        TORCH_WARN("config '", source, "': '", full, "' is retired (no loss used it) and is ignored; remove it");
        continue;
      }
      if (per_step_keys().count(full)) {
        const bool moved = is_per_step_rate(full) && entry.second.IsScalar() && entry.second.as<double>(0.0) > 0;
        TORCH_CHECK(!moved || stored, "config '", source, "': '", full,
                    "' is positive, but per-step pose corrections were removed (they kept the avatar blurred); the "
                    "alignment passes (pose_refinement.align_at) refine the fits: remove the key");
        TORCH_WARN("config '", source, "': '", full, "' belongs to the per-step pose corrections, which were removed",
                   moved ? "; this run trained with them, and goes on with its alignment passes alone" : "",
                   "; it is ignored");
        continue;
      }
      if (const auto renamed = renamed_keys().find(full); renamed != renamed_keys().end()) {
        TORCH_WARN("config '", source, "': '", full, "' is deprecated; write '", section, ".", renamed->second, "'");
        key = renamed->second;
      }
      auto f = std::find_if(it->second.begin(), it->second.end(), [&](const auto& p) { return p.first == key; });
      TORCH_CHECK(f != it->second.end(), "config '", source, "': unknown key '", section, ".", key, "'");
      try {
        f->second.read(entry.second);
      } catch (const YAML::Exception& e) {
        TORCH_CHECK(false, "config '", source, "': bad value for '", section, ".", key, "': ", e.what());
      } catch (const c10::Error& e) {
        TORCH_CHECK(false, "config '", source, "': '", section, ".", key, "': ", e.what_without_backtrace());
      }
    }
  }
  // A run of a version with per-step corrections may have moved its fits with them alone (its stored config may even
  // predate their keys); a config to train with must give the passes that move them now.
  const bool nothing_moves = c.pose_refinement.enabled && c.pose_refinement.align_at.empty();
  TORCH_CHECK(
      stored || !nothing_moves, "config '", source,
      "': pose_refinement is enabled but nothing would move the fits: give pose_refinement.align_at (the shares "
      "of the run at which the alignment passes run)");
  if (stored && nothing_moves)
    TORCH_WARN("config '", source, "': this run refined its fits with per-step pose corrections, which were removed; ",
               "it keeps the fits it refined and has no alignment pass to move them");
  try {
    c.validate();
  } catch (const c10::Error& e) {
    std::string message = e.what_without_backtrace();
    const std::string generic = "config: ";
    if (message.rfind(generic, 0) == 0) message = message.substr(generic.size());
    TORCH_CHECK(false, "config '", source, "': ", message);
  }
  return c;
}

std::string config_text(const std::string& path) {
  std::ifstream in(path);
  TORCH_CHECK(in.good(), "cannot open config '", path, "'");
  std::stringstream text;
  text << in.rdbuf();
  return text.str();
}
}  // namespace

TrainConfig TrainConfig::from_yaml_text(const std::string& text, const std::string& source) {
  return read_yaml_over(TrainConfig{}, text, source, false);
}

TrainConfig TrainConfig::from_stored_yaml_text(const std::string& text, const std::string& source) {
  TrainConfig before_the_keys;
  before_the_keys.pose_refinement.align_at = {};
  before_the_keys.pose_refinement.align_joints_from = 1.0;
  before_the_keys.pose_refinement.align_orientation_from = 0.0;
  before_the_keys.pose_refinement.keypoint_weight = 0.0;
  return read_yaml_over(before_the_keys, text, source, true);
}

TrainConfig TrainConfig::from_yaml_file(const std::string& path) { return from_yaml_text(config_text(path), path); }

TrainConfig TrainConfig::from_stored_yaml_file(const std::string& path) {
  return from_stored_yaml_text(config_text(path), path);
}

std::string TrainConfig::to_yaml() const {
  TrainConfig copy = *this;
  YAML::Emitter e;
  e << YAML::BeginMap;
  for (auto& [name, section] : sections(copy)) {
    e << YAML::Key << name << YAML::Value << YAML::BeginMap;
    for (auto& [key, f] : section) {
      e << YAML::Key << key << YAML::Value;
      f.write(e);
    }
    e << YAML::EndMap;
  }
  e << YAML::EndMap;
  return std::string(e.c_str()) + "\n";
}

namespace {

void check_range(double value, double lo, double hi, const char* key) {
  TORCH_CHECK(std::isfinite(value) && value >= lo && value <= hi, "config: ", key, " must be a finite number in [", lo,
              ", ", hi, "], got ", value);
}

void check_positive(double value, double hi, const char* key) {
  TORCH_CHECK(std::isfinite(value) && value > 0 && value <= hi, "config: ", key, " must be a finite number in (0, ", hi,
              "], got ", value);
}

void check_count(int64_t value, int64_t lo, int64_t hi, const char* key) {
  TORCH_CHECK(value >= lo && value <= hi, "config: ", key, " must be an integer in [", lo, ", ", hi, "], got ", value);
}

void check_parts(const PartWeights& p, const char* key) {
  const std::string k(key);
  check_range(p.body, 0, kMaxLossWeight, (k + ".body").c_str());
  check_range(p.face, 0, kMaxLossWeight, (k + ".face").c_str());
  check_range(p.hands, 0, kMaxLossWeight, (k + ".hands").c_str());
}

}  // namespace

void TrainConfig::validate() const {
  check_count(schedule.iterations, 1, kMaxIterations, "schedule.iterations");
  check_count(schedule.warmup_iterations, 0, kMaxIterations, "schedule.warmup_iterations");
  TORCH_CHECK(schedule.decay_at.size() == schedule.decay_factor.size(),
              "config: schedule.decay_at and schedule.decay_factor must have the same length, got ",
              schedule.decay_at.size(), " and ", schedule.decay_factor.size());
  for (size_t i = 0; i < schedule.decay_at.size(); ++i) {
    TORCH_CHECK(std::isfinite(schedule.decay_at[i]) && schedule.decay_at[i] > 0 && schedule.decay_at[i] < 1 &&
                    (i == 0 || schedule.decay_at[i] > schedule.decay_at[i - 1]),
                "config: schedule.decay_at must rise strictly inside (0, 1), got ", schedule.decay_at[i],
                " at position ", i);
    check_positive(schedule.decay_factor[i], 1.0, "schedule.decay_factor");
  }
  check_positive(schedule.learning_rate, kMaxLearningRate, "schedule.learning_rate");
  check_positive(schedule.colour_learning_rate, kMaxLearningRate, "schedule.colour_learning_rate");
  check_positive(schedule.adam_epsilon, 1.0, "schedule.adam_epsilon");
  for (const auto& [value, key] : {std::pair{loss.image, "loss.image"},
                                   {loss.lab, "loss.lab"},
                                   {loss.gradient, "loss.gradient"},
                                   {loss.mean_offset, "loss.mean_offset"},
                                   {loss.scale, "loss.scale"},
                                   {loss.laplacian_mean, "loss.laplacian_mean"},
                                   {loss.laplacian_scale, "loss.laplacian_scale"}})
    check_range(value, 0, kMaxLossWeight, key);
  check_count(loss.lpips_every, 1, kMaxIterations, "loss.lpips_every");
  check_parts(loss.mean_offset_parts, "loss.mean_offset_parts");
  check_parts(loss.scale_parts, "loss.scale_parts");
  check_parts(loss.laplacian_mean_parts, "loss.laplacian_mean_parts");
  TORCH_CHECK(device == "cpu" || device == "cuda", "config: run.device must be cpu or cuda, got '", device, "'");
  check_count(log_every, 1, kMaxIterations, "run.log_every");
  check_count(validate_every, 1, kMaxIterations, "run.validate_every");
  check_count(checkpoint_every, 1, kMaxIterations, "run.checkpoint_every");
  check_count(validation_frames, 1, kMaxIterations, "run.validation_frames");
  check_count(avatar.subdivision_levels, 0, 3, "avatar.subdivision_levels");
  check_count(avatar.plane_channels, 1, kMaxPlaneChannels, "avatar.plane_channels");
  check_count(avatar.plane_resolution, 2, kMaxPlaneResolution, "avatar.plane_resolution");
  check_count(avatar.time_resolution, 2, kMaxPlaneResolution, "avatar.time_resolution");
  check_count(avatar.face_plane_resolution, 2, kMaxPlaneResolution, "avatar.face_plane_resolution");
  check_count(avatar.hidden_width, 1, kMaxHiddenWidth, "avatar.hidden_width");
  check_count(avatar.joint_embedding_size, 1, kMaxHiddenWidth, "avatar.joint_embedding_size");
  check_count(avatar.num_betas, 0, kMaxHiddenWidth, "avatar.num_betas");
  check_count(avatar.num_expression_coeffs, 0, kMaxHiddenWidth, "avatar.num_expression_coeffs");
  check_range(avatar.time_dropout, 0, 1, "avatar.time_dropout");
  check_range(pose_refinement.start, 0, 1, "pose_refinement.start");
  check_range(pose_refinement.keypoint_weight, 0, kMaxLossWeight, "pose_refinement.keypoint_weight");
  check_range(pose_refinement.smoothing_seconds, 0, kMaxFitSmoothingSeconds, "pose_refinement.smoothing_seconds");
  const std::vector<double>& align_at = pose_refinement.align_at;
  for (size_t i = 0; i < align_at.size(); ++i)
    TORCH_CHECK(std::isfinite(align_at[i]) && align_at[i] >= pose_refinement.start && align_at[i] < 1 &&
                    (i == 0 || align_at[i] > align_at[i - 1]),
                "config: pose_refinement.align_at must rise strictly from pose_refinement.start (",
                pose_refinement.start, ") to below 1, got ", align_at[i], " at position ", i);
  check_count(pose_refinement.align_iterations, 1, kMaxIterations, "pose_refinement.align_iterations");
  check_count(pose_refinement.rounds, 1, kMaxPoseRefinementRounds, "pose_refinement.rounds");
  TORCH_CHECK(pose_refinement.enabled || pose_refinement.rounds == 1, "config: pose_refinement.rounds is ",
              pose_refinement.rounds,
              " but pose_refinement is not enabled: a later round starts from the refined fits ",
              "of the one before, which only a refining run makes; enable it or leave rounds at 1");
  check_range(pose_refinement.align_joints_from, 0, 1, "pose_refinement.align_joints_from");
  check_range(pose_refinement.align_orientation_from, 0, 1, "pose_refinement.align_orientation_from");
  TORCH_CHECK(pose_refinement.align_orientation_from <= pose_refinement.align_joints_from,
              "config: pose_refinement.align_orientation_from (", pose_refinement.align_orientation_from,
              ") must not exceed pose_refinement.align_joints_from (", pose_refinement.align_joints_from,
              "): joints fitted under a held root would take up its error");
}

std::vector<ConfigChange> config_changes(const TrainConfig& before, const TrainConfig& after) {
  TrainConfig a = before, b = after;
  const auto table_a = sections(a), table_b = sections(b);
  std::vector<ConfigChange> changes;
  for (size_t s = 0; s < table_a.size(); ++s) {
    for (size_t k = 0; k < table_a[s].second.size(); ++k) {
      YAML::Emitter ea, eb;
      ea << YAML::Flow;
      eb << YAML::Flow;
      table_a[s].second[k].second.write(ea);
      table_b[s].second[k].second.write(eb);
      if (std::string(ea.c_str()) != std::string(eb.c_str()))
        changes.push_back({table_a[s].first + "." + table_a[s].second[k].first, ea.c_str(), eb.c_str()});
    }
  }
  return changes;
}

bool change_allowed_on_resume(const std::string& key) {
  if (key.rfind("schedule.", 0) == 0) return true;
  for (const char* allowed :
       {"run.log_every", "run.validate_every", "run.checkpoint_every", "run.validation_frames", "run.device"})
    if (key == allowed) return true;
  return false;
}

}  // namespace sfgs::train
