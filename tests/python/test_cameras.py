"""The camera helpers shared with `sfgs render` (csrc/animate/camera_placement.h): where each camera stands and
what it looks at, checked through the projection of known points."""
import math

import pytest
import torch

import sfgs


def camera_point(camera, point):
    """`point` (world) in the camera's frame."""
    return camera["world_to_camera"] @ torch.tensor([*point, 1.0], dtype=torch.float64)


def pixel(camera, point):
    x, y, z, _ = camera_point(camera, point).tolist()
    return camera["fx"] * x / z + camera["cx"], camera["fy"] * y / z + camera["cy"]


def test_look_at_puts_the_target_on_the_optical_axis_and_keeps_up_up():
    camera = sfgs.look_at_camera([1.0, 1.5, 3.0], torch.tensor([0.0, 1.0, 0.0]), 400, 600)
    assert (camera["width"], camera["height"], camera["cx"], camera["cy"]) == (400, 600, 200.0, 300.0)
    assert camera["fx"] == pytest.approx(1.2 * 600)
    eye_in_camera = camera_point(camera, [1.0, 1.5, 3.0])
    assert torch.allclose(eye_in_camera[:3], torch.zeros(3, dtype=torch.float64), atol=1e-12)
    target = camera_point(camera, [0.0, 1.0, 0.0])
    assert target[:2].abs().max() < 1e-12 and target[2] == pytest.approx(math.sqrt(1 + 0.25 + 9))
    u, v = pixel(camera, [0.0, 1.0, 0.0])
    _, v_above = pixel(camera, [0.0, 1.2, 0.0])
    assert (u, v) == pytest.approx((200.0, 300.0)) and v_above < v, "world +Y is up in the image"
    rotation = camera["world_to_camera"][:3, :3]
    assert torch.allclose(rotation @ rotation.T, torch.eye(3, dtype=torch.float64), atol=1e-12)
    assert torch.det(rotation) == pytest.approx(1.0)
    assert sfgs.look_at_camera([0, 0, 2], [0, 0, 0], 64, 48, fx=100.0)["fx"] == 100.0


def test_camera_in_front_stands_before_the_body_and_turns_about_the_vertical():
    target = [0.2, 1.0, -0.5]
    front = sfgs.camera_in_front(target, 320, 480, distance=2.0, height_above=0.5)
    expected = sfgs.look_at_camera([0.2, 1.5, 1.5], target, 320, 480)
    assert torch.allclose(front["world_to_camera"], expected["world_to_camera"], atol=1e-12)
    side = sfgs.camera_in_front(target, 320, 480, distance=2.0, height_above=0.5, angle=math.pi / 2)
    assert torch.allclose(camera_point(side, [2.2, 1.5, -0.5])[:3], torch.zeros(3, dtype=torch.float64), atol=1e-12)


def test_an_orbit_keeps_distance_and_height_and_comes_round():
    centre = [0.0, 1.0, 0.0]
    start = sfgs.look_at_camera([0.0, 1.6, 2.5], centre, 200, 300)
    quarter = sfgs.orbit_camera(start, centre, math.pi / 2)
    eye = -quarter["world_to_camera"][:3, :3].T @ quarter["world_to_camera"][:3, 3]
    assert eye.tolist() == pytest.approx([2.5, 1.6, 0.0], abs=1e-12)
    assert pixel(quarter, centre) == pytest.approx((100.0, 150.0))
    full = sfgs.orbit_camera(start, centre, 2 * math.pi)
    assert torch.allclose(full["world_to_camera"], start["world_to_camera"], atol=1e-12)


def test_bad_placements_are_clear_errors():
    with pytest.raises(RuntimeError, match="distance must be positive"):
        sfgs.look_at_camera([0, 1, 0], [0, 1, 0], 64, 48)
    with pytest.raises(RuntimeError, match="straight up or down"):
        sfgs.look_at_camera([0, 3, 0], [0, 1, 0], 64, 48)
    with pytest.raises(TypeError, match=r"a point \(x, y, z\)"):
        sfgs.look_at_camera([0, 1], [0, 1, 0], 64, 48)
    with pytest.raises(RuntimeError, match="must be finite"):
        sfgs.camera_in_front([0, float("nan"), 0], 64, 48)
    with pytest.raises(RuntimeError, match="width and height must be positive"):
        sfgs.camera_in_front([0, 1, 0], 0, 48)
