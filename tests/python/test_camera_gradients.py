"""Camera gradients: a camera whose world_to_camera or intrinsics are tensors that require a gradient renders the
image its values give, and the image's gradient reaches them (finite differences in float64)."""
import pytest
import torch

import sfgs
from test_sfgs_module import render_loss, small_scene


def rotation(axis_angle):
    """Rodrigues' formula, differentiable (the angle is never zero here)."""
    angle = axis_angle.norm()
    k = axis_angle / angle
    cross = torch.stack([torch.stack([0 * k[0], -k[2], k[1]]), torch.stack([k[2], 0 * k[0], -k[0]]),
                         torch.stack([-k[1], k[0], 0 * k[0]])])
    return torch.eye(3, dtype=axis_angle.dtype) + torch.sin(angle) * cross + (1 - torch.cos(angle)) * cross @ cross


def placement(axis_angle, translation):
    top = torch.cat([rotation(axis_angle), translation[:, None]], 1)
    return torch.cat([top, torch.tensor([[0.0, 0.0, 0.0, 1.0]], dtype=top.dtype)], 0)


AXIS_ANGLE = torch.tensor([0.05, -0.1, 0.02], dtype=torch.float64)
TRANSLATION = torch.tensor([0.1, -0.05, 0.2], dtype=torch.float64)


def world_scene(covariances=False):
    """small_scene's Gaussians moved into a world that the camera placement(AXIS_ANGLE, TRANSLATION) sees as
    small_scene's camera at the origin did (up to that camera's small shift)."""
    scene = small_scene(covariances=covariances)
    w2c = placement(AXIS_ANGLE, TRANSLATION)
    r, t = w2c[:3, :3], w2c[:3, 3]
    scene["means"] = (scene["means"] - t) @ r
    scene["world_to_camera"] = w2c
    return scene


@pytest.mark.parametrize("covariances", [False, True])
def test_a_camera_that_requires_grad_renders_as_its_values_do(covariances):
    scene = world_scene(covariances)
    plain = sfgs.render(**scene)
    tracked = dict(scene, world_to_camera=scene["world_to_camera"].clone().requires_grad_(True),
                   fx=torch.tensor(scene["fx"], dtype=torch.float64, requires_grad=True))
    out = sfgs.render(**tracked)
    assert out["image"].requires_grad
    for key in ("image", "alpha", "depth"):
        assert torch.allclose(out[key], plain[key], rtol=0, atol=1e-10), key
    assert torch.equal(out["radii"], plain["radii"])
    with torch.no_grad():
        assert not sfgs.render(**tracked)["image"].requires_grad


def test_camera_gradients_match_finite_differences():
    scene = world_scene()
    h, w = scene["height"], scene["width"]
    gen = torch.Generator().manual_seed(2)
    weights = [torch.randn(h, w, 3, generator=gen, dtype=torch.float64),
               torch.randn(h, w, generator=gen, dtype=torch.float64),
               torch.randn(h, w, generator=gen, dtype=torch.float64)]

    def f(axis_angle, translation, fx, fy, cx, cy):
        return render_loss(weights, **dict(scene, world_to_camera=placement(axis_angle, translation), fx=fx, fy=fy,
                                           cx=cx, cy=cy))

    inputs = (AXIS_ANGLE.clone(), TRANSLATION.clone()) + tuple(
        torch.tensor(scene[k], dtype=torch.float64) for k in ("fx", "fy", "cx", "cy"))
    inputs = tuple(t.requires_grad_(True) for t in inputs)
    assert torch.autograd.gradcheck(f, inputs, eps=1e-6, atol=1e-6, rtol=1e-5)


def test_an_intrinsic_that_moves_the_image_gets_the_gradient_that_moves_it_back():
    """Fitting cx from a shifted start: gradient descent on the image error brings it back."""
    scene = world_scene()
    target = sfgs.render(**scene)["image"]
    cx = torch.tensor(scene["cx"] + 0.6, dtype=torch.float64, requires_grad=True)
    optimiser = torch.optim.Adam([cx], lr=0.05)
    for _ in range(60):
        optimiser.zero_grad()
        loss = (sfgs.render(**dict(scene, cx=cx))["image"] - target).square().sum()
        loss.backward()
        optimiser.step()
    assert abs(cx.item() - scene["cx"]) < 0.05


def test_bad_camera_tensors_are_clear_errors():
    scene = world_scene()
    with pytest.raises(RuntimeError, match=r"render\(fx\): expected a number or a floating tensor of one value"):
        sfgs.render(**dict(scene, fx=torch.ones(2, dtype=torch.float64, requires_grad=True)))
    with pytest.raises(RuntimeError, match="world_to_camera must be a floating"):
        sfgs.render(**dict(scene, world_to_camera=torch.eye(3, dtype=torch.float64, requires_grad=True)))


def test_a_batch_of_cameras_renders_each_as_alone():
    scene = world_scene()
    second = placement(AXIS_ANGLE * 0.5, TRANSLATION * 2)
    batch = sfgs.render(**dict(scene, world_to_camera=torch.stack([scene["world_to_camera"], second])))
    assert batch["image"].shape == (2, 17, 23, 3) and batch["radii"].shape == (2, 6, 2)
    for b, w2c in enumerate([scene["world_to_camera"], second]):
        single = sfgs.render(**dict(scene, world_to_camera=w2c))
        for key in ("image", "alpha", "depth", "radii", "visible"):
            assert torch.equal(batch[key][b], single[key]), key
    placements = torch.stack([scene["world_to_camera"], second]).requires_grad_(True)
    sfgs.render(**dict(scene, world_to_camera=placements))["image"][1].sum().backward()
    assert placements.grad[0].abs().sum() == 0 and placements.grad[1].abs().sum() > 0
    with pytest.raises(RuntimeError, match="needs B >= 1"):
        sfgs.render(**dict(scene, world_to_camera=torch.zeros(0, 4, 4, dtype=torch.float64)))
