#pragma once
// SFGS's fine-grained hand residual. For a hand pose theta, the MANO hand and the SMPL-X hand are compared in the
// canonical frame, vertex by vertex through the MANO_SMPLX_vertex_ids correspondence and relative to their wrist
// joints: r = (T_MANO(beta_h, theta) - wrist_MANO) - (T_SMPLX,hand(beta, theta) - wrist_SMPLX), where T is the
// shaped, pose-corrected rest mesh before skinning (MANO's pose correctives against SMPL-X's finger correctives).
// An MLP on [r, theta] refines it: r' = r + MLP([r, theta]) (the MLP starts at zero), and r' is ADDED to the
// canonical hand points, which SMPL-X's skinning then carries with the body.
//
// beta_h are MANO's own shape coefficients fitted once (linear least squares) to the subject's SMPL-X hand: the
// two models' shape spaces differ, so reusing SMPL-X's betas (as the authors do) compares unrelated hands.
//
// With the shapes fixed, both rest meshes are linear in the same pose feature f = (R_k - I) of the 15 finger
// joints (each model's pose correctives), and the wrists do not move: r = c + f D, with c and D made once from the
// models. forward uses that map (one small product per hand, where MANO's full forward pass is about a hundred
// kernels); reference() composes MANO's forward pass as the definition above reads, and is what it is tested
// against.
#include <array>
#include <cstdint>

#include <torch/nn/module.h>
#include <torch/nn/pimpl.h>

#include "body/mano.h"
#include "body/parts.h"
#include "body/skeleton.h"
#include "body/smplx.h"
#include "model/mlp.h"

namespace sfgs::model {

class HandResidualImpl : public torch::nn::Module {
 public:
  // smplx: the model; shaped_vertices (V, 3) and rest_joints (J, 3): it shaped by the subject's betas (float64);
  // left is expected with its shapedirs repaired (body::repair_left_mano_shapedirs).
  HandResidualImpl(const body::SmplxModelData& smplx, const at::Tensor& shaped_vertices, const at::Tensor& rest_joints,
                   const body::ManoModelData& left, const body::ManoModelData& right,
                   const body::HandVertexIds& hand_vertex_ids);

  // Axis-angle hand poses (15, 3) as SMPL-X applies them (hand mean included); an undefined pose skips its hand.
  // joint_rotations: the caller's SMPL-X local joint rotations (J, 3, 3) of the same pose, whose finger joints are
  // then used instead of being computed again; or undefined.
  // -> the residual of the coarse SMPL-X vertices (V, 3), zero off the hands; undefined when both are skipped.
  at::Tensor forward(const at::Tensor& left_pose, const at::Tensor& right_pose,
                     const at::Tensor& joint_rotations = {}) const;
  // The same through MANO's forward pass and SMPL-X's correctives (tests).
  at::Tensor reference(const at::Tensor& left_pose, const at::Tensor& right_pose) const;

  // The refining MLP of each hand.
  static MlpShape shape();

 private:
  struct Hand {
    body::Side side;
    body::Mano mano{nullptr};
    Mlp refine{nullptr};
    at::Tensor vertex_ids;      // (K) coarse SMPL-X vertex of each MANO vertex
    at::Tensor mano_betas;      // (1, B_h) fitted
    at::Tensor smplx_hand;      // (K, 3) the shaped SMPL-X hand relative to its wrist, no pose
    at::Tensor smplx_posedirs;  // (135, 3 K) SMPL-X's correctives of this hand's finger joints, or undefined
    // The linear map r = c + f D, in float64 on the CPU (not buffers: made from the models, not saved), and its
    // copy in the dtype and on the device forward last ran in.
    at::Tensor constant, pose_directions;  // (K, 3) c and (135, 3 K) D (undefined: neither model has correctives)
    mutable at::Tensor used_constant, used_pose_directions;
  };
  Hand make_hand(const char* name, body::Side side, const body::SmplxModelData& smplx,
                 const at::Tensor& shaped_vertices, const at::Tensor& rest_joints, const body::ManoModelData& mano,
                 const at::Tensor& vertex_ids);
  // r before the refining MLP, from the linear map, or through MANO's forward pass.
  at::Tensor linear_residual(const Hand& hand, const at::Tensor& pose, const at::Tensor& joint_rotations) const;
  at::Tensor composed_residual(const Hand& hand, const at::Tensor& pose) const;
  at::Tensor refined(const Hand& hand, const at::Tensor& pose, const at::Tensor& residual) const;
  template <typename Residual>
  at::Tensor both_hands(const at::Tensor& left_pose, const at::Tensor& right_pose, Residual&& residual) const;

  int64_t coarse_vertex_count_ = 0;
  std::array<Hand, 2> hands_;  // left, right
};
TORCH_MODULE(HandResidual);

}  // namespace sfgs::model
