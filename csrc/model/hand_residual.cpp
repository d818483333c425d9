#include "model/hand_residual.h"

#include <cmath>
#include <string>
#include <tuple>

#include <ATen/Functions.h>
#include <ATen/TensorOperators.h>

#include "body/rotations.h"
#include "body/skeleton.h"
#include "body/tensor_checks.h"
#include "model/constants.h"

namespace sfgs::model {
namespace {

constexpr int64_t kHandPoseFeatureSize = 9 * body::kHandJointCount;  // R - I of the 15 finger joints

}  // namespace

MlpShape HandResidualImpl::shape() {
  return MlpShape{{3, body::kHandPoseSize},
                  {kHandResidualHiddenWidth, kHandResidualHiddenWidth},
                  3,
                  /*group_norm=*/false,
                  /*zero_output=*/true};
}

HandResidualImpl::HandResidualImpl(const body::SmplxModelData& smplx, const at::Tensor& shaped_vertices,
                                   const at::Tensor& rest_joints, const body::ManoModelData& left,
                                   const body::ManoModelData& right, const body::HandVertexIds& hand_vertex_ids)
    : coarse_vertex_count_(smplx.v_template.size(0)) {
  hands_[0] = make_hand("left", body::Side::kLeft, smplx, shaped_vertices, rest_joints, left, hand_vertex_ids.left);
  hands_[1] = make_hand("right", body::Side::kRight, smplx, shaped_vertices, rest_joints, right, hand_vertex_ids.right);
}

HandResidualImpl::Hand HandResidualImpl::make_hand(const char* name, body::Side side, const body::SmplxModelData& smplx,
                                                   const at::Tensor& shaped_vertices, const at::Tensor& rest_joints,
                                                   const body::ManoModelData& mano, const at::Tensor& vertex_ids) {
  mano.validate();
  const std::string prefix(name);
  const int64_t k = mano.v_template.size(0);
  TORCH_CHECK(vertex_ids.defined() && vertex_ids.dim() == 1 && vertex_ids.size(0) == k, "HandResidual: the ", prefix,
              " hand's vertex ids must give one SMPL-X vertex for each of the ", k, " vertices of '", mano.source,
              "', got ", describe(vertex_ids));
  const at::Tensor ids = vertex_ids.to(at::kCPU, at::kLong);
  TORCH_CHECK(ids.min().item<int64_t>() >= 0 && ids.max().item<int64_t>() < coarse_vertex_count_, "HandResidual: the ",
              prefix, " hand's vertex ids must lie in [0, ", coarse_vertex_count_, ")");

  // The subject's SMPL-X hand relative to its wrist, and MANO's shape fitted to it in the same frame.
  const int64_t wrist = body::smplx_hand_joint(side, 0);
  const at::Tensor target = shaped_vertices.index_select(0, ids) - rest_joints[wrist];  // (K, 3)
  const at::Tensor wrist_regressor = mano.j_regressor[0];                               // (K)
  const at::Tensor template_relative = mano.v_template - wrist_regressor.matmul(mano.v_template);
  const int64_t shape_count = mano.shapedirs.size(2);
  const at::Tensor shapedirs_relative =
      mano.shapedirs - at::einsum("k,kcb->cb", {wrist_regressor, mano.shapedirs}).unsqueeze(0);  // (K, 3, B_h)
  at::Tensor betas = at::zeros({shape_count, 1}, at::kDouble);
  // The SVD driver: a hand's shape space is often rank-deficient relative to the wrist (the procedural hand's has
  // rank 6 of 10), and LibTorch 1.13's default 'gelsy' then returns a wrong, run-dependent solution.
  if (shape_count > 0)
    betas = std::get<0>(at::linalg_lstsq(shapedirs_relative.reshape({k * 3, shape_count}),
                                         (target - template_relative).reshape({k * 3, 1}), c10::nullopt,
                                         c10::string_view("gelsd")));
  const at::Tensor fitted = template_relative + shapedirs_relative.matmul(betas.flatten());  // MANO at rest
  const at::Tensor misfit = fitted - target;
  const double rms = misfit.pow(2).sum(1).mean().sqrt().item<double>();
  if (rms > kHandFitWarningRms)
    TORCH_WARN("HandResidual: the ", prefix, " MANO hand ('", mano.source, "') fits the subject's SMPL-X ", prefix,
               " hand only to ", rms, " m RMS: are the MANO files swapped, or meant for another body model?");

  Hand hand;
  hand.side = side;
  body::ManoOptions options;
  options.num_betas = shape_count;
  options.use_pca = false;
  options.flat_hand_mean = true;  // the poses come with the mean already added, as SMPL-X applied them
  hand.mano = register_module(prefix + "_mano", body::Mano(mano, options));
  hand.refine = register_module(prefix + "_refine", Mlp(shape()));
  hand.vertex_ids =
      register_buffer(prefix + "_vertex_ids", ids.clone());  // never the caller's tensor: to() moves buffers
  hand.mano_betas = register_buffer(prefix + "_mano_betas", betas.reshape({1, shape_count}).to(at::kFloat));
  hand.smplx_hand = register_buffer(prefix + "_smplx_hand", target.to(at::kFloat));
  if (smplx.posedirs.defined()) {
    // Pose-feature columns 9 (j - 1) .. of joint j; this hand's finger joints are consecutive.
    const int64_t first_column = 9 * (body::smplx_hand_joint(side, 1) - 1);
    const at::Tensor columns = smplx.posedirs.index_select(0, ids).narrow(2, first_column, kHandPoseFeatureSize);
    hand.smplx_posedirs = register_buffer(
        prefix + "_smplx_posedirs", columns.reshape({k * 3, kHandPoseFeatureSize}).t().contiguous().to(at::kFloat));
  }
  // The linear map: MANO's rest mesh at zero pose against the SMPL-X hand, and the two models' correctives (both in
  // (K, 3, 135) layout, rows of the finger joints 1..15) turned into (135, 3 K).
  hand.constant = (fitted - target).to(at::kDouble).contiguous();
  at::Tensor directions;
  if (mano.posedirs.defined()) directions = mano.posedirs.to(at::kDouble).reshape({k * 3, kHandPoseFeatureSize});
  if (smplx.posedirs.defined()) {
    const int64_t first_column = 9 * (body::smplx_hand_joint(side, 1) - 1);
    const at::Tensor smplx_directions = smplx.posedirs.index_select(0, ids)
                                            .narrow(2, first_column, kHandPoseFeatureSize)
                                            .to(at::kDouble)
                                            .reshape({k * 3, kHandPoseFeatureSize});
    directions = directions.defined() ? directions - smplx_directions : -smplx_directions;
  }
  if (directions.defined()) hand.pose_directions = directions.t().contiguous();
  return hand;
}

at::Tensor HandResidualImpl::linear_residual(const Hand& hand, const at::Tensor& pose,
                                             const at::Tensor& joint_rotations) const {
  const auto options = pose.options();
  if (!hand.used_constant.defined() || hand.used_constant.device() != pose.device() ||
      hand.used_constant.scalar_type() != pose.scalar_type()) {
    hand.used_constant = hand.constant.to(options);
    if (hand.pose_directions.defined()) hand.used_pose_directions = hand.pose_directions.to(options);
  }
  if (!hand.used_pose_directions.defined()) return hand.used_constant;
  const at::Tensor rotations =
      joint_rotations.defined() ? joint_rotations.narrow(0, body::smplx_hand_joint(hand.side, 1), body::kHandJointCount)
                                : body::axis_angle_to_matrix(pose);
  const at::Tensor feature = (rotations - at::eye(3, options)).reshape({1, kHandPoseFeatureSize});
  return at::addmm(hand.used_constant.view({1, -1}), feature, hand.used_pose_directions).view_as(hand.used_constant);
}

at::Tensor HandResidualImpl::composed_residual(const Hand& hand, const at::Tensor& pose) const {
  body::ManoInput input;
  input.betas = hand.mano_betas;
  input.hand_pose = pose.reshape({1, body::kHandPoseSize});
  const body::ManoOutput mano = hand.mano->forward(input);
  const at::Tensor mano_relative = mano.rest_vertices[0] - mano.rest_joints[0][0];
  at::Tensor smplx_relative = hand.smplx_hand;
  if (hand.smplx_posedirs.defined()) {
    const at::Tensor rotations = body::axis_angle_to_matrix(pose);
    const at::Tensor feature = (rotations - at::eye(3, rotations.options())).reshape({1, kHandPoseFeatureSize});
    smplx_relative = smplx_relative + feature.matmul(hand.smplx_posedirs).view_as(smplx_relative);
  }
  return mano_relative - smplx_relative;
}

at::Tensor HandResidualImpl::refined(const Hand& hand, const at::Tensor& pose, const at::Tensor& r) const {
  const at::Tensor flat_pose = pose.reshape({1, body::kHandPoseSize});
  return r + hand.refine->finish(hand.refine->project(0, r) + hand.refine->project(1, flat_pose));
}

template <typename Residual>
at::Tensor HandResidualImpl::both_hands(const at::Tensor& left_pose, const at::Tensor& right_pose,
                                        Residual&& residual) const {
  at::Tensor out;
  for (const auto& [hand, pose] : {std::pair{&hands_[0], &left_pose}, {&hands_[1], &right_pose}}) {
    if (!pose->defined()) continue;
    const at::Tensor& ids = hand->vertex_ids;
    check_tensor(*pose, "HandResidual: hand pose", {body::kHandJointCount, 3}, hand->mano_betas.scalar_type(),
                 ids.device());
    const at::Tensor r = refined(*hand, *pose, residual(*hand, *pose));
    if (!out.defined()) out = at::zeros({coarse_vertex_count_, 3}, r.options());
    out = out.index_copy(0, ids, r);
  }
  return out;
}

at::Tensor HandResidualImpl::forward(const at::Tensor& left_pose, const at::Tensor& right_pose,
                                     const at::Tensor& joint_rotations) const {
  if (joint_rotations.defined())
    check_tensor(joint_rotations, "HandResidual: joint rotations", {body::kSmplxJointCount, 3, 3},
                 hands_[0].mano_betas.scalar_type(), hands_[0].vertex_ids.device());
  return both_hands(left_pose, right_pose, [&](const Hand& hand, const at::Tensor& pose) {
    return linear_residual(hand, pose, joint_rotations);
  });
}

at::Tensor HandResidualImpl::reference(const at::Tensor& left_pose, const at::Tensor& right_pose) const {
  return both_hands(left_pose, right_pose,
                    [this](const Hand& hand, const at::Tensor& pose) { return composed_residual(hand, pose); });
}

}  // namespace sfgs::model
