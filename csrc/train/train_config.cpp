#include "train/train_config.h"

#include <algorithm>
#include <fstream>
#include <functional>
#include <map>
#include <sstream>

#include <c10/util/Exception.h>
#include <yaml-cpp/yaml.h>

namespace sfgs::train {
namespace {

// One table maps every key to its field, for reading and writing alike.
struct Field {
  std::function<void(const YAML::Node&)> read;
  std::function<void(YAML::Emitter&)> write;
};

template <typename T> Field field(T& target) {
  return Field{[&target](const YAML::Node& n) { target = n.as<T>(); },
               [&target](YAML::Emitter& e) { e << target; }};
}

Field parts_field(PartWeights& p) {
  return Field{[&p](const YAML::Node& n) {
                 for (const auto& kv : n) {
                   const std::string key = kv.first.as<std::string>();
                   if (key == "body") p.body = kv.second.as<double>();
                   else if (key == "face") p.face = kv.second.as<double>();
                   else if (key == "hands") p.hands = kv.second.as<double>();
                   else TORCH_CHECK(false, "unknown part '", key, "' (expected body, face or hands)");
                 }
               },
               [&p](YAML::Emitter& e) {
                 e << YAML::Flow << YAML::BeginMap << YAML::Key << "body" << YAML::Value << p.body << YAML::Key << "face"
                   << YAML::Value << p.face << YAML::Key << "hands" << YAML::Value << p.hands << YAML::EndMap;
               }};
}

using Section = std::vector<std::pair<std::string, Field>>;

std::vector<std::pair<std::string, Section>> sections(TrainConfig& c) {
  model::AvatarConfig& a = c.avatar;
  LossWeights& l = c.loss;
  Schedule& s = c.schedule;
  BodyFiles& b = c.body;
  return {
      {"body", {{"smplx", field(b.smplx)}, {"mano_left", field(b.mano_left)}, {"mano_right", field(b.mano_right)},
                {"hand_vertex_ids", field(b.hand_vertex_ids)}, {"face_vertex_ids", field(b.face_vertex_ids)}}},
      {"run", {{"seed", field(c.seed)}, {"device", field(c.device)}, {"log_every", field(c.log_every)},
               {"validate_every", field(c.validate_every)}, {"checkpoint_every", field(c.checkpoint_every)},
               {"validation_frames", field(c.validation_frames)}}},
      {"avatar", {{"subdivision_levels", field(a.subdivision_levels)}, {"plane_channels", field(a.plane_channels)},
                  {"plane_resolution", field(a.plane_resolution)}, {"time_resolution", field(a.time_resolution)},
                  {"face_plane_resolution", field(a.face_plane_resolution)}, {"hidden_width", field(a.hidden_width)},
                  {"joint_embedding_size", field(a.joint_embedding_size)}, {"num_betas", field(a.num_betas)},
                  {"num_expression_coeffs", field(a.num_expression_coeffs)}, {"use_hexplane", field(a.use_hexplane)},
                  {"use_structure_offset", field(a.use_structure_offset)}, {"use_color_offset", field(a.use_color_offset)},
                  {"use_hand_residual", field(a.use_hand_residual)}, {"use_face_planes", field(a.use_face_planes)}}},
      {"loss", {{"image", field(l.image)}, {"lab", field(l.lab)}, {"gradient", field(l.gradient)},
                {"use_lpips", field(l.use_lpips)}, {"lpips_weights", field(l.lpips_weights)}, {"face", field(l.face)},
                {"mean_offset", field(l.mean_offset)}, {"mean_offset_parts", parts_field(l.mean_offset_parts)},
                {"scale", field(l.scale)}, {"scale_parts", parts_field(l.scale_parts)},
                {"laplacian_mean", field(l.laplacian_mean)}, {"laplacian_mean_parts", parts_field(l.laplacian_mean_parts)},
                {"laplacian_scale", field(l.laplacian_scale)}, {"joint_drift", field(l.joint_drift)}}},
      {"schedule", {{"iterations", field(s.iterations)}, {"warmup_iterations", field(s.warmup_iterations)},
                    {"decay_at", field(s.decay_at)}, {"decay_factor", field(s.decay_factor)},
                    {"learning_rate", field(s.learning_rate)}, {"colour_learning_rate", field(s.colour_learning_rate)},
                    {"adam_epsilon", field(s.adam_epsilon)}}},
  };
}

}  // namespace

TrainConfig TrainConfig::from_yaml_text(const std::string& text, const std::string& source) {
  TrainConfig c;
  YAML::Node root;
  try {
    root = YAML::Load(text);
  } catch (const YAML::Exception& e) {
    TORCH_CHECK(false, "config '", source, "' is not valid YAML: ", e.what());
  }
  if (root.IsNull()) return c;
  TORCH_CHECK(root.IsMap(), "config '", source, "' must be a mapping of sections (body, run, avatar, loss, schedule)");
  auto table = sections(c);
  for (const auto& kv : root) {
    const std::string section = kv.first.as<std::string>();
    auto it = std::find_if(table.begin(), table.end(), [&](const auto& s) { return s.first == section; });
    TORCH_CHECK(it != table.end(), "config '", source, "': unknown section '", section,
                "' (expected body, run, avatar, loss or schedule)");
    TORCH_CHECK(kv.second.IsMap(), "config '", source, "': section '", section, "' must be a mapping");
    for (const auto& entry : kv.second) {
      const std::string key = entry.first.as<std::string>();
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
  c.validate();
  return c;
}

TrainConfig TrainConfig::from_yaml_file(const std::string& path) {
  std::ifstream in(path);
  TORCH_CHECK(in.good(), "cannot open config '", path, "'");
  std::stringstream text;
  text << in.rdbuf();
  return from_yaml_text(text.str(), path);
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

void TrainConfig::validate() const {
  TORCH_CHECK(schedule.iterations >= 1, "schedule.iterations must be at least 1, got ", schedule.iterations);
  TORCH_CHECK(schedule.warmup_iterations >= 0, "schedule.warmup_iterations must be >= 0");
  TORCH_CHECK(schedule.decay_at.size() == schedule.decay_factor.size(),
              "schedule.decay_at and schedule.decay_factor must have the same length");
  for (size_t i = 0; i < schedule.decay_at.size(); ++i)
    TORCH_CHECK(schedule.decay_at[i] > 0 && schedule.decay_at[i] < 1 && (i == 0 || schedule.decay_at[i] > schedule.decay_at[i - 1]),
                "schedule.decay_at must rise strictly inside (0, 1)");
  TORCH_CHECK(schedule.learning_rate > 0 && schedule.colour_learning_rate > 0, "learning rates must be positive");
  TORCH_CHECK(device == "cpu" || device == "cuda", "run.device must be cpu or cuda, got '", device, "'");
  TORCH_CHECK(log_every >= 1 && validate_every >= 1 && checkpoint_every >= 1, "run.*_every must be at least 1");
  TORCH_CHECK(avatar.subdivision_levels >= 0 && avatar.subdivision_levels <= 3, "avatar.subdivision_levels must be in [0, 3]");
  TORCH_CHECK(avatar.plane_channels >= 1 && avatar.plane_resolution >= 2 && avatar.time_resolution >= 2 &&
                  avatar.face_plane_resolution >= 2 && avatar.hidden_width >= 1,
              "avatar plane and network sizes must be positive");
}

}  // namespace sfgs::train
