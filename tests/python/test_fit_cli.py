"""`sfgs synth --layout neuman --pose-noise` and `sfgs fit` through the executable, as a user meets them: a NeuMan
video with keypoints and noisy fits, a fit written beside it that `sfgs train` reads, its report and log, and clear
errors for bad options and bad keypoint files.

Uses the executable named by SFGS_EXECUTABLE (CTest sets it); skipped without it."""
import json
import os
import shutil
import subprocess

import pytest

SFGS = os.environ.get("SFGS_EXECUTABLE", "")
pytestmark = [pytest.mark.cli,
              pytest.mark.skipif(not os.path.isfile(SFGS), reason="SFGS_EXECUTABLE does not name the sfgs executable")]

TINY = """
run: {seed: 3, log_every: 1, validate_every: 100, checkpoint_every: 100}
avatar: {subdivision_levels: 0, plane_channels: 4, plane_resolution: 16, time_resolution: 4,
         face_plane_resolution: 16, hidden_width: 16}
loss: {use_lpips: false}
schedule: {iterations: 1, warmup_iterations: 1}
"""


def sfgs_run(*args):
    return subprocess.run([SFGS, *args], capture_output=True, text=True)


@pytest.fixture(scope="module")
def video(tmp_path_factory):
    folder = str(tmp_path_factory.mktemp("fit") / "video")
    result = sfgs_run("synth", "--out", folder, "--layout", "neuman", "--frames", "4", "--width", "64", "--height",
                      "80", "--pose-noise", "medium,swap=0.5")
    assert result.returncode == 0, result.stderr
    assert "fits corrupted at level medium,swap=0.5" in result.stdout
    return folder


def test_synth_writes_keypoints_noisy_fits_and_the_truth(video):
    keypoints = json.load(open(os.path.join(video, "keypoints_whole_body", "3.json")))
    assert len(keypoints) == 133 and all(len(k) == 3 for k in keypoints)
    noisy = json.load(open(os.path.join(video, "smplx_optimized", "smplx_params", "0.json")))
    exact = json.load(open(os.path.join(video, "ground_truth", "smplx_params", "0.json")))
    assert set(noisy) == {"root_pose", "body_pose", "jaw_pose", "leye_pose", "reye_pose", "lhand_pose", "rhand_pose",
                          "expr", "trans"}
    assert noisy["body_pose"] != exact["body_pose"]


def test_fit_writes_fits_the_trainer_reads(video, tmp_path):
    out = str(tmp_path / "fit")
    result = sfgs_run("fit", "--data", video, "--out", out, "--iterations", "5,10,5,2", "--log-every", "5")
    assert result.returncode == 0, result.stderr
    assert "sfgs fit: fitted 4 frames" in result.stdout and "MPJPE" in result.stdout
    report = json.load(open(os.path.join(out, "fit_report.json")))
    assert report["frames"] == 4 and report["silhouette"] and report["accuracy"]["frames"] == 4
    assert [s["name"] for s in report["stages"]] == ["global", "body", "detail", "silhouette"]
    lines = [json.loads(line) for line in open(os.path.join(out, "fit_log.jsonl"))]
    assert any(line.get("stage") == "body" and "terms" in line for line in lines)
    again = sfgs_run("fit", "--data", video, "--out", out)
    assert again.returncode != 0 and "pass --force" in again.stderr
    # In place of the video's own fits, `sfgs train` trains on them.
    trained = tmp_path / "video"
    shutil.copytree(video, trained)
    shutil.rmtree(trained / "smplx_optimized")
    shutil.copytree(os.path.join(out, "smplx_optimized"), trained / "smplx_optimized")
    config = tmp_path / "tiny.yaml"
    config.write_text(TINY)
    result = sfgs_run("train", "--data", str(trained), "--out", str(tmp_path / "run"), "--config", str(config),
                      "--quiet")
    assert result.returncode == 0, result.stderr


def test_bad_options_and_keypoint_files_are_clear_errors(video, tmp_path):
    result = sfgs_run("synth", "--out", str(tmp_path / "x"), "--pose-noise", "extreme")
    assert result.returncode != 0 and "none, low, medium" in result.stderr
    result = sfgs_run("fit", "--data", video, "--out", str(tmp_path / "y"), "--iterations", "1,2")
    assert result.returncode != 0 and "one count or three or four" in result.stderr
    broken = tmp_path / "broken"
    shutil.copytree(video, broken)
    (broken / "keypoints_whole_body" / "2.json").write_text("[[1, 2, 0.5]]")
    result = sfgs_run("fit", "--data", str(broken), "--out", str(tmp_path / "z"))
    assert result.returncode != 0
    assert "2.json" in result.stderr and "expected 133 keypoints" in result.stderr


def test_refinement_and_test_time_fitting_anchor_on_the_keypoints(video, tmp_path):
    config = tmp_path / "refine.yaml"
    config.write_text(TINY.replace("iterations: 1,", "iterations: 2,") +
                      "pose_refinement: {enabled: true, start: 0, align_at: [0.5], align_iterations: 3,"
                      " keypoint_weight: 2}\n")
    run = str(tmp_path / "run")
    result = sfgs_run("train", "--data", video, "--out", run, "--config", str(config), "--quiet")
    assert result.returncode == 0, result.stderr
    log = [json.loads(line) for line in open(os.path.join(run, "log.jsonl"))]
    # The alignment pass fits the training fits (to the image and the keypoints); the steps add no pose term.
    passes = [e for e in log if e.get("event") == "pose_alignment"]
    assert len(passes) == 1 and passes[0]["loss_after"] <= passes[0]["loss_before"], passes
    steps = [e for e in log if e.get("event") == "step"]
    assert steps and not any("pose_keypoints" in s["loss"] for s in steps), steps[:1]

    # The four-frame video has no test frames: its training frames are fitted instead.
    fit = ["--split", "train", "--fit-test-poses", "--fit-iterations", "3"]
    result = sfgs_run("eval", "--run", run, *fit)
    assert result.returncode == 0, result.stderr
    fitted = json.load(open(os.path.join(run, "metrics_train_fitted_poses.json")))
    frames = fitted["frames"]
    assert frames > 0 and f"anchored on whole-body keypoints: {frames} of {frames} frames" in result.stdout
    assert fitted["pose_fitting"] == {"iterations": 3, "keypoint_weight": 1.0, "frames_with_keypoints": frames}

    # Without the term the files are not read: a broken one does not stop the image-only protocol.
    broken = tmp_path / "broken"
    shutil.copytree(video, broken)
    for name in os.listdir(broken / "keypoints_whole_body"):
        (broken / "keypoints_whole_body" / name).write_text("[]")
    result = sfgs_run("eval", "--run", run, "--data", str(broken), *fit, "--fit-keypoint-weight", "0")
    assert result.returncode == 0, result.stderr
    assert "anchored on whole-body keypoints: no (--fit-keypoint-weight 0)" in result.stdout
    result = sfgs_run("eval", "--run", run, "--data", str(broken), *fit)
    assert result.returncode != 0 and "expected 133 keypoints" in result.stderr, result.stderr
    result = sfgs_run("eval", "--run", run, *fit, "--fit-keypoint-weight", "-1")
    assert result.returncode != 0 and "fit-keypoint-weight" in result.stderr, result.stderr
