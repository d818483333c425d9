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
    for k in (0, 1, 2, 5):
        if arguments[k] is not None:
            arguments[k].requires_grad_(True)
    return arguments


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("with_rest", [True, False])
def test_skin_gaussians_passes_opcheck(device, with_rest):
    opcheck()(torch.ops.sfgs.skin_gaussians.default, skin_arguments(device, with_rest))


# The transform rows too: a pose being fitted differentiates them through the fused node.
@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("with_rest", [True, False])
def test_skin_gaussians_gradients_match_finite_differences(device, with_rest):
    means, log_scales, rest, joints, weights, rows = skin_arguments(device, with_rest)
    if with_rest:
        assert torch.autograd.gradcheck(
            lambda m, s, r, t: torch.ops.sfgs.skin_gaussians(m, s, r, joints, weights, t), [means, log_scales, rest, rows])
    else:
        assert torch.autograd.gradcheck(
            lambda m, s, t: torch.ops.sfgs.skin_gaussians(m, s, None, joints, weights, t), [means, log_scales, rows])


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


def gathered_mlp_arguments(device, width=128, rows=37, groups=5, outputs=4):
    gen = torch.Generator().manual_seed(7)
    randn = lambda *shape: torch.randn(*shape, generator=gen).to(device)  # noqa: E731
    return [randn(rows, width), randn(groups, width), torch.randint(0, groups, (rows,), generator=gen).to(device),
            randn(width, width) / width ** 0.5, randn(width), randn(outputs, width) / width ** 0.5, randn(outputs)]


# Inference only: on CUDA a width of 128 takes the fused kernel, other widths the LibTorch composition.
@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("width", [128, 8])
def test_gathered_mlp_passes_opcheck(device, width):
    opcheck()(torch.ops.sfgs.gathered_mlp.default, gathered_mlp_arguments(device, width))


def test_gathered_mlp_refuses_a_gradient():
    arguments = gathered_mlp_arguments("cpu", width=8)
    arguments[0].requires_grad_(True)
    with pytest.raises(RuntimeError, match="inference only"):
        torch.ops.sfgs.gathered_mlp(*arguments)
    with torch.no_grad():
        assert torch.ops.sfgs.gathered_mlp(*arguments).shape == (37, 4)


def mlp_inference_arguments(device, width=128, blocks=(64, 32), layers=3, rows=37, outputs=4):
    gen = torch.Generator().manual_seed(8)
    randn = lambda *shape: torch.randn(*shape, generator=gen).to(device)  # noqa: E731
    inputs = [randn(rows, b) for b in blocks]
    input_weights = [randn(width, b) / sum(blocks) ** 0.5 for b in blocks]
    hidden = [randn(width, width) / width ** 0.5 for _ in range(layers - 1)]
    return [inputs, randn(rows, width), input_weights, randn(width), hidden, [randn(width) for _ in hidden],
            [1 + 0.2 * randn(width) for _ in range(layers)], [0.1 * randn(width) for _ in range(layers)],
            randn(outputs, width) / width ** 0.5, randn(outputs), 4, 1e-5]


# Inference only: on CUDA a width of 128 in 4 groups takes the fused kernel, others the LibTorch composition.
@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("width", [128, 16])
def test_mlp_inference_passes_opcheck(device, width):
    opcheck()(torch.ops.sfgs.mlp_inference.default, mlp_inference_arguments(device, width))


def test_mlp_inference_refuses_a_gradient():
    arguments = mlp_inference_arguments("cpu", width=16)
    arguments[1].requires_grad_(True)
    with pytest.raises(RuntimeError, match="inference only"):
        torch.ops.sfgs.mlp_inference(*arguments)
    with torch.no_grad():
        assert torch.ops.sfgs.mlp_inference(*arguments).shape == (37, 4)


def propagation_arguments(device):
    """A chain of four points, the first trusted: the plan mesh_propagation::plan makes (rings 1, 2, 3 fill points
    1, 2 and 3, each from the one before)."""
    ints = lambda values: torch.tensor(values, dtype=torch.int32, device=device)  # noqa: E731
    values = torch.randn(4, 3, generator=torch.Generator().manual_seed(9), dtype=torch.float64).to(device)
    trust = torch.tensor([1.0, 0.0, 0.0, 0.5], dtype=torch.float64, device=device)
    return [values, trust, ints([[1, 0], [0, 2], [1, 3], [2, 0]]), ints([1, 2, 2, 1]), ints([1, 2, 3]),
            ints([[0, 1], [1, 2], [2, 3]]), ints([1, 1, 1]), ints([1, 2, 3]), [0, 1, 2, 3], 2]


@pytest.mark.parametrize("device", DEVICES)
def test_propagate_on_mesh_passes_opcheck(device):
    arguments = propagation_arguments(device)
    out = torch.ops.sfgs.propagate_on_mesh(*arguments)
    assert torch.equal(out[0], arguments[0][0]), "a trusted point keeps its value"
    opcheck()(torch.ops.sfgs.propagate_on_mesh.default, arguments)


def test_propagate_on_mesh_refuses_a_neighbour_outside_the_mesh():
    arguments = propagation_arguments("cpu")
    arguments[2] = arguments[2].clone()
    arguments[2][1, 1] = 7
    with pytest.raises(RuntimeError, match=r"a neighbour lies outside \[0, 4\)"):
        torch.ops.sfgs.propagate_on_mesh(*arguments)


def plane_reads(grid, height, width):
    """The reads plane_sampling::plane_reads makes (grid_sample's bilinear corners, border, align_corners), one chunk
    a texel: (chunk_rows, chunk_begins, chunk_ends, points, weights)."""
    planes, points, _ = grid.shape
    x = ((grid[..., 0] + 1) / 2 * (width - 1)).clamp(0, width - 1)
    y = ((grid[..., 1] + 1) / 2 * (height - 1)).clamp(0, height - 1)
    x0, y0 = x.floor(), y.floor()
    fx, fy = x - x0, y - y0
    corner_x, corner_y = torch.stack([x0, x0 + 1, x0, x0 + 1]), torch.stack([y0, y0, y0 + 1, y0 + 1])
    weights = torch.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy])
    plane_of = torch.arange(planes, device=grid.device).view(1, planes, 1).expand(4, planes, points)
    point_of = torch.arange(points, device=grid.device).view(1, 1, points).expand(4, planes, points)
    inside = (corner_x < width) & (corner_y < height)
    rows = (plane_of * height * width + corner_y.long() * width + corner_x.long())[inside]
    rows, order = torch.sort(rows, stable=True)
    texels, counts = torch.unique_consecutive(rows, return_counts=True)
    ends = counts.cumsum(0)
    return [texels.int(), (ends - counts).int(), ends.int(), point_of[inside][order].int(), weights[inside][order]]


@pytest.mark.parametrize("device", DEVICES)
def test_plane_sampling_ops_pass_gradcheck_and_opcheck(device):
    gen = torch.Generator().manual_seed(10)
    planes = torch.randn(3, 2, 4, 5, generator=gen, dtype=torch.float64).to(device).requires_grad_(True)
    grid = (torch.rand(3, 9, 2, generator=gen, dtype=torch.float64) * 2.4 - 1.2).to(device)
    reads = plane_reads(grid, 4, 5)
    assert torch.autograd.gradcheck(lambda p: torch.ops.sfgs.sample_fixed_planes(p, grid, *reads), [planes])
    positions = grid[..., 0].contiguous()
    line = plane_reads(grid, 1, 5)  # along the width alone: v plays no part
    time = torch.tensor(0.3, dtype=torch.float64, device=device)
    assert torch.autograd.gradcheck(
        lambda p: torch.ops.sfgs.sample_fixed_planes_at_time(p, positions, time, *line), [planes])
    expected = torch.nn.functional.grid_sample(planes, torch.stack([positions, time.expand_as(positions)], -1)
                                               .unsqueeze(1), align_corners=True, padding_mode="border")
    sampled = torch.ops.sfgs.sample_fixed_planes_at_time(planes, positions, time, *line)
    assert torch.allclose(sampled, expected.squeeze(2).permute(2, 0, 1).reshape(9, -1))
    opcheck()(torch.ops.sfgs.sample_fixed_planes.default, [planes, grid, *reads])
    opcheck()(torch.ops.sfgs.sample_fixed_planes_at_time.default, [planes, positions, time, *line])
