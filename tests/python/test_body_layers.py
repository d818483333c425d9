"""The SMPL-X and MANO layers of `import sfgs` on the CC0 stand-in files of ../shared/bodies (official layouts;
skipped without them): shapes, translation, gradients through the pose, and clear errors."""
import os

import pytest
import torch

import sfgs

SHARED = os.environ.get("SFGS_SHARED_DIR", os.path.join(os.path.dirname(__file__), "..", "..", "..", "shared"))
BODIES = os.path.join(SHARED, "bodies")
SMPLX = os.path.join(BODIES, "anny_smplx_layout.npz")
MANO = os.path.join(BODIES, "anny_mano_left.npz")
pytestmark = pytest.mark.skipif(not os.path.isfile(SMPLX), reason=f"no stand-in body files at {BODIES}")


def test_smplx_poses_a_batch_differentiably():
    layer = sfgs.Smplx(SMPLX, dtype="float64")
    body_pose = (0.2 * torch.randn(2, 21, 3, dtype=torch.float64)).requires_grad_(True)
    out = layer({"body_pose": body_pose, "betas": torch.zeros(2, 10, dtype=torch.float64)})
    assert out["vertices"].shape == (2, layer.vertex_count, 3) and out["joints"].shape == (2, 55, 3)
    assert out["faces"].dtype == torch.int64
    out["vertices"].square().sum().backward()
    assert body_pose.grad is not None and body_pose.grad.abs().sum() > 0
    moved = layer({"body_pose": body_pose.detach(), "transl": torch.tensor([[0.0, 1.0, 0.0]] * 2, dtype=torch.float64)})
    still = layer({"body_pose": body_pose.detach()})
    assert torch.allclose(moved["vertices"] - still["vertices"],
                          torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64).expand_as(still["vertices"]))


def test_mano_poses_a_hand():
    layer = sfgs.Mano(MANO)
    out = layer({"hand_pose": 0.3 * torch.randn(1, 45), "global_orient": torch.zeros(1, 3)})
    assert out["vertices"].shape[0] == 1 and out["vertices"].shape[2] == 3 and out["joints"].shape == (1, 16, 3)


def test_bad_inputs_are_named():
    layer = sfgs.Smplx(SMPLX)
    with pytest.raises(ValueError, match="unknown key 'bodypose'; expected one of betas, global_orient"):
        layer({"bodypose": torch.zeros(1, 21, 3)})
    with pytest.raises(TypeError, match=r"Smplx.forward\['body_pose'\]: expected a torch.Tensor, got list"):
        layer({"body_pose": [0.0] * 63})
    with pytest.raises(RuntimeError, match="body_pose"):
        layer({"body_pose": torch.zeros(1, 20, 3)})
    with pytest.raises(ValueError, match="expected 'float32' or 'float64'"):
        sfgs.Smplx(SMPLX, dtype="half")
    with pytest.raises(RuntimeError):
        sfgs.Smplx(os.path.join(BODIES, "no_such_model.npz"))
