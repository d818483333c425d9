"""`sfgs prepare` driven as a user would: a folder of frames (and a video file) to a dataset; bad inputs are named.
Through the `sfgs` executable (SFGS_EXECUTABLE, which CTest sets); skipped without it or without the MediaPipe
models (scripts/install_deps.sh fetches them)."""
import json
import os
import subprocess

import pytest

SFGS = os.environ.get("SFGS_EXECUTABLE", "")
MODELS = os.environ.get("SFGS_MEDIAPIPE_DIR",
                        os.path.join(os.path.dirname(__file__), "..", "..", "models", "mediapipe"))
pytestmark = [pytest.mark.cli,
              pytest.mark.skipif(not os.path.isfile(SFGS), reason="SFGS_EXECUTABLE does not name the sfgs executable"),
              pytest.mark.skipif(not os.path.isfile(os.path.join(MODELS, "models.json")),
                                 reason=f"no MediaPipe models in {MODELS} (scripts/install_deps.sh fetches them)")]


def sfgs(*args):
    return subprocess.run([SFGS, *args], capture_output=True, text=True)


def test_a_folder_of_frames_becomes_a_dataset(tmp_path):
    video, out = str(tmp_path / "video"), str(tmp_path / "dataset")
    assert sfgs("synth", "--out", video, "--motions", "walk", "--frames", "4", "--width", "180",
                "--height", "320").returncode == 0
    result = sfgs("prepare", os.path.join(video, "images"), "--out", out, "--no-fit", "--quiet")
    assert result.returncode == 0, result.stderr
    assert "4 of 4 frames show a person (180 x 320, focal 320 px, the default, max(width, height))" in result.stdout
    assert sorted(os.listdir(os.path.join(out, "keypoints_whole_body"))) == ["0.json", "1.json", "2.json", "3.json"]
    with open(os.path.join(out, "keypoints_whole_body", "0.json")) as f:
        assert len(json.load(f)) == 133
    with open(os.path.join(out, "prepare_log.jsonl")) as f:
        events = [json.loads(line)["event"] for line in f]
    assert events.count("frame") == 4 and events[-1] == "detection"
    again = sfgs("prepare", os.path.join(video, "images"), "--out", out, "--no-fit")
    assert again.returncode == 1 and "exists; give another folder or --force" in again.stderr


def test_a_video_file_is_decoded_and_bad_inputs_are_named(tmp_path, run):
    frames = str(tmp_path / "frames")
    rendered = sfgs("render", "--run", run, "--out", frames, "--frames", "3")
    assert rendered.returncode == 0, rendered.stderr
    mp4 = os.path.join(frames, "render.mp4")
    if not os.path.isfile(mp4):
        pytest.skip("this build writes no MP4 (no OpenCV encoder)")
    # The tiny avatar is no detectable person: the error counts the decoded frames.
    result = sfgs("prepare", mp4, "--out", str(tmp_path / "dataset"))
    assert result.returncode == 1 and "no person was found in any of the 3 frames" in result.stderr
    assert not os.path.exists(tmp_path / "dataset")
    missing = sfgs("prepare", str(tmp_path / "missing.mp4"), "--out", str(tmp_path / "dataset"))
    assert missing.returncode == 1 and "cannot read video" in missing.stderr
    bad_model = sfgs("prepare", mp4, "--out", str(tmp_path / "d2"), "--model", "huge")
    assert bad_model.returncode == 1 and "expected lite, full or heavy" in bad_model.stderr
