"""The Python module: `import sfgs` from Debian's python3 with python3-torch, autograd through the C++ node."""
import math

import pytest
import torch

import sfgs


def small_scene(n=6, width=23, height=17, channels=3, seed=0, covariances=False):
    gen = torch.Generator().manual_seed(seed)
    fx = fy = 30.0
    cx, cy = 0.47 * width, 0.53 * height
    z = 2.5 + 1.5 * torch.rand(n, generator=gen, dtype=torch.float64)
    u = width * (0.2 + 0.6 * torch.rand(n, generator=gen, dtype=torch.float64))
    v = height * (0.2 + 0.6 * torch.rand(n, generator=gen, dtype=torch.float64))
    means = torch.stack([(u - cx) * z / fx, (v - cy) * z / fy, z], 1)
    scales = (1.5 + 3 * torch.rand(n, 3, generator=gen, dtype=torch.float64)) * z[:, None] / fx
    rotations = torch.randn(n, 4, generator=gen, dtype=torch.float64)
    scene = dict(
        means=means,
        opacities=0.2 + 0.4 * torch.rand(n, generator=gen, dtype=torch.float64),
        features=torch.rand(n, channels, generator=gen, dtype=torch.float64),
        background=torch.rand(channels, generator=gen, dtype=torch.float64),
        world_to_camera=torch.eye(4, dtype=torch.float64),
        fx=fx, fy=fy, cx=cx, cy=cy, width=width, height=height,
    )
    if covariances:
        r = torch.nn.functional.normalize(rotations, dim=1)
        w, x, y, zq = r.unbind(1)
        rot = torch.stack([1 - 2 * (y * y + zq * zq), 2 * (x * y - w * zq), 2 * (x * zq + w * y),
                           2 * (x * y + w * zq), 1 - 2 * (x * x + zq * zq), 2 * (y * zq - w * x),
                           2 * (x * zq - w * y), 2 * (y * zq + w * x), 1 - 2 * (x * x + y * y)], 1).view(-1, 3, 3)
        m = rot * scales[:, None, :]
        c = m @ m.transpose(1, 2)
        scene["covariances"] = torch.stack([c[:, 0, 0], c[:, 0, 1], c[:, 0, 2], c[:, 1, 1], c[:, 1, 2], c[:, 2, 2]], 1)
    else:
        scene["scales"], scene["rotations"] = scales, rotations
    return scene


def render_loss(weights, **scene):
    out = sfgs.render(**scene)
    return (out["image"] * weights[0]).sum() + (out["alpha"] * weights[1]).sum() + (out["depth"] * weights[2]).sum()


@pytest.mark.parametrize("covariances", [False, True])
@pytest.mark.parametrize("antialiased", [False, True])
def test_gradcheck_float64(covariances, antialiased):
    scene = small_scene(covariances=covariances)
    names = ["means", "opacities", "features", "background"] + (["covariances"] if covariances else ["scales", "rotations"])
    h, w = scene["height"], scene["width"]
    gen = torch.Generator().manual_seed(1)
    weights = [torch.randn(h, w, 3, generator=gen, dtype=torch.float64), torch.randn(h, w, generator=gen, dtype=torch.float64),
               torch.randn(h, w, generator=gen, dtype=torch.float64)]

    def f(*tensors):
        return render_loss(weights, **{**scene, **dict(zip(names, tensors))}, antialiased=antialiased)

    inputs = tuple(scene[n].clone().requires_grad_(True) for n in names)
    assert torch.autograd.gradcheck(f, inputs, eps=1e-6, atol=1e-7, rtol=1e-5)


def test_outputs_and_module_constants():
    scene = small_scene()
    out = sfgs.render(**scene)
    assert out["image"].shape == (17, 23, 3)
    assert out["alpha"].shape == out["depth"].shape == (17, 23)
    assert out["radii"].dtype == torch.int32 and out["radii"].shape == (6, 2)
    assert out["visible"].dtype == torch.bool and bool(out["visible"].all())
    assert sfgs.MIN_ALPHA == pytest.approx(1 / 255) and sfgs.MAX_ALPHA == 0.99 and sfgs.TILE_SIZE == 16
    assert math.isclose(sfgs.LOW_PASS_VARIANCE_PX2, 0.3)
    assert isinstance(sfgs.cuda_available(), bool)


def test_errors_are_python_exceptions_with_clear_messages():
    scene = small_scene()
    scene["means"] = scene["means"][:, :2]
    with pytest.raises(RuntimeError, match=r"means must have shape \(N, 3\)"):
        sfgs.render(**scene)


def test_demo_scene_renders():
    s = sfgs.demo_scene(count=2000, width=64, height=48)
    out = sfgs.render(s["means"], s["opacities"], s["features"], s["background"], s["world_to_camera"].float(),
                      s["fx"], s["fy"], s["cx"], s["cy"], 64, 48, scales=s["scales"], rotations=s["rotations"])
    assert 0.05 < float(out["alpha"].mean()) < 0.9
