"""The splatting op as a dispatcher operator: after `import sfgs`, torch.ops.sfgs.render_gaussians is the op that
sfgs.render calls, with CPU, CUDA, Meta and Autograd kernels (csrc/ops/splat/op.cpp)."""
import pytest
import torch

import sfgs


DEVICES = [pytest.param("cpu"), pytest.param("cuda", marks=pytest.mark.skipif(
    not (torch.cuda.is_available() and sfgs.cuda_available()), reason="needs a GPU and sfgs built with CUDA"))]


def scene(n=7, width=21, height=15, covariances=False, seed=0, device="cpu"):
    gen = torch.Generator().manual_seed(seed)
    rand = lambda *shape: torch.rand(*shape, generator=gen, dtype=torch.float64)  # noqa: E731
    fx = fy = 28.0
    cx, cy = 0.48 * width, 0.52 * height
    z = 2.5 + 1.5 * rand(n)
    u, v = width * (0.2 + 0.6 * rand(n)), height * (0.2 + 0.6 * rand(n))
    s = dict(means=torch.stack([(u - cx) * z / fx, (v - cy) * z / fy, z], 1), opacities=0.2 + 0.5 * rand(n),
             features=rand(n, 3), background=rand(3), world_to_camera=torch.eye(4, dtype=torch.float64),
             fx=fx, fy=fy, cx=cx, cy=cy, width=width, height=height)
    scales = (1.5 + 3 * rand(n, 3)) * z[:, None] / fx
    if covariances:
        s["covariances"] = torch.cat([scales ** 2, torch.zeros(n, 3, dtype=torch.float64)], 1)[:, [0, 3, 4, 1, 5, 2]]
    else:
        s["scales"], s["rotations"] = scales, torch.randn(n, 4, generator=gen, dtype=torch.float64)
    return {k: v.to(device) if isinstance(v, torch.Tensor) and k != "world_to_camera" else v for k, v in s.items()}


def op_arguments(s, antialiased=False, deterministic=False):
    """The op's arguments in its schema's order (sfgs.render's defaults: near 0.01, far 1e10, the low-pass on)."""
    return (s["means"], s.get("scales"), s.get("rotations"), s.get("covariances"), s["opacities"], s["features"],
            s["background"], s["world_to_camera"].flatten().tolist(), s["fx"], s["fy"], s["cx"], s["cy"],
            s["width"], s["height"], 0.01, 1e10, sfgs.LOW_PASS_VARIANCE_PX2, antialiased, deterministic)


def differentiable(s):
    return [k for k in ("means", "scales", "rotations", "covariances", "opacities", "features", "background") if k in s]


# Deterministic mode, so that CUDA's gradients are bit-identical from one call to the next (the CPU always is).
@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("covariances", [False, True])
def test_torch_ops_call_is_sfgs_render(covariances, device):
    s = scene(covariances=covariances, device=device)
    names = differentiable(s)
    for k in names:
        s[k].requires_grad_(True)
    image, alpha, depth, radii = torch.ops.sfgs.render_gaussians(*op_arguments(s, antialiased=True, deterministic=True))
    out = sfgs.render(**s, antialiased=True, deterministic=True)
    for got, expected in ((image, out["image"]), (alpha, out["alpha"]), (depth, out["depth"]), (radii, out["radii"])):
        assert torch.equal(got, expected)
    assert float(alpha.max()) > 0.1
    weights = torch.randn(*image.shape, generator=torch.Generator().manual_seed(3), dtype=torch.float64).to(device)
    got = torch.autograd.grad((image * weights).sum() + depth.sum(), [s[k] for k in names])
    expected = torch.autograd.grad((out["image"] * weights).sum() + out["depth"].sum(), [s[k] for k in names])
    for name, g, e in zip(names, got, expected):
        assert torch.equal(g, e), name


def test_errors_name_the_argument():
    s = scene()
    s["opacities"] = s["opacities"].clone()
    s["opacities"][4] = 1.5
    with pytest.raises(RuntimeError, match=r"opacities must be finite and in \[0, 1\]; 1 of 7 are not \(first: index 4"):
        torch.ops.sfgs.render_gaussians(*op_arguments(s))


# opcheck runs the op under schema, autograd-registration and fake-tensor checks (torch >= 2.4).
# test_aot_dispatch_dynamic is left out: AOT dispatch traces the forward with fake tensors, where no backend kernel
# runs, so the autograd node gets none of the state its backward needs (the intersection lists, whose sizes depend
# on the data; docs/splatting.md), and tracing the backward fails by design with the op's own error.
@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("covariances", [False, True])
def test_opcheck(covariances, device):
    if not hasattr(torch.library, "opcheck"):
        pytest.skip(f"torch.library.opcheck needs torch >= 2.4; this is torch {torch.__version__}")
    s = scene(covariances=covariances, device=device)
    for k in differentiable(s):
        s[k].requires_grad_(True)
    torch.library.opcheck(torch.ops.sfgs.render_gaussians.default, op_arguments(s),
                          test_utils=("test_schema", "test_autograd_registration", "test_faketensor"))
