#include "train/checkpoint.h"

#include <filesystem>
#include <sstream>
#include <vector>

#include <ATen/ATen.h>
#include <torch/serialize/output-archive.h>

#include "common/atomic_file.h"
#include "common/checksum.h"
#include "model/sampling_filter.h"

namespace sfgs::train {

std::unique_ptr<torch::optim::Adam> make_optimizer(const model::Avatar& avatar, const Schedule& schedule) {
  std::vector<at::Tensor> colour, other;
  for (const auto& p : avatar->named_parameters())
    (p.key().find("colour") != std::string::npos ? colour : other).push_back(p.value());
  std::vector<torch::optim::OptimizerParamGroup> groups;
  const auto options = [&](double rate) {
    return std::make_unique<torch::optim::AdamOptions>(torch::optim::AdamOptions(rate).eps(schedule.adam_epsilon));
  };
  groups.emplace_back(other, options(schedule.learning_rate));
  if (!colour.empty()) groups.emplace_back(colour, options(schedule.colour_learning_rate));
  return std::make_unique<torch::optim::Adam>(groups, *options(schedule.learning_rate));
}

namespace {

constexpr const char* kFormatName = "sfgs-checkpoint";
constexpr int64_t kFormatVersion = 2;

at::Tensor string_tensor(const std::string& s) {
  return at::from_blob(const_cast<char*>(s.data()), {int64_t(s.size())}, at::kByte).clone();
}

std::string tensor_string(const at::Tensor& t) {
  const at::Tensor c = t.contiguous();
  return std::string(reinterpret_cast<const char*>(c.data_ptr<uint8_t>()), size_t(c.numel()));
}

// Every parameter and buffer of the avatar by name, the way save()/load() name them.
std::vector<std::pair<std::string, at::Tensor>> avatar_tensors(const model::Avatar& avatar) {
  std::vector<std::pair<std::string, at::Tensor>> tensors;
  for (const auto& p : avatar->named_parameters()) tensors.emplace_back(p.key(), p.value());
  for (const auto& b : avatar->named_buffers()) tensors.emplace_back(b.key(), b.value());
  return tensors;
}

std::string serialised(torch::optim::Optimizer& optimizer) {
  torch::serialize::OutputArchive archive;
  optimizer.save(archive);
  std::ostringstream bytes;
  archive.save_to(bytes);
  return bytes.str();
}

}  // namespace

std::string first_non_finite_tensor(const torch::nn::Module& module) {
  std::vector<std::pair<std::string, at::Tensor>> floating;
  for (const auto& p : module.named_parameters())
    if (at::isFloatingType(p.value().scalar_type())) floating.emplace_back(p.key(), p.value());
  for (const auto& b : module.named_buffers())
    if (at::isFloatingType(b.value().scalar_type())) floating.emplace_back(b.key(), b.value());
  if (floating.empty()) return "";
  std::vector<at::Tensor> finite;
  for (const auto& [name, t] : floating) finite.push_back(t.detach().isfinite().all());
  const at::Tensor all = at::stack(finite).cpu();  // the one synchronisation
  for (size_t i = 0; i < floating.size(); ++i) {
    if (all[int64_t(i)].item<bool>()) continue;
    const at::Tensor t = floating[i].second.detach();
    const int64_t bad = t.numel() - t.isfinite().sum().item<int64_t>();
    return "'" + floating[i].first + "' (" + std::to_string(bad) + " of " + std::to_string(t.numel()) + " values)";
  }
  return "";
}

void save_checkpoint(const std::string& path, const CheckpointInfo& info, const model::Avatar& avatar,
                     torch::optim::Optimizer& optimizer) {
  const std::string bad = first_non_finite_tensor(*avatar);
  if (!bad.empty())
    throw std::runtime_error("not writing checkpoint '" + path + "' at iteration " + std::to_string(info.iteration) +
                             ": parameter " + bad + " is not finite");
  torch::serialize::OutputArchive archive, avatar_archive;
  avatar->save(avatar_archive);
  nlohmann::json checksums;
  for (const auto& [name, t] : avatar_tensors(avatar)) checksums["avatar." + name] = crc32_of(t);
  const std::string optimizer_bytes = serialised(optimizer);
  checksums["optimizer"] = crc32_of(optimizer_bytes.data(), optimizer_bytes.size());
  checksums["betas"] = crc32_of(info.betas);
  if (info.observation_sum.defined()) {
    const at::Tensor observation = info.observation_sum.detach().to(at::kCPU, at::kFloat).contiguous();
    checksums["observation"] = crc32_of(observation);
    archive.write("observation", observation);
    archive.write("observation_steps", at::tensor({info.observation_steps}, at::kLong));
  }
  if (info.footprint_minimum.defined()) {
    const at::Tensor footprint = info.footprint_minimum.detach().to(at::kCPU, at::kFloat).contiguous();
    checksums["sampling"] = crc32_of(footprint);
    archive.write("sampling", footprint);
  }
  if (info.pose_refinement.defined()) {
    const at::Tensor refinement = info.pose_refinement.detach().to(at::kCPU, at::kDouble).contiguous();
    checksums["pose_refinement"] = crc32_of(refinement);
    archive.write("pose_refinement", refinement);
  }
  archive.write("format", string_tensor(kFormatName));
  archive.write("version", at::tensor({kFormatVersion}, at::kLong));
  archive.write("avatar", avatar_archive);
  archive.write("optimizer_state", string_tensor(optimizer_bytes));
  archive.write("iteration", at::tensor({info.iteration}, at::kLong));
  archive.write("training_seconds", at::tensor({info.training_seconds}, at::kDouble));
  archive.write("rng", string_tensor(info.rng_state));
  archive.write("config", string_tensor(info.config.to_yaml()));
  archive.write("dataset", string_tensor(info.dataset));
  archive.write("dataset_fingerprint", string_tensor(info.dataset_fingerprint));
  archive.write("betas", info.betas.cpu());
  archive.write("checksums", string_tensor(checksums.dump()));
  std::ostringstream bytes;
  archive.save_to(bytes);
  const std::string data = bytes.str();
  write_file_atomically(path, std::vector<unsigned char>(data.begin(), data.end()), true);
}

CheckpointReader::CheckpointReader(const std::string& path) : path_(path) {
  TORCH_CHECK(std::filesystem::exists(path), "checkpoint '", path, "' does not exist");
  try {
    archive_.load_from(path);
  } catch (const c10::Error& e) {
    TORCH_CHECK(false, "'", path, "' is not a readable sfgs checkpoint (the file is damaged or of another kind): ",
                e.what_without_backtrace());
  }
  const auto read = [&](const char* key) {
    at::Tensor t;
    TORCH_CHECK(archive_.try_read(key, t), "checkpoint '", path, "' lacks its '", key,
                "' entry (the file is damaged or was not written by sfgs)");
    return t;
  };
  at::Tensor version;
  info_.version = archive_.try_read("version", version) ? version.item<int64_t>() : 1;
  TORCH_CHECK(info_.version <= kFormatVersion, "checkpoint '", path, "' has format version ", info_.version,
              "; this sfgs reads versions up to ", kFormatVersion, " (update sfgs)");
  if (info_.version >= 2) {
    TORCH_CHECK(tensor_string(read("format")) == kFormatName, "'", path, "' is not an sfgs checkpoint");
    checksums_ = nlohmann::json::parse(tensor_string(read("checksums")), nullptr, false);
    TORCH_CHECK(checksums_.is_object(), "checkpoint '", path, "' has a damaged checksum table");
    at::Tensor fingerprint;
    if (archive_.try_read("dataset_fingerprint", fingerprint)) info_.dataset_fingerprint = tensor_string(fingerprint);
  }
  info_.iteration = read("iteration").item<int64_t>();
  at::Tensor seconds;
  if (archive_.try_read("training_seconds", seconds)) info_.training_seconds = seconds.item<double>();
  info_.rng_state = tensor_string(read("rng"));
  info_.dataset = tensor_string(read("dataset"));
  info_.betas = read("betas");
  at::Tensor steps;
  if (archive_.try_read("observation_steps", steps) && archive_.try_read("observation", info_.observation_sum)) {
    info_.observation_steps = steps.item<int64_t>();
    TORCH_CHECK(checksums_.value("observation", uint32_t(0)) == crc32_of(info_.observation_sum), "checkpoint '", path,
                "' is damaged: its observation record does not match the checksum written with it");
    TORCH_CHECK(info_.observation_steps > 0, "checkpoint '", path, "' has an observation record over ",
                info_.observation_steps, " steps");
  }
  if (archive_.try_read("sampling", info_.footprint_minimum)) {
    TORCH_CHECK(checksums_.value("sampling", uint32_t(0)) == crc32_of(info_.footprint_minimum), "checkpoint '", path,
                "' is damaged: its sampling record does not match the checksum written with it");
    TORCH_CHECK(
        !info_.footprint_minimum.isnan().any().item<bool>() && (info_.footprint_minimum >= 0).all().item<bool>(),
        "checkpoint '", path, "' has a sampling record with negative or NaN footprints");
  }
  if (archive_.try_read("pose_refinement", info_.pose_refinement)) {
    TORCH_CHECK(checksums_.value("pose_refinement", uint32_t(0)) == crc32_of(info_.pose_refinement), "checkpoint '",
                path, "' is damaged: its pose refinement state does not match the checksum written with it");
    TORCH_CHECK(info_.pose_refinement.isfinite().all().item<bool>(), "checkpoint '", path,
                "' holds non-finite pose corrections");
  }
  if (info_.version >= 2)
    TORCH_CHECK(checksums_.value("betas", uint32_t(0)) == crc32_of(info_.betas), "checkpoint '", path,
                "' is damaged: its betas do not match the checksum written with them");
  info_.config = TrainConfig::from_stored_yaml_text(tensor_string(read("config")), path + " (its config)");
}

void CheckpointReader::load_avatar(model::Avatar& avatar) {
  torch::serialize::InputArchive nested;
  TORCH_CHECK(archive_.try_read("avatar", nested), "checkpoint '", path_, "' lacks the avatar's state");
  try {
    avatar->load(nested);
  } catch (const c10::Error& e) {
    TORCH_CHECK(false, "checkpoint '", path_,
                "' does not hold the avatar its config describes (damaged, or written by "
                "another version of sfgs): ",
                e.what_without_backtrace());
  }
  if (info_.version >= 2) {
    for (const auto& [name, t] : avatar_tensors(avatar)) {
      const std::string key = "avatar." + name;
      TORCH_CHECK(checksums_.contains(key) && checksums_[key].get<uint32_t>() == crc32_of(t), "checkpoint '", path_,
                  "' is damaged: tensor '", name,
                  "' does not match the checksum written with it (use an earlier copy "
                  "of the run or train it again)");
    }
  }
  const std::string bad = first_non_finite_tensor(*avatar);
  TORCH_CHECK(bad.empty(), "checkpoint '", path_, "' holds non-finite values in ", bad,
              ": the run diverged before it was written, or the file is damaged; it cannot be used");
  // The observation record (checkpoints of runs trained before it existed have none: every Gaussian is trusted).
  if (info_.observation_sum.defined()) avatar->set_observation(info_.observation_sum / double(info_.observation_steps));
  // Likewise the sampling record (none: renders are not widened).
  if (info_.footprint_minimum.defined()) avatar->set_sampling_record(model::sampling_record(info_.footprint_minimum));
}

void CheckpointReader::load_optimizer(torch::optim::Optimizer& optimizer) {
  if (info_.version < 2) {
    torch::serialize::InputArchive nested;
    archive_.read("optimizer", nested);
    optimizer.load(nested);
    return;
  }
  at::Tensor state;
  TORCH_CHECK(archive_.try_read("optimizer_state", state), "checkpoint '", path_, "' lacks the optimiser's state");
  const std::string bytes = tensor_string(state);
  TORCH_CHECK(checksums_.value("optimizer", uint32_t(0)) == crc32_of(bytes.data(), bytes.size()), "checkpoint '", path_,
              "' is damaged: the optimiser state does not match the checksum written with it");
  torch::serialize::InputArchive nested;
  nested.load_from(bytes.data(), bytes.size());
  optimizer.load(nested);
}

}  // namespace sfgs::train
