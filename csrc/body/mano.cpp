#include "body/mano.h"

#include <utility>

#include <ATen/Functions.h>
#include <ATen/TensorOperators.h>
#include <c10/util/Exception.h>

#include "body/mesh.h"
#include "body/model_arrays.h"
#include "body/rotations.h"
#include "body/skeleton.h"
#include "body/tensor_checks.h"
#include "body/constants.h"
#include "io/npz.h"

namespace sfgs::body {

ManoModelData ManoModelData::load(const std::string& path) {
  const io::NpzArchive npz(path);
  const ModelArrays arrays(npz, "MANO");
  ManoModelData d;
  d.source = path;
  d.v_template = arrays.floating("v_template", {-1, 3});
  const int64_t v = d.v_template.size(0);
  d.faces = arrays.faces("f", v);
  d.j_regressor = arrays.floating("J_regressor", {-1, v});
  TORCH_CHECK(d.j_regressor.size(0) == kManoJointCount, arrays.name("J_regressor"), " regresses ",
              d.j_regressor.size(0), " joints; MANO has ", kManoJointCount);
  d.weights = arrays.floating("weights", {v, kManoJointCount});
  d.parents = arrays.parents("kintree_table", kManoJointCount);
  d.shapedirs = arrays.floating("shapedirs", {v, 3, -1});
  d.posedirs = arrays.posedirs("posedirs", v, kManoJointCount);
  d.hands_components = arrays.floating("hands_components", {-1, kHandPoseSize});
  d.hands_mean = arrays.floating("hands_mean", {kHandPoseSize});
  d.validate();
  return d;
}

void ManoModelData::validate() const {
  const ModelChecks check("MANO model '" + source + "'");
  check.skinned_model(*this, kManoJointCount);
  check.hand_components(hands_components, "hands_components");
  check.floating(hands_mean, "hands_mean", {kHandPoseSize});
}

void ManoModelData::save(const std::string& path, bool overwrite) const {
  validate();
  const int64_t v = v_template.size(0);
  const auto f64 = at::TensorOptions().dtype(at::kDouble);
  std::vector<int64_t> parent_row(parents);
  parent_row[0] = 4294967295LL;  // numpy's uint32 -1, as the official kintree_table
  const at::Tensor kintree =
      at::stack({at::tensor(parent_row, at::kLong), at::arange(kManoJointCount, at::TensorOptions(at::kLong))});
  io::write_npz(
      path,
      {{"v_template", v_template.to(f64)},
       {"f", faces.to(at::kLong)},
       {"J_regressor", j_regressor.to(f64)},
       {"weights", weights.to(f64)},
       {"kintree_table", kintree},
       {"shapedirs", shapedirs.to(f64)},
       {"posedirs", posedirs.defined() ? posedirs.to(f64) : at::zeros({v, 3, 9 * (kManoJointCount - 1)}, f64)},
       {"hands_components", hands_components.to(f64)},
       {"hands_mean", hands_mean.to(f64)},
       {"J", j_regressor.to(f64).matmul(v_template.to(f64))}},
      overwrite);
}

bool repair_left_mano_shapedirs(ManoModelData& left, const ManoModelData& right) {
  left.validate();
  right.validate();
  TORCH_CHECK(left.shapedirs.sizes() == right.shapedirs.sizes(), "repair_left_mano_shapedirs: the left model ('",
              left.source, "') and the right model ('", right.source, "') have different shapedirs shapes (",
              left.shapedirs.sizes(), " and ", right.shapedirs.sizes(), ")");
  const at::Tensor left_x = left.shapedirs.select(1, 0), right_x = right.shapedirs.select(1, 0);
  const double difference = (left_x - right_x).abs().sum().item<double>();
  const double scale = right_x.abs().sum().item<double>();
  if (difference > kManoLeftShapedirsBugTolerance * scale) return false;
  left.shapedirs = left.shapedirs.clone();
  left.shapedirs.select(1, 0).neg_();
  return true;
}

ManoImpl::ManoImpl(const std::string& path, ManoOptions options) : ManoImpl(ManoModelData::load(path), options) {}

ManoImpl::ManoImpl(const ManoModelData& data, ManoOptions options) : options_(options) {
  data.validate();
  const std::string what = "Mano ('" + data.source + "')";
  TORCH_CHECK(options_.num_betas >= 0, what, ": num_betas must be >= 0, got ", options_.num_betas);
  if (options_.num_betas > data.shapedirs.size(2)) {
    TORCH_WARN(what, " has ", data.shapedirs.size(2), " shape directions; using ", data.shapedirs.size(2),
               " betas instead of ", options_.num_betas);
    options_.num_betas = data.shapedirs.size(2);
  }
  TORCH_CHECK(options_.subdivision_levels >= 0, what, ": subdivision_levels must be >= 0, got ",
              options_.subdivision_levels);
  SkinnedMeshData mesh;
  mesh.v_template = data.v_template;
  mesh.faces = data.faces;
  mesh.j_regressor = data.j_regressor;
  mesh.weights = data.weights;
  mesh.parents = data.parents;
  mesh.blend_shapes = data.shapedirs.narrow(2, 0, options_.num_betas);
  mesh.posedirs = data.posedirs;
  mesh_ = register_module("mesh", SkinnedMesh(mesh, options_.dtype, options_.subdivision_levels));
  if (options_.use_pca) {
    TORCH_CHECK(options_.num_pca_comps >= 1 && options_.num_pca_comps <= data.hands_components.size(0), what,
                ": num_pca_comps must lie in [1, ", data.hands_components.size(0), "], got ", options_.num_pca_comps);
    components_ = register_buffer(
        "hands_components", buffer_copy(data.hands_components.narrow(0, 0, options_.num_pca_comps), options_.dtype));
  }
  mean_ = register_buffer("hands_mean", buffer_copy(data.hands_mean, options_.dtype));
}

ManoOutput ManoImpl::forward(const ManoInput& input) const {
  const int64_t batch =
      common_batch_size("Mano",
                        {{"betas", &input.betas},
                         {"global_orient", &input.global_orient},
                         {"hand_pose", &input.hand_pose},
                         {"transl", &input.transl},
                         {"rotations", &input.rotations}},
                        {{"vertex_offsets", &input.vertex_offsets}, {"joint_offsets", &input.joint_offsets}});
  const auto options = at::TensorOptions().dtype(dtype()).device(device());
  const auto given_or_zeros = [&](const at::Tensor& t, const std::string& name, int64_t count) {
    if (!t.defined()) return at::zeros({batch, count}, options);
    check_tensor(t, "Mano: " + name, {batch, count}, dtype(), device());
    return t;
  };
  ManoOutput out;
  at::Tensor rotations;
  if (input.rotations.defined()) {
    TORCH_CHECK(!input.global_orient.defined() && !input.hand_pose.defined(),
                "Mano: give either rotations or global_orient / hand_pose, not both");
    check_tensor(input.rotations, "Mano: rotations", {batch, kManoJointCount, 3, 3}, dtype(), device());
    rotations = input.rotations;
  } else {
    at::Tensor hand;
    if (options_.use_pca) {
      hand = input.hand_pose.defined()
                 ? given_or_zeros(input.hand_pose, "hand_pose (PCA coefficients)", options_.num_pca_comps)
                       .matmul(components_)
                 : at::zeros({batch, kHandPoseSize}, options);
    } else {
      const at::Tensor& pose = input.hand_pose;
      hand = given_or_zeros(pose.defined() && pose.dim() == 3 ? pose.flatten(1) : pose, "hand_pose (or (B, 15, 3))",
                            kHandPoseSize);
    }
    if (!options_.flat_hand_mean) hand = hand + mean_;
    out.full_pose =
        at::cat({given_or_zeros(input.global_orient, "global_orient", 3), hand}, 1).view({batch, kManoJointCount, 3});
    rotations = axis_angle_to_matrix(out.full_pose);
  }
  static_cast<BodyOutput&>(out) =
      mesh_->forward(given_or_zeros(input.betas, "betas", options_.num_betas), rotations,
                     given_or_zeros(input.transl, "transl", 3), input.vertex_offsets, input.joint_offsets);
  return out;
}

}  // namespace sfgs::body
