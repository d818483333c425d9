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
  // -> the residual of the coarse SMPL-X vertices (V, 3), zero off the hands; undefined when both are skipped.
  at::Tensor forward(const at::Tensor& left_pose, const at::Tensor& right_pose) const;

  // The refining MLP of each hand.
  static MlpShape shape();

 private:
  struct Hand {
    body::Mano mano{nullptr};
    Mlp refine{nullptr};
    at::Tensor vertex_ids;      // (K) coarse SMPL-X vertex of each MANO vertex
    at::Tensor mano_betas;      // (1, B_h) fitted
    at::Tensor smplx_hand;      // (K, 3) the shaped SMPL-X hand relative to its wrist, no pose
    at::Tensor smplx_posedirs;  // (135, 3 K) SMPL-X's correctives of this hand's finger joints, or undefined
  };
  Hand make_hand(const char* name, body::Side side, const body::SmplxModelData& smplx,
                 const at::Tensor& shaped_vertices, const at::Tensor& rest_joints, const body::ManoModelData& mano,
                 const at::Tensor& vertex_ids);
  at::Tensor residual(const Hand& hand, const at::Tensor& pose) const;

  int64_t coarse_vertex_count_ = 0;
  std::array<Hand, 2> hands_;  // left, right
};
TORCH_MODULE(HandResidual);

}  // namespace sfgs::model
