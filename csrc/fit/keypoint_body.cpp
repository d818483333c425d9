#include "fit/keypoint_body.h"

#include <ATen/ATen.h>

#include "body/skeleton.h"

namespace sfgs::fit {

KeypointBody::KeypointBody(const body::SmplxModelData& model, const at::Tensor& vertex_ids, int64_t betas,
                           int64_t expressions, const at::TensorOptions& options) {
  TORCH_CHECK(betas <= model.shapedirs.size(2) && expressions <= model.exprdirs.size(2), "KeypointBody: '",
              model.source, "' has ", model.shapedirs.size(2), " shape and ", model.exprdirs.size(2),
              " expression directions, ", betas, " and ", expressions, " asked for");
  const auto host = at::TensorOptions().dtype(at::kDouble);
  const at::Tensor ids = vertex_ids.to(at::kCPU, at::kLong);
  const at::Tensor shape = model.shapedirs.to(host).narrow(2, 0, betas);
  const at::Tensor expression = model.exprdirs.to(host).narrow(2, 0, expressions);
  const at::Tensor regressor = model.j_regressor.to(host);
  const int64_t v = model.v_template.size(0), j = regressor.size(0);
  const auto place = [&](const at::Tensor& t) { return t.to(options).contiguous(); };
  template_points_ = place(model.v_template.to(host).index_select(0, ids));
  shape_points_ = place(shape.index_select(0, ids));
  expression_points_ = place(expression.index_select(0, ids));
  if (model.posedirs.defined()) posedirs_points_ = place(model.posedirs.to(host).index_select(0, ids));
  weights_ = place(model.weights.to(host).index_select(0, ids));
  joint_template_ = place(regressor.matmul(model.v_template.to(host)));
  joint_shape_ = place(regressor.matmul(shape.reshape({v, 3 * betas})).view({j, 3, betas}));
  joint_expression_ = place(regressor.matmul(expression.reshape({v, 3 * expressions})).view({j, 3, expressions}));
  tree_ = body::KinematicTree(model.parents);
  tree_->to(options.device());
}

at::Tensor KeypointBody::rest_joints(const at::Tensor& betas, const at::Tensor& expression) const {
  return joint_template_ + joint_shape_.matmul(betas) + at::einsum("jce,be->bjc", {joint_expression_, expression});
}

at::Tensor KeypointBody::rest_pelvis(const at::Tensor& betas, const at::Tensor& expression) const {
  return rest_joints(betas, expression).select(1, body::smplx_joint::kPelvis);
}

PosedPoints KeypointBody::forward(const at::Tensor& betas, const at::Tensor& expression, const at::Tensor& rotations,
                                  const at::Tensor& translation) const {
  const int64_t batch = rotations.size(0);
  at::Tensor rest = (template_points_ + shape_points_.matmul(betas)).unsqueeze(0) +
                    at::einsum("sce,be->bsc", {expression_points_, expression});
  if (posedirs_points_.defined())
    rest = rest + at::einsum("scp,bp->bsc", {posedirs_points_, body::pose_feature(rotations)});
  const body::PosedSkeleton skeleton = tree_->pose(rotations, rest_joints(betas, expression), translation);
  PosedPoints out;
  out.points =
      body::linear_blend_skinning(rest.expand({batch, -1, -1}).contiguous(), weights_, skeleton.skinning_transforms);
  out.joints = skeleton.joints;
  out.joint_rotations = skeleton.joint_transforms.narrow(2, 0, 3).narrow(3, 0, 3);
  return out;
}

}  // namespace sfgs::fit
