"""The fused ops as dispatcher operators (csrc/ops/registration.h): after `import sfgs`, torch.ops.sfgs.<op> has CPU,
CUDA, Meta and Autograd kernels, which torch.library.opcheck checks where torch has it (torch >= 2.4)."""
import pytest
import torch

import sfgs


DEVICES = [pytest.param("cpu"), pytest.param("cuda", marks=pytest.mark.skipif(
    not (torch.cuda.is_available() and sfgs.cuda_available()), reason="needs a GPU and sfgs built with CUDA"))]


def opcheck():
    if not hasattr(torch.library, "opcheck"):
        pytest.skip(f"torch.library.opcheck needs torch >= 2.4; this is torch {torch.__version__}")
    return torch.library.opcheck


def skin_arguments(device, with_rest=True, n=20, joints=5, influences=3):
    gen = torch.Generator().manual_seed(0)
    rand = lambda *shape: torch.rand(*shape, generator=gen, dtype=torch.float64)  # noqa: E731
    weights = rand(n, influences) + 0.1
    weights = weights / weights.sum(1, keepdim=True)
    rows = torch.eye(4, dtype=torch.float64)[:3].reshape(1, 12) + 0.1 * (rand(joints, 12) - 0.5)
    arguments = [rand(n, 3) - 0.5, -2 + 0.2 * rand(n), rand(n, 3) - 0.5 if with_rest else None,
                 torch.randint(0, joints, (n, influences), generator=gen, dtype=torch.int32), weights, rows]
    arguments = [a.to(device) if a is not None else None for a in arguments]
    for k in (0, 1, 2):
        if arguments[k] is not None:
            arguments[k].requires_grad_(True)
    return arguments


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("with_rest", [True, False])
def test_skin_gaussians_passes_opcheck(device, with_rest):
    opcheck()(torch.ops.sfgs.skin_gaussians.default, skin_arguments(device, with_rest))


@pytest.mark.parametrize("device", DEVICES)
def test_skin_gaussians_gradients_match_finite_differences(device):
    arguments = skin_arguments(device)
    differentiable = [a for a in arguments[:3]]
    fixed = arguments[3:]
    assert torch.autograd.gradcheck(lambda m, s, r: torch.ops.sfgs.skin_gaussians(m, s, r, *fixed), differentiable)


def group_norm_arguments(device, with_bias=True, rows=12, channels=8):
    gen = torch.Generator().manual_seed(1)
    randn = lambda *shape: torch.randn(*shape, generator=gen, dtype=torch.float64)  # noqa: E731
    arguments = [randn(rows, channels), randn(channels) if with_bias else None, 1 + 0.3 * randn(channels),
                 0.3 * randn(channels)]
    return [a.to(device).requires_grad_(True) if a is not None else None for a in arguments]


# The CUDA kernel takes groups of 32 or more channels; the CPU any.
@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("with_bias", [True, False])
def test_group_norm_relu_ops_pass_opcheck(device, with_bias):
    channels = 64
    pre, bias, gamma, beta = group_norm_arguments(device, with_bias, channels=channels)
    opcheck()(torch.ops.sfgs.group_norm_relu.default, (pre, bias, gamma, beta, 2, 1e-5))
    x = torch.randn(12, 5, dtype=torch.float64, device=device, requires_grad=True)
    weight = torch.randn(channels, 5, dtype=torch.float64, device=device, requires_grad=True)
    opcheck()(torch.ops.sfgs.linear_group_norm_relu.default, (x, weight, bias, gamma, beta, 2, 1e-5))


@pytest.mark.parametrize("device", DEVICES)
def test_pixel_losses_passes_opcheck(device):
    gen = torch.Generator().manual_seed(2)
    prediction = torch.rand(9, 11, 3, generator=gen, dtype=torch.float64).to(device).requires_grad_(True)
    target = torch.rand(9, 11, 3, generator=gen, dtype=torch.float64).to(device)
    opcheck()(torch.ops.sfgs.pixel_losses.default, (prediction, target))


@pytest.mark.parametrize("device", DEVICES)
def test_fused_ssim_passes_opcheck(device):
    gen = torch.Generator().manual_seed(3)
    target = torch.rand(13, 15, 3, generator=gen, dtype=torch.float64)
    prediction = (target + 0.2 * torch.rand(13, 15, 3, generator=gen, dtype=torch.float64)).clamp(0, 1)
    opcheck()(torch.ops.sfgs.fused_ssim.default, (prediction.to(device).requires_grad_(True), target.to(device)))


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("with_bias", [True, False])
def test_linear_passes_opcheck(device, with_bias):
    gen = torch.Generator().manual_seed(4)
    arguments = [torch.randn(9, 5, generator=gen, dtype=torch.float64), torch.randn(4, 5, generator=gen,
                 dtype=torch.float64), torch.randn(4, generator=gen, dtype=torch.float64) if with_bias else None]
    opcheck()(torch.ops.sfgs.linear.default,
              [a.to(device).requires_grad_(True) if a is not None else None for a in arguments])
    rows = torch.randn(300, 7, generator=gen, dtype=torch.float64).to(device)
    opcheck()(torch.ops.sfgs.column_sum.default, (rows,))
    assert torch.allclose(torch.ops.sfgs.column_sum(rows), rows.sum(0))


@pytest.mark.parametrize("device", DEVICES)
def test_feature_fusion_ops_pass_opcheck(device):
    gen = torch.Generator().manual_seed(5)
    randn = lambda *shape: torch.randn(*shape, generator=gen, dtype=torch.float64).to(device)  # noqa: E731
    opcheck()(torch.ops.sfgs.gated_mix.default, [randn(6, 8).requires_grad_(True) for _ in range(3)])
    points = torch.randperm(9, generator=gen)
    order = sfgs_merge_order(points[:4], points[4:])
    first, second = randn(4, 3).requires_grad_(True), randn(5, 3).requires_grad_(True)
    opcheck()(torch.ops.sfgs.merge_rows.default, (first, second, order[0].to(device), order[1].to(device)))


def sfgs_merge_order(first_points, second_points):
    """feature_fusion::MergeOrder in Python: source[i] is point i's row in cat(first, second); inverse the rows'
    points."""
    inverse = torch.cat([first_points, second_points])
    source = torch.empty_like(inverse)
    source[inverse] = torch.arange(len(inverse))
    return source, inverse


@pytest.mark.parametrize("device", DEVICES)
def test_gathered_first_layer_passes_opcheck(device):
    gen = torch.Generator().manual_seed(6)
    rows = torch.randn(11, 6, generator=gen, dtype=torch.float64).to(device).requires_grad_(True)
    group_rows = torch.randn(4, 6, generator=gen, dtype=torch.float64).to(device).requires_grad_(True)
    groups = torch.randint(0, 4, (11,), generator=gen).to(device)
    opcheck()(torch.ops.sfgs.gathered_first_layer.default, (rows, group_rows, groups))
