#include "train/avatar_keypoints.h"

#include <ATen/ATen.h>

#include "body/procedural_body.h"
#include "body/skeleton.h"
#include "fit/constants.h"
#include "common/tensor_description.h"

namespace sfgs::train {

body::WholeBodyKeypointMap body_keypoint_map(const std::string& smplx_path) {
  return body::wholebody_keypoint_map(body::smplx_model_or_procedural(smplx_path), smplx_path);
}

FrameKeypoints frame_keypoints(const at::Tensor& detections, const Camera& camera) {
  TORCH_CHECK(detections.dim() == 2 && detections.size(0) == body::kWholeBodyKeypointCount && detections.size(1) == 3,
              "frame_keypoints: expected (", body::kWholeBodyKeypointCount, ", 3) detections, got ",
              describe(detections));
  const auto options = detections.options().dtype(at::kFloat);
  FrameKeypoints k;
  const at::Tensor intrinsics =
      at::tensor({camera.fx, camera.fy, camera.cx, camera.cy}, at::kDouble).to(options).unsqueeze(0);
  k.observed = fit::observe_keypoints(detections.to(at::kFloat).unsqueeze(0), intrinsics);
  k.world_to_camera = at::tensor(at::ArrayRef<double>(camera.world_to_camera.data(), 16)).view({4, 4}).to(options);
  k.weights = fit::whole_body_keypoint_weights(options);
  return k;
}

at::Tensor avatar_camera_keypoints(const body::WholeBodyKeypointMap& map, const model::Avatar& avatar,
                                   const model::AvatarOutput& out, const at::Tensor& world_to_camera) {
  const at::Tensor& transforms = out.skinning_transforms;  // (J, 4, 4)
  TORCH_CHECK(transforms.dim() == 3 && transforms.size(0) == body::kSmplxJointCount,
              "avatar_camera_keypoints: the whole-body keypoints need the ", body::kSmplxJointCount,
              " joints of an SMPL-X-layout body, got skinning transforms ", describe(transforms));
  const at::Tensor rotation = world_to_camera.narrow(0, 0, 3).narrow(1, 0, 3);
  const at::Tensor translation = world_to_camera.narrow(0, 0, 3).select(1, 3);
  const auto to_camera = [&](const at::Tensor& points) { return points.matmul(rotation.t()) + translation; };
  const at::Tensor joint_rotations = transforms.narrow(1, 0, 3).narrow(2, 0, 3);  // each joint's global rotation
  const at::Tensor support =
      out.posed_vertices.narrow(0, 0, avatar->model_vertex_count()).index_select(0, map.support_vertices());
  const at::Tensor neck = rotation.matmul(joint_rotations.select(0, body::smplx_joint::kNeck)).unsqueeze(0);
  return map
      .evaluate(to_camera(support).unsqueeze(0), to_camera(out.posed_joints).unsqueeze(0),
                body::contour_bins(neck, map.contour_bin_count()))
      .squeeze(0);
}

at::Tensor keypoint_reprojection_loss(const body::WholeBodyKeypointMap& map, const model::Avatar& avatar,
                                      const model::AvatarOutput& out, const FrameKeypoints& keypoints) {
  TORCH_CHECK(keypoints.defined(), "keypoint_reprojection_loss: the frame has no detections");
  const at::Tensor posed = avatar_camera_keypoints(map, avatar, out, keypoints.world_to_camera).unsqueeze(0);
  return fit::reprojection_loss(posed, keypoints.observed, keypoints.weights, kFitRobustSigma).squeeze(0);
}

}  // namespace sfgs::train
