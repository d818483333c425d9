"""`sfgs render --motion FILE|DIR`: AMASS-format motions and ExAvatar motion folders drive a trained avatar, with the
orbit, fixed and follow cameras, resampled to the output frame rate; bad motion files and options get clear errors.
Through the `sfgs` executable (SFGS_EXECUTABLE, which CTest sets); skipped without it."""
import json
import os
import subprocess

import numpy as np
import pytest

from conftest import TINY_CONFIG
from test_avatar_api import read_png_rgb

SFGS = os.environ.get("SFGS_EXECUTABLE", "")
pytestmark = [pytest.mark.cli,
              pytest.mark.skipif(not os.path.isfile(SFGS), reason="SFGS_EXECUTABLE does not name the sfgs executable")]


def sfgs_run(*args):
    return subprocess.run([SFGS, *args], capture_output=True, text=True)


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    root = tmp_path_factory.mktemp("motion_render")
    data, run = str(root / "data"), str(root / "run")
    subprocess.run([SFGS, "synth", "--out", data, "--frames", "10", "--width", "40", "--height", "32"], check=True,
                   capture_output=True)
    (root / "tiny.yaml").write_text(TINY_CONFIG)
    result = sfgs_run("train", "--data", data, "--out", run, "--config", str(root / "tiny.yaml"), "--quiet")
    assert result.returncode == 0, result.stderr
    return run


def amass_walk(path, frames=60, fps=60.0, smplh=False):
    """A Z-up AMASS-style clip: standing upright (AMASS's root turns the body's Y-up into Z-up), walking 1 m/s
    along +X, the legs swinging."""
    t = np.arange(frames) / fps
    poses = np.zeros((frames, 156 if smplh else 165))
    poses[:, 0] = np.pi / 2  # root: the body's up (+Y) to AMASS's up (+Z)
    poses[:, 3] = 0.4 * np.sin(2 * np.pi * t)  # left hip
    poses[:, 6] = -0.4 * np.sin(2 * np.pi * t)  # right hip
    trans = np.stack([t, np.zeros(frames), np.full(frames, 0.9)], 1)
    rate_key = "mocap_framerate" if smplh else "mocap_frame_rate"
    np.savez(path, poses=poses, trans=trans, betas=np.zeros(16), **{rate_key: np.array(fps)})
    return str(path)


def rendered_frames(folder):
    return sorted(f for f in os.listdir(folder) if f.endswith(".png"))


@pytest.mark.parametrize("camera", ["follow", "orbit", "fixed"])
def test_an_amass_motion_drives_the_avatar(tmp_path, trained, camera):
    motion = amass_walk(tmp_path / "walk.npz")
    out = str(tmp_path / camera)
    result = sfgs_run("render", "--run", trained, "--out", out, "--motion", motion, "--fps", "10", "--camera", camera,
                      "--size", "48x64", "--distance", "3")
    assert result.returncode == 0, result.stderr
    frames = rendered_frames(out)
    assert len(frames) == 10, frames  # one second of 60 fps motion at 10 fps: frames at 0, 0.1, ..., 0.9 s
    first, last = (read_png_rgb(os.path.join(out, frames[k])) for k in (0, -1))
    assert first.shape == (64, 48, 3)
    assert (first < 0.9).any(), "the body should be in view"
    if camera == "follow":
        assert (last < 0.9).any(), "the follow camera keeps the walking body in view"


def test_an_exavatar_motion_folder_drives_the_avatar(tmp_path, trained):
    """Three frames of a body 3 m in front of a static camera (ExAvatar's camera coordinates), raising an arm."""
    params = tmp_path / "exavatar" / "smplx_optimized" / "smplx_params_smoothed"
    params.mkdir(parents=True)
    for k in range(3):
        body = np.zeros((21, 3))
        body[15, 2] = -0.5 * k  # left shoulder
        frame = {"root_pose": [np.pi, 0, 0], "body_pose": body.tolist(), "jaw_pose": [0, 0, 0],
                 "leye_pose": [0, 0, 0], "reye_pose": [0, 0, 0], "lhand_pose": [[0, 0, 0]] * 15,
                 "rhand_pose": [[0, 0, 0]] * 15, "expr": [0.0] * 10, "trans": [0, 0.2, 3.0]}
        (params / f"{k}.json").write_text(json.dumps(frame))
    out = str(tmp_path / "exavatar_out")
    result = sfgs_run("render", "--run", trained, "--out", out, "--motion", str(tmp_path / "exavatar"),
                      "--size", "48x64")
    assert result.returncode == 0, result.stderr
    frames = rendered_frames(out)
    assert len(frames) == 2, frames  # ExAvatar frames at 30 fps end at 2/30 s: at 24 fps, 0 and 1/24 s
    assert (read_png_rgb(os.path.join(out, frames[0])) < 0.9).any(), "the body should be in view"


def test_a_smplh_motion_renders_with_a_note(tmp_path, trained):
    motion = amass_walk(tmp_path / "walk_smplh.npz", frames=12, fps=120.0, smplh=True)
    out = str(tmp_path / "smplh")
    result = sfgs_run("render", "--run", trained, "--out", out, "--motion", motion, "--size", "48x64")
    assert result.returncode == 0, result.stderr
    assert "SMPL-H motion: body and hands taken, jaw and eyes left at rest" in result.stdout
    assert len(rendered_frames(out)) == 3  # 0.092 s at 24 fps: frames at 0, 1/24 and 2/24 s


def test_bad_motion_files_and_options_are_named(tmp_path, trained):
    bad = tmp_path / "bad.npz"
    np.savez(bad, poses=np.zeros((4, 165)))
    result = sfgs_run("render", "--run", trained, "--out", str(tmp_path / "o1"), "--motion", str(bad))
    assert result.returncode == 1
    assert "lacks its frame rate: expected 'mocap_frame_rate'" in result.stderr
    motion = amass_walk(tmp_path / "walk.npz")
    result = sfgs_run("render", "--run", trained, "--out", str(tmp_path / "o2"), "--motion", motion, "--camera", "top")
    assert result.returncode == 1 and "--camera must be orbit, fixed or follow, got 'top'" in result.stderr
    result = sfgs_run("render", "--run", trained, "--out", str(tmp_path / "o3"), "--motion", motion, "--size", "48")
    assert result.returncode == 1 and "--size must be WIDTHxHEIGHT" in result.stderr
