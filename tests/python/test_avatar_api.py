"""The avatar API of `import sfgs`: load a run trained by the sfgs executable, pose it, render it.

The tiny run of conftest.py, trained by the `sfgs` executable named by SFGS_EXECUTABLE (CTest sets it); skipped
without it."""
import json
import os
import struct
import zlib

import pytest
import torch

import sfgs

SFGS = os.environ.get("SFGS_EXECUTABLE", "")
pytestmark = pytest.mark.skipif(not os.path.isfile(SFGS), reason="SFGS_EXECUTABLE does not name the sfgs executable")


def test_loads_the_run_and_its_dataset(run):
    avatar = sfgs.load_avatar(run)
    assert avatar.iteration == 4
    assert avatar.frame_count == 10
    assert "hidden_width: 16" in avatar.config_yaml
    assert [avatar.frame(i)["split"] for i in (0, 4, 9)] == ["train", "val", "test"]


def test_eval_scores_only_the_regions_its_frames_showed(run):
    # At 40 x 32 pixels some regions (the hands) are too small in every frame: they get no score, not a PSNR of 0.
    with open(os.path.join(run, "metrics_test.json")) as f:
        metrics = json.load(f)
    regions = metrics["regions"]
    assert regions, "the synthetic dataset has ground-truth geometry"
    for m in metrics["motions"]:
        assert 0 <= m["unseen_share"] <= 1, m
    assert any(r["frames"] == 0 for r in regions), "a region no frame shows"
    for r in regions:
        if r["frames"] == 0:
            assert r["psnr"] is None and r["ssim"] is None, r
        else:
            assert r["psnr"] > 0 and 0 < r["ssim"] <= 1, r


def test_expressions_are_the_avatars_size(run):
    avatar = sfgs.load_avatar(run)
    count = avatar.expression_count
    frame = avatar.frame(2)
    assert frame["pose"]["expression"].shape == (count,), "frame() gives the avatar's coefficients"
    for wrong in (count + 40, max(count - 1, 0) if count > 1 else count + 1):
        with pytest.raises(RuntimeError, match=f"this avatar takes {count} expression coefficients"):
            avatar.gaussians({"expression": torch.zeros(wrong)})
    avatar.gaussians({"expression": torch.zeros(1, count)})


def test_gaussians_have_their_shapes_and_follow_the_pose(run):
    avatar = sfgs.load_avatar(run)
    rest = avatar.gaussians()
    n = avatar.gaussian_count
    assert rest["means"].shape == (n, 3) and rest["covariances"].shape == (n, 6)
    assert rest["colours"].shape == (n, 3) and rest["opacities"].shape == (n,)
    assert all(torch.isfinite(v).all() for v in rest.values())
    moved = avatar.gaussians({"transl": torch.tensor([0.0, 0.5, 0.0])})
    assert torch.allclose(moved["means"], rest["means"] + torch.tensor([0.0, 0.5, 0.0]), atol=1e-5)
    # Gradients reach the pose through the networks, skinning and the splatting op.
    body_pose = torch.zeros(21, 3, requires_grad=True)
    frame = avatar.frame(2)
    image = avatar.render(frame["camera"], {"body_pose": body_pose, "transl": frame["pose"]["transl"],
                                            "global_orient": frame["pose"]["global_orient"]})["image"]
    image.sum().backward()
    assert body_pose.grad is not None and body_pose.grad.abs().sum() > 0


def test_centre_frames_the_posed_body_for_the_camera_helpers(run):
    avatar = sfgs.load_avatar(run)
    pose = {"transl": torch.tensor([0.3, 0.0, 0.0])}
    means = avatar.gaussians(pose)["means"].detach().double()
    box_centre = (means.min(0).values + means.max(0).values) / 2
    assert avatar.centre(pose) == pytest.approx(box_centre.tolist(), abs=1e-6)
    camera = sfgs.camera_in_front(avatar.centre(pose), 40, 32)
    with torch.no_grad():
        alpha = avatar.render(camera, pose)["alpha"]
    assert alpha[16, 20] > 0.5, "the body is in the middle of the image"


def test_render_matches_the_evaluation_renders(run):
    """A test frame rendered through Python equals `sfgs eval --save-images`'s PNG up to 8-bit rounding."""
    avatar = sfgs.load_avatar(run)
    avatar.set_cached(True)
    folder = os.path.join(run, "eval_images_test")
    images = sorted(f for f in os.listdir(folder) if f.endswith(".png"))
    assert len(images) == 1, "sfgs eval --save-images should write the one test frame"
    frame = avatar.frame(9)
    with torch.no_grad():
        image = avatar.render(frame["camera"], frame["pose"])["image"]
    assert image.shape == (32, 40, 3)
    png = read_png_rgb(os.path.join(folder, images[0]))
    assert (image - png).abs().max() <= 0.5 / 255 + 1e-6
    assert (png < 0.9).any(), "the body should be in view"


def test_python_evaluation_equals_sfgs_eval_per_frame(run):
    """sfgs.evaluate on Avatar.render's frame gives `sfgs eval`'s per-frame numbers (metrics_test.json)."""
    with open(os.path.join(run, "metrics_test.json")) as f:
        per_frame = json.load(f)["per_frame"]
    avatar = sfgs.load_avatar(run)
    avatar.set_cached(True)
    dataset = sfgs.read_dataset(os.path.join(os.path.dirname(run), "data"))
    (index,) = dataset.split("test")
    truth = dataset.frame(index)
    (expected,) = [m for m in per_frame if m["name"] == truth["name"]]
    with torch.no_grad():
        image = avatar.render(truth["camera"], truth["pose"])["image"]
    scored = sfgs.evaluate(image, truth["image"], truth["eval_mask"], lpips=expected.get("lpips") is not None)
    assert abs(scored["psnr"] - expected["psnr"]) <= 1e-6
    assert abs(scored["ssim"] - expected["ssim"]) <= 1e-9
    if expected.get("lpips") is not None:
        assert abs(scored["lpips"] - expected["lpips"]) <= 1e-7
    else:
        assert scored["lpips"] is None
    # The protocol differs from a plain PSNR of the two images: white outside the person.
    assert scored["psnr"] != pytest.approx(sfgs.psnr(image.clamp(0, 1), truth["image"]).item(), abs=1e-3)
    with pytest.raises(RuntimeError, match=r"permute"):
        sfgs.evaluate(image.permute(2, 0, 1), truth["image"].permute(2, 0, 1), lpips=False)


def read_png_rgb(path):
    """8-bit RGB, non-interlaced PNG (what sfgs writes) -> (H, W, 3) float in [0, 1], with the standard library."""
    data = open(path, "rb").read()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    pos, idat, width, height = 8, b"", 0, 0
    while pos < len(data):
        length = struct.unpack(">I", data[pos:pos + 4])[0]
        kind, body = data[pos + 4:pos + 8], data[pos + 8:pos + 8 + length]
        if kind == b"IHDR":
            width, height, depth, colour = struct.unpack(">IIBB", body[:10])
            assert (depth, colour) == (8, 2), "expected 8-bit RGB"
        elif kind == b"IDAT":
            idat += body
        pos += 12 + length
    raw, stride, rows, previous = zlib.decompress(idat), 3 * width, [], bytearray(3 * width)
    for y in range(height):
        kind, line = raw[y * (stride + 1)], bytearray(raw[y * (stride + 1) + 1:(y + 1) * (stride + 1)])
        for x in range(stride):
            a = line[x - 3] if x >= 3 else 0
            b, c = previous[x], previous[x - 3] if x >= 3 else 0
            if kind == 1:
                line[x] = (line[x] + a) & 255
            elif kind == 2:
                line[x] = (line[x] + b) & 255
            elif kind == 3:
                line[x] = (line[x] + (a + b) // 2) & 255
            elif kind == 4:
                p = a + b - c
                pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                line[x] = (line[x] + (a if pa <= pb and pa <= pc else b if pb <= pc else c)) & 255
        rows.append(bytes(line))
        previous = line
    return torch.frombuffer(bytearray(b"".join(rows)), dtype=torch.uint8).view(height, width, 3).float() / 255


def test_motion_files_pose_the_avatar(run, tmp_path):
    import numpy as np
    frames, fps = 30, 60.0
    poses = np.zeros((frames, 165))
    poses[:, 0] = np.pi / 2  # upright in AMASS's Z-up frame
    poses[:, 50] = np.linspace(0, -1, frames)  # the left shoulder lowering the arm
    path = str(tmp_path / "clip.npz")
    np.savez(path, poses=poses, trans=np.zeros((frames, 3)), mocap_frame_rate=np.array(fps))
    motion = sfgs.read_motion(path)
    assert motion["format"] == "amass-smplx" and motion["fps"] == 60.0 and motion["absolute_hands"]
    assert len(motion["frames"]) == 30 and motion["frames"][0]["body_pose"].shape == (21, 3)
    assert torch.allclose(motion["frames"][0]["global_orient"], torch.zeros(3, dtype=torch.float64), atol=1e-9)
    assert len(sfgs.read_motion(path, fps=20)["frames"]) == 10  # 29/60 s at 20 fps: 0, 0.05, ..., 0.45 s
    avatar = sfgs.load_avatar(run)
    posed = avatar.motion(path, fps=20)
    assert len(posed["frames"]) == 10
    first, last = (avatar.gaussians(posed["frames"][k])["means"] for k in (0, -1))
    assert first.shape == (avatar.gaussian_count, 3)
    assert (first - last).abs().max() > 0.05, "the arm moved"
    with pytest.raises(RuntimeError, match="lacks its frame rate"):
        np.savez(str(tmp_path / "bad.npz"), poses=poses)
        sfgs.read_motion(str(tmp_path / "bad.npz"))


def test_bad_inputs_are_clear_errors(run, tmp_path):
    with pytest.raises(RuntimeError, match="checkpoint"):
        sfgs.load_avatar(str(tmp_path))
    with pytest.raises(RuntimeError, match="device must be"):
        sfgs.load_avatar(run, device="tpu")
    avatar = sfgs.load_avatar(run)
    with pytest.raises(RuntimeError, match="unknown key 'body'"):
        avatar.gaussians({"body": torch.zeros(3)})
    with pytest.raises(RuntimeError, match="world_to_camera"):
        avatar.render({"fx": 1.0})
    with pytest.raises(RuntimeError, match="index"):
        avatar.frame(10)
