#include "body/smplx.h"

#include <utility>

#include <ATen/Functions.h>
#include <ATen/TensorOperators.h>
#include <c10/util/Exception.h>

#include "body/mesh.h"
#include "body/model_arrays.h"
#include "body/rotations.h"
#include "body/skeleton.h"
#include "body/tensor_checks.h"
#include "io/npz.h"

namespace sfgs::body {
namespace {

// numpy's uint32 -1, the root marker the official kintree_table carries in [0, 0].
constexpr int64_t kOfficialRootMarker = 4294967295LL;

}  // namespace

SmplxModelData SmplxModelData::load(const std::string& path) {
  const io::NpzArchive npz(path);
  const ModelArrays arrays(npz, "SMPL-X");
  SmplxModelData d;
  d.source = path;
  d.v_template = arrays.floating("v_template", {-1, 3});
  const int64_t v = d.v_template.size(0);
  d.faces = arrays.faces("f", v);
  d.j_regressor = arrays.floating("J_regressor", {-1, v});
  TORCH_CHECK(d.j_regressor.size(0) == kSmplxJointCount, arrays.name("J_regressor"), " regresses ",
              d.j_regressor.size(0), " joints; SMPL-X has ", kSmplxJointCount,
              " (an SMPL file has 24, an SMPL+H file 52)");
  d.weights = arrays.floating("weights", {v, kSmplxJointCount});
  d.parents = arrays.parents("kintree_table", kSmplxJointCount);
  const at::Tensor blend = arrays.floating("shapedirs", {v, 3, -1});
  const int64_t columns = blend.size(2);
  int64_t shape_space = 0;
  if (columns == kSmplxShapeSpace + kSmplxExpressionSpace) {
    shape_space = kSmplxShapeSpace;
  } else if (columns == kSmplxV10ShapeSpace + kSmplxV10ExpressionSpace) {
    shape_space = kSmplxV10ShapeSpace;
  } else {
    TORCH_CHECK(false, arrays.name("shapedirs"), " has ", columns, " blend shapes; SMPL-X v1.1 has ",
                kSmplxShapeSpace + kSmplxExpressionSpace, " (", kSmplxShapeSpace, " shape + ", kSmplxExpressionSpace,
                " expression) and v1.0 has ", kSmplxV10ShapeSpace + kSmplxV10ExpressionSpace);
  }
  d.shapedirs = blend.narrow(2, 0, shape_space).contiguous();
  d.exprdirs = blend.narrow(2, shape_space, columns - shape_space).contiguous();
  d.posedirs = arrays.posedirs("posedirs", v, kSmplxJointCount);
  d.hands_components_left = arrays.floating("hands_componentsl", {-1, kHandPoseSize});
  d.hands_components_right = arrays.floating("hands_componentsr", {-1, kHandPoseSize});
  d.hands_mean_left = arrays.floating("hands_meanl", {kHandPoseSize});
  d.hands_mean_right = arrays.floating("hands_meanr", {kHandPoseSize});
  TORCH_CHECK(npz.contains("vt") == npz.contains("ft"), "'", path, "' has only one of 'vt' and 'ft'");
  if (npz.contains("vt")) {
    d.uvs = arrays.floating("vt", {-1, 2});
    d.uv_faces = arrays.faces("ft", d.uvs.size(0));
  }
  if (npz.contains("part_labels")) d.part_labels = arrays.labels("part_labels", v);
  d.validate();
  return d;
}

void SmplxModelData::validate() const {
  const std::string what = "SMPL-X model '" + source + "'";
  const ModelChecks check(what);
  const int64_t v = check.skinned_model(*this, kSmplxJointCount);
  check.floating(exprdirs, "exprdirs", {v, 3, -1});
  check.hand_components(hands_components_left, "hands_components_left");
  check.hand_components(hands_components_right, "hands_components_right");
  check.floating(hands_mean_left, "hands_mean_left", {kHandPoseSize});
  check.floating(hands_mean_right, "hands_mean_right", {kHandPoseSize});
  TORCH_CHECK(uvs.defined() == uv_faces.defined(), what, ": uvs and uv_faces come together");
  if (uvs.defined()) {
    check.floating(uvs, "uvs", {-1, 2});
    checked_faces(uv_faces, uvs.size(0), what + ": uv_faces");
    TORCH_CHECK(uv_faces.size(0) == faces.size(0), what, ": uv_faces has ", uv_faces.size(0), " faces, faces has ",
                faces.size(0));
  }
  if (part_labels.defined()) check.labels(part_labels, "part_labels", v);
}

void SmplxModelData::save(const std::string& path, bool overwrite) const {
  validate();
  const int64_t v = v_template.size(0);
  TORCH_CHECK(shapedirs.size(2) <= kSmplxShapeSpace && exprdirs.size(2) <= kSmplxExpressionSpace, "cannot save '", path,
              "': the v1.1 layout holds at most ", kSmplxShapeSpace, " shape and ", kSmplxExpressionSpace,
              " expression directions, the model has ", shapedirs.size(2), " and ", exprdirs.size(2));
  const auto f64 = at::TensorOptions().dtype(at::kDouble);
  at::Tensor blend = at::zeros({v, 3, kSmplxShapeSpace + kSmplxExpressionSpace}, f64);
  blend.narrow(2, 0, shapedirs.size(2)).copy_(shapedirs);
  blend.narrow(2, kSmplxShapeSpace, exprdirs.size(2)).copy_(exprdirs);
  std::vector<int64_t> parent_row(parents);
  parent_row[0] = kOfficialRootMarker;
  const at::Tensor kintree =
      at::stack({at::tensor(parent_row, at::kLong), at::arange(kSmplxJointCount, at::TensorOptions(at::kLong))});
  std::vector<std::pair<std::string, at::Tensor>> arrays = {
      {"v_template", v_template.to(f64)},
      {"f", faces.to(at::kLong)},
      {"J_regressor", j_regressor.to(f64)},
      {"weights", weights.to(f64)},
      {"kintree_table", kintree},
      {"shapedirs", blend},
      {"posedirs", posedirs.defined() ? posedirs.to(f64) : at::zeros({v, 3, 9 * (kSmplxJointCount - 1)}, f64)},
      {"hands_componentsl", hands_components_left.to(f64)},
      {"hands_componentsr", hands_components_right.to(f64)},
      {"hands_meanl", hands_mean_left.to(f64)},
      {"hands_meanr", hands_mean_right.to(f64)}};
  if (uvs.defined()) {
    arrays.emplace_back("vt", uvs.to(f64));
    arrays.emplace_back("ft", uv_faces.to(at::kLong));
  }
  if (part_labels.defined()) arrays.emplace_back("part_labels", part_labels.to(at::kByte));
  io::write_npz(path, arrays, overwrite);
}

SmplxModelData subdivide(const SmplxModelData& data, int64_t levels) {
  data.validate();
  SmplxModelData fine = data;
  for (const MidpointSubdivision& step : midpoint_subdivisions(data.faces, data.v_template.size(0), levels)) {
    fine.v_template = step.interpolate(fine.v_template);
    fine.weights = step.interpolate(fine.weights);
    fine.shapedirs = step.interpolate(fine.shapedirs);
    fine.exprdirs = step.interpolate(fine.exprdirs);
    if (fine.posedirs.defined()) fine.posedirs = step.interpolate(fine.posedirs);
    if (fine.part_labels.defined()) fine.part_labels = step.interpolate_labels(fine.part_labels);
    fine.j_regressor =
        at::cat({fine.j_regressor, at::zeros({kSmplxJointCount, step.edges().size(0)}, fine.j_regressor.options())}, 1);
    fine.faces = step.fine_faces();
  }
  if (data.uvs.defined()) {
    for (const MidpointSubdivision& step : midpoint_subdivisions(data.uv_faces, data.uvs.size(0), levels)) {
      fine.uvs = step.interpolate(fine.uvs);
      fine.uv_faces = step.fine_faces();
    }
  }
  return fine;
}

// ---- the layer ------------------------------------------------------------------------------------------------

SmplxImpl::SmplxImpl(const std::string& path, SmplxOptions options) : SmplxImpl(SmplxModelData::load(path), options) {}

SmplxImpl::SmplxImpl(const SmplxModelData& data, SmplxOptions options) : options_(options) {
  data.validate();
  const std::string what = "Smplx ('" + data.source + "')";
  TORCH_CHECK(options_.num_betas >= 0 && options_.num_expression_coeffs >= 0, what,
              ": num_betas and num_expression_coeffs must be >= 0, got ", options_.num_betas, " and ",
              options_.num_expression_coeffs);
  if (options_.num_betas > data.shapedirs.size(2)) {
    TORCH_WARN(what, " has ", data.shapedirs.size(2), " shape directions; using ", data.shapedirs.size(2),
               " betas instead of ", options_.num_betas);
    options_.num_betas = data.shapedirs.size(2);
  }
  if (options_.num_expression_coeffs > data.exprdirs.size(2)) {
    TORCH_WARN(what, " has ", data.exprdirs.size(2), " expression directions; using ", data.exprdirs.size(2),
               " expression coefficients instead of ", options_.num_expression_coeffs);
    options_.num_expression_coeffs = data.exprdirs.size(2);
  }
  TORCH_CHECK(options_.subdivision_levels >= 0, what, ": subdivision_levels must be >= 0, got ",
              options_.subdivision_levels);

  SkinnedMeshData mesh;
  mesh.v_template = data.v_template;
  mesh.faces = data.faces;
  mesh.j_regressor = data.j_regressor;
  mesh.weights = data.weights;
  mesh.parents = data.parents;
  mesh.blend_shapes = at::cat(
      {data.shapedirs.narrow(2, 0, options_.num_betas), data.exprdirs.narrow(2, 0, options_.num_expression_coeffs)}, 2);
  mesh.posedirs = data.posedirs;
  mesh_ = register_module("mesh", SkinnedMesh(mesh, options_.dtype, options_.subdivision_levels));

  if (options_.use_pca) {
    const int64_t available = std::min(data.hands_components_left.size(0), data.hands_components_right.size(0));
    TORCH_CHECK(options_.num_pca_comps >= 1 && options_.num_pca_comps <= available, what,
                ": num_pca_comps must lie in [1, ", available, "], got ", options_.num_pca_comps);
    hands_left_ =
        register_buffer("hands_components_left",
                        buffer_copy(data.hands_components_left.narrow(0, 0, options_.num_pca_comps), options_.dtype));
    hands_right_ =
        register_buffer("hands_components_right",
                        buffer_copy(data.hands_components_right.narrow(0, 0, options_.num_pca_comps), options_.dtype));
  }
  hands_mean_left_ = register_buffer("hands_mean_left", buffer_copy(data.hands_mean_left, options_.dtype));
  hands_mean_right_ = register_buffer("hands_mean_right", buffer_copy(data.hands_mean_right, options_.dtype));

  const int64_t levels = options_.subdivision_levels;
  part_labels_ = data.part_labels;
  if (part_labels_.defined()) {
    for (const MidpointSubdivision& step : midpoint_subdivisions(data.faces, data.v_template.size(0), levels))
      part_labels_ = step.interpolate_labels(part_labels_);
  }
  uvs_ = data.uvs;
  uv_faces_ = data.uv_faces;
  if (uvs_.defined()) {
    for (const MidpointSubdivision& step : midpoint_subdivisions(data.uv_faces, data.uvs.size(0), levels)) {
      uvs_ = step.interpolate(uvs_);
      uv_faces_ = step.fine_faces();
    }
  }
}

at::Tensor SmplxImpl::full_pose(const SmplxInput& input, int64_t batch) const {
  const auto options = at::TensorOptions().dtype(dtype()).device(device());
  // An axis-angle pose of `joints` joints as (B, 3 joints); (B, joints, 3) is accepted too.
  const auto joint_pose = [&](const at::Tensor& pose, const char* name, int64_t joints) {
    if (!pose.defined()) return at::zeros({batch, 3 * joints}, options);
    const at::Tensor flat = pose.dim() == 3 && pose.size(1) == joints && pose.size(2) == 3 ? pose.flatten(1) : pose;
    check_tensor(flat, std::string("Smplx: ") + name + " (or (B, " + std::to_string(joints) + ", 3))",
                 {batch, 3 * joints}, dtype(), device());
    return flat;
  };
  const auto hand_pose = [&](const at::Tensor& pose, const char* name, const at::Tensor& components,
                             const at::Tensor& mean) {
    at::Tensor full;
    if (options_.use_pca) {
      if (pose.defined()) {
        check_tensor(pose, std::string("Smplx: ") + name + " (PCA coefficients)", {batch, options_.num_pca_comps},
                     dtype(), device());
        full = pose.matmul(components);
      } else {
        full = at::zeros({batch, kHandPoseSize}, options);
      }
    } else {
      full = joint_pose(pose, name, kHandJointCount);
    }
    return options_.flat_hand_mean ? full : full + mean;
  };
  const SmplxPose& p = input.pose;
  return at::cat({joint_pose(p.global_orient, "global_orient", 1),
                  joint_pose(p.body_pose, "body_pose", kSmplxBodyJointCount), joint_pose(p.jaw_pose, "jaw_pose", 1),
                  joint_pose(p.leye_pose, "leye_pose", 1), joint_pose(p.reye_pose, "reye_pose", 1),
                  hand_pose(p.left_hand_pose, "left_hand_pose", hands_left_, hands_mean_left_),
                  hand_pose(p.right_hand_pose, "right_hand_pose", hands_right_, hands_mean_right_)},
                 1)
      .view({batch, kSmplxJointCount, 3});
}

SmplxOutput SmplxImpl::forward(const SmplxInput& input) const {
  std::vector<std::pair<const char*, const at::Tensor*>> batched = {{"betas", &input.betas},
                                                                    {"rotations", &input.rotations}};
  for (const SmplxPose::Field& f : SmplxPose::fields()) batched.emplace_back(f.name, &(input.pose.*(f.member)));
  const int64_t batch = common_batch_size(
      "Smplx", batched, {{"vertex_offsets", &input.vertex_offsets}, {"joint_offsets", &input.joint_offsets}});
  const auto options = at::TensorOptions().dtype(dtype()).device(device());
  SmplxOutput out;
  at::Tensor rotations;
  if (input.rotations.defined()) {
    for (const SmplxPose::Field& f : SmplxPose::fields())
      TORCH_CHECK(f.joints == 0 || f.member == &SmplxPose::transl || !(input.pose.*(f.member)).defined(),
                  "Smplx: give either rotations or axis-angle poses, got rotations and ", f.name);
    check_tensor(input.rotations, "Smplx: rotations", {batch, kSmplxJointCount, 3, 3}, dtype(), device());
    rotations = input.rotations;
  } else {
    out.full_pose = full_pose(input, batch);
    rotations = axis_angle_to_matrix(out.full_pose);
  }
  const auto coefficients = [&](const at::Tensor& t, const char* name, int64_t count) {
    if (!t.defined()) return at::zeros({batch, count}, options);
    check_tensor(t, std::string("Smplx: ") + name, {batch, count}, dtype(), device());
    return t;
  };
  const at::Tensor blend = at::cat({coefficients(input.betas, "betas", options_.num_betas),
                                    coefficients(input.pose.expression, "expression", options_.num_expression_coeffs)},
                                   1);
  const at::Tensor transl = coefficients(input.pose.transl, "transl", 3);
  static_cast<BodyOutput&>(out) = mesh_->forward(blend, rotations, transl, input.vertex_offsets, input.joint_offsets);
  return out;
}

}  // namespace sfgs::body
