"""No silent failures and no lost runs, through the `sfgs` executable and `import sfgs` as a user meets them:
concurrent trains, kill -9 and resume, a render that runs out of space, options that swallow options, runs used
from another directory, and Python arguments of the wrong type or value.

Trains tiny avatars with the executable named by SFGS_EXECUTABLE (CTest sets it); skipped without it."""
import json
import os
import resource
import signal
import subprocess
import time

import pytest
import torch

import sfgs

SFGS = os.environ.get("SFGS_EXECUTABLE", "")
pytestmark = [pytest.mark.cli,
              pytest.mark.skipif(not os.path.isfile(SFGS), reason="SFGS_EXECUTABLE does not name the sfgs executable")]

TINY = """
run: {seed: 3, log_every: 1, validate_every: 100, checkpoint_every: %d}
avatar: {subdivision_levels: 0, plane_channels: 4, plane_resolution: 16, time_resolution: 4,
         face_plane_resolution: 16, hidden_width: 16}
loss: {use_lpips: false}
schedule: {iterations: %d, warmup_iterations: 1}
"""


def sfgs_run(*args, cwd=None, **kwargs):
    return subprocess.run([SFGS, *args], cwd=cwd, capture_output=True, text=True, **kwargs)


def config(tmp_path, iterations, checkpoint_every=100):
    path = tmp_path / f"tiny_{iterations}_{checkpoint_every}.yaml"
    path.write_text(TINY % (checkpoint_every, iterations))
    return str(path)


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    folder = str(tmp_path_factory.mktemp("safety") / "data")
    subprocess.run([SFGS, "synth", "--out", folder, "--frames", "10", "--width", "40", "--height", "32"], check=True,
                   capture_output=True)
    return folder


@pytest.fixture(scope="module")
def trained(tmp_path_factory, data):
    root = tmp_path_factory.mktemp("trained")
    run = str(root / "run")
    result = sfgs_run("train", "--data", data, "--out", run, "--config", config(root, 2), "--quiet")
    assert result.returncode == 0, result.stderr
    return run


def log_events(run):
    with open(os.path.join(run, "log.jsonl")) as f:
        return [json.loads(line) for line in f]


def wait_for(condition, seconds=120):
    deadline = time.time() + seconds
    while time.time() < deadline:
        if condition():
            return True
        time.sleep(0.05)
    return False


def test_two_trains_into_one_folder_the_second_is_refused_naming_the_first(tmp_path, data):
    run = str(tmp_path / "run")
    cfg = config(tmp_path, 12)
    first = subprocess.Popen([SFGS, "train", "--data", data, "--out", run, "--config", cfg, "--quiet", "--force"],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lock = os.path.join(run, ".sfgs-train.lock")
    assert wait_for(lambda: os.path.exists(lock) and "pid" in open(lock).read())
    second = sfgs_run("train", "--data", data, "--out", run, "--config", cfg, "--quiet", "--force")
    out, err = first.communicate(timeout=600)
    assert first.returncode == 0, err
    assert second.returncode == 1
    assert f"is in use by another sfgs train (pid {first.pid}, `" in second.stderr
    assert [e["event"] for e in log_events(run)].count("end") == 1


def test_a_run_killed_mid_training_resumes_without_duplicate_log_rows(tmp_path, data):
    run = str(tmp_path / "run")
    victim = subprocess.Popen([SFGS, "train", "--data", data, "--out", run, "--config", config(tmp_path, 10, 3),
                               "--quiet"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)

    def past_the_first_checkpoint():
        try:
            return os.path.exists(os.path.join(run, "checkpoint.pt")) and any(
                e["event"] == "step" and e["iteration"] >= 4 for e in log_events(run))
        except (OSError, ValueError):
            return False

    assert wait_for(past_the_first_checkpoint)
    victim.send_signal(signal.SIGKILL)
    victim.wait()
    stale = os.path.join(run, f"checkpoint.pt.tmp-{victim.pid}")
    open(stale, "wb").write(b"half a checkpoint")  # what a kill during a checkpoint write leaves
    result = sfgs_run("train", "--out", run, "--resume", "--quiet")  # the README's form: no --data, no --config
    assert result.returncode == 0, result.stderr
    assert "removed 'checkpoint.pt.tmp-" in result.stderr
    assert not os.path.exists(stale)
    steps = [e["iteration"] for e in log_events(run) if e["event"] == "step"]
    assert sorted(steps) == list(range(1, 11))
    assert "the run is finished at iteration 10 of 10" in result.stdout
    again = sfgs_run("train", "--out", run, "--resume", "--quiet")
    assert again.returncode == 0 and "already at iteration 10 of 10: nothing to do" in again.stdout


def test_a_render_that_runs_out_of_space_fails_and_leaves_nothing(tmp_path, trained):
    out = str(tmp_path / "video")

    def small_file_limit():  # every file past 6 KB fails to grow: a full disk for the video, not for the frames
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (6000, 6000))

    result = subprocess.run([SFGS, "render", "--run", trained, "--out", out, "--frames", "40"], capture_output=True,
                            text=True, preexec_fn=small_file_limit)
    assert result.returncode == 1, result.stdout
    assert "render.mp4" in result.stderr and "incomplete" in result.stderr, result.stderr
    assert "the 40 frames it had written" in result.stderr
    assert sorted(os.listdir(out)) == [".sfgs-render.lock"]


def test_render_force_replaces_exactly_the_earlier_render(tmp_path, trained):
    out = str(tmp_path / "video")
    assert sfgs_run("render", "--run", trained, "--out", out, "--frames", "6").returncode == 0
    frames = lambda: sorted(f for f in os.listdir(out) if f.startswith("frame_"))
    assert len(frames()) == 6
    manifest = json.load(open(os.path.join(out, "render.json")))
    assert manifest["format"] == "sfgs-render" and manifest["frames"] == 6 and set(frames()) <= set(manifest["written"])
    result = sfgs_run("render", "--run", trained, "--out", out, "--frames", "2")
    assert result.returncode == 1 and "pass --force to replace it" in result.stderr
    assert sfgs_run("render", "--run", trained, "--out", out, "--frames", "2", "--force").returncode == 0
    assert frames() == ["frame_0000.png", "frame_0001.png"], "the earlier render's extra frames go with it"
    # A file the user put in the folder: refused by name, --force or not, and nothing changes.
    open(os.path.join(out, "thesis.tex"), "w").write("mine")
    before = sorted(os.listdir(out))
    result = sfgs_run("render", "--run", trained, "--out", out, "--frames", "3", "--force")
    assert result.returncode == 1 and "'thesis.tex'" in result.stderr and "no sfgs render wrote" in result.stderr
    assert sorted(os.listdir(out)) == before


def test_version_and_per_command_help():
    result = sfgs_run("--version")
    assert result.returncode == 0 and result.stdout.startswith("sfgs 0.") and "LibTorch" in result.stdout
    assert sfgs_run("version").stdout == result.stdout
    result = sfgs_run("train", "--help")
    assert result.returncode == 0 and result.stdout.startswith("usage: sfgs train [options]")
    assert "--stop-at" in result.stdout and "Options take their value" in result.stdout
    assert "ablate" not in result.stdout and "synth " not in result.stdout, "only train's section"
    assert "  ablate " in sfgs_run("help").stdout, "sfgs help lists every command"


def test_options_never_swallow_options(tmp_path, data):
    result = sfgs_run("train", "--data", data, "--out", "--force")
    assert result.returncode == 1
    assert "option --out needs a value, but the next argument is the option '--force'" in result.stderr
    assert not os.path.exists("--force")
    result = sfgs_run("train", "--data", "--out", str(tmp_path / "x"))
    assert result.returncode == 1 and "option --data needs a value" in result.stderr
    result = sfgs_run("eval", "--run", str(tmp_path), "--run", str(tmp_path))
    assert result.returncode == 1 and "option --run is given twice" in result.stderr
    # A run inside its dataset folder would mix its files into the dataset's.
    result = sfgs_run("train", "--data", data, "--out", os.path.join(data, "run"))
    assert result.returncode == 1 and "lies in the dataset folder" in result.stderr
    assert not os.path.exists(os.path.join(data, "run"))
    # An output of the wrong kind is refused before any work: a PNG never lands on a checkpoint.
    checkpoint = tmp_path / "checkpoint.pt"
    checkpoint.write_text("precious")
    result = sfgs_run("bench", "--out", str(checkpoint), "--force")
    assert result.returncode == 1 and "names the PNG image the bench writes (FILE.png)" in result.stderr
    assert checkpoint.read_text() == "precious"
    # --stop-at 0 is no iteration to pause at (it was once taken as "not given").
    result = sfgs_run("train", "--data", data, "--out", str(tmp_path / "paused"), "--stop-at", "0")
    assert result.returncode == 1 and "--stop-at expects an integer in [1, " in result.stderr
    assert not os.path.exists(tmp_path / "paused")


def test_a_run_is_used_from_any_directory_and_a_moved_dataset_is_named(tmp_path, data, trained):
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    result = sfgs_run("eval", "--run", os.path.abspath(trained), cwd=str(elsewhere))
    assert result.returncode == 0, result.stderr
    moved = str(tmp_path / "moved_data")
    os.rename(data, moved)
    try:
        result = sfgs_run("eval", "--run", trained)
        assert result.returncode == 1
        assert "which is not there" in result.stderr and "(--data;" in result.stderr
        assert sfgs_run("eval", "--run", trained, "--data", moved).returncode == 0
        result = sfgs_run("train", "--out", trained, "--resume", "--data", moved, "--iterations", "3", "--quiet")
        assert result.returncode == 0, result.stderr  # same data, new place: the fingerprint matches
    finally:
        os.rename(moved, data)
    result = sfgs_run("train", "--out", trained, "--resume", "--iterations", "4")  # the run now names 'moved'
    assert result.returncode == 1 and "which is not there (moved or deleted); pass --data" in result.stderr


def test_resume_refusals_leave_the_run_untouched(tmp_path, data, trained):
    before = {name: open(os.path.join(trained, name), "rb").read() for name in ("config.yaml", "checkpoint.pt")}
    wide = tmp_path / "wide.yaml"
    wide.write_text(open(os.path.join(trained, "config.yaml")).read().replace("hidden_width: 16", "hidden_width: 32"))
    result = sfgs_run("train", "--out", trained, "--resume", "--config", str(wide), "--data", data)
    assert result.returncode == 1 and "avatar.hidden_width (16 -> 32)" in result.stderr
    result = sfgs_run("train", "--out", trained, "--resume", "--iterations", "1", "--data", data)
    assert result.returncode == 1 and "past the 1 iterations asked for" in result.stderr
    other = str(tmp_path / "other")
    subprocess.run([SFGS, "synth", "--out", other, "--frames", "10", "--width", "40", "--height", "32", "--seed", "9"],
                   check=True, capture_output=True)
    result = sfgs_run("train", "--out", trained, "--resume", "--data", other)
    assert result.returncode == 1 and "is not the one this run was trained on" in result.stderr
    assert before == {name: open(os.path.join(trained, name), "rb").read() for name in before}


def test_python_arguments_of_the_wrong_type_or_value_are_our_errors(data, trained):
    avatar = sfgs.load_avatar(trained, data=data)
    frame = avatar.frame(2)
    with pytest.raises(TypeError, match=r"pose\['body_pose'\]: expected a torch.Tensor, got list \(wrap it"):
        avatar.render(frame["camera"], {"body_pose": [0.1] * 63})
    with pytest.raises(TypeError, match=r"pose: expected a dict of SMPL-X parameters"):
        avatar.gaussians([1, 2, 3])
    camera = dict(frame["camera"], width=40.0)
    with pytest.raises(TypeError, match=r"camera\['width'\]: expected an int, got float 40.0"):
        avatar.render(camera, frame["pose"])
    with pytest.raises(RuntimeError, match="body_pose must be finite"):
        avatar.gaussians({"body_pose": torch.full((21, 3), float("nan"))})
    with pytest.raises(RuntimeError, match="transl must be finite, got inf at index 0"):
        avatar.render(frame["camera"], {"transl": torch.tensor([float("inf"), 0.0, 0.0])})
    singular = dict(frame["camera"], world_to_camera=torch.zeros(4, 4, dtype=torch.float64))
    singular["world_to_camera"][3, 3] = 1
    with pytest.raises(RuntimeError, match="rotation part of world_to_camera must be orthonormal"):
        avatar.render(singular, frame["pose"])
    s = sfgs.demo_scene(count=10, width=16, height=12)
    with pytest.raises(RuntimeError, match=r"demo_scene: the Gaussian count must be >= 0, got -5"):
        sfgs.demo_scene(count=-5, width=16, height=12)
    with pytest.raises(RuntimeError, match=r"demo_scene: the image must be 1 to 16384 pixels a side, got 0 x 12"):
        sfgs.demo_scene(count=10, width=0, height=12)
    with pytest.raises(TypeError, match=r"render\(width\): expected an int, got float 16.0"):
        sfgs.render(s["means"], s["opacities"], s["features"], s["background"], s["world_to_camera"], s["fx"],
                    s["fy"], s["cx"], s["cy"], 16.0, 12, scales=s["scales"], rotations=s["rotations"])
    with pytest.raises(TypeError, match=r"render\(means\): expected a torch.Tensor, got list"):
        sfgs.render([0.0] * 3, s["opacities"], s["features"], s["background"], s["world_to_camera"], s["fx"],
                    s["fy"], s["cx"], s["cy"], 16, 12, scales=s["scales"], rotations=s["rotations"])


def test_results_carry_their_provenance_and_never_outlive_their_checkpoint(tmp_path, data):
    run = str(tmp_path / "run")
    tiny = config(tmp_path, 2)
    assert sfgs_run("train", "--data", data, "--out", run, "--config", tiny, "--quiet").returncode == 0
    for split in ("test", "val"):
        result = sfgs_run("eval", "--run", run, "--split", split, "--save-images")
        assert result.returncode == 0, result.stderr
    metrics = {split: json.load(open(os.path.join(run, f"metrics_{split}.json"))) for split in ("test", "val")}
    for split, m in metrics.items():
        p = m["provenance"]
        assert p["split"] == split and p["own_dataset"] and p["checkpoint_iteration"] == 2, p
        assert len(p["checkpoint_crc32"]) == 8 and p["dataset_fingerprint"] and p["written_at"].endswith("Z"), p
        assert p["command"].startswith("sfgs eval --run") and f"--split {split}" in p["command"], p
    assert os.path.isdir(os.path.join(run, "eval_images_test"))

    # Another dataset: refused unless asked for, and then kept apart from the run's own results.
    other = str(tmp_path / "other")
    subprocess.run([SFGS, "synth", "--out", other, "--frames", "10", "--width", "40", "--height", "32", "--seed", "9"],
                   check=True, capture_output=True)
    result = sfgs_run("eval", "--run", run, "--data", other)
    assert result.returncode == 1 and "--other-dataset" in result.stderr and "is not the dataset" in result.stderr
    assert sfgs_run("eval", "--run", run, "--data", other, "--other-dataset").returncode == 0
    foreign = [f for f in os.listdir(run) if f.startswith("metrics_test_")]
    assert len(foreign) == 1 and json.load(open(os.path.join(run, foreign[0])))["provenance"]["own_dataset"] is False
    with pytest.raises(RuntimeError, match="other_dataset=True"):
        sfgs.load_avatar(run, data=other)
    assert sfgs.load_avatar(run, data=other, other_dataset=True).frame_count == 10

    # A file the user keeps in an images folder survives every removal.
    keep = os.path.join(run, "eval_images_test", "notes.txt")
    open(keep, "w").write("mine")
    # Training on replaces the checkpoint: the results it described go, with their images.
    result = sfgs_run("train", "--out", run, "--resume", "--iterations", "3", "--quiet")
    assert result.returncode == 0, result.stderr
    assert not [f for f in os.listdir(run) if f.startswith("metrics")]
    assert os.listdir(os.path.join(run, "eval_images_test")) == ["notes.txt"]
    # A fresh run on the folder clears the derived outputs (and only them).
    assert sfgs_run("eval", "--run", run, "--split", "val").returncode == 0
    result = sfgs_run("train", "--data", data, "--out", run, "--config", tiny, "--quiet", "--force")
    assert result.returncode == 0, result.stderr
    assert not [f for f in os.listdir(run) if f.startswith("metrics")] and os.path.isfile(keep)


def test_a_cpu_run_of_days_says_so_after_its_first_step(tmp_path, data):
    run = str(tmp_path / "run")
    long_run = config(tmp_path, 100000000)
    result = sfgs_run("train", "--data", data, "--out", run, "--config", long_run, "--stop-at", "1")
    assert result.returncode == 0, result.stderr
    assert "the run's 100000000 remaining iterations would take about" in result.stderr, result.stderr
    assert "configs/demo.yaml" in result.stderr and "--iterations N" in result.stderr
    estimate = [e for e in log_events(run) if e["event"] == "estimate"]
    assert len(estimate) == 1 and estimate[0]["estimated_seconds"] > 3600, estimate


def test_synth_reports_its_progress(tmp_path):
    result = sfgs_run("synth", "--out", str(tmp_path / "video"), "--frames", "10", "--width", "32", "--height", "32")
    assert result.returncode == 0, result.stderr
    lines = [line for line in result.stdout.splitlines() if "frames rendered" in line]
    assert len(lines) >= 5 and lines[0].startswith("sfgs synth: 1 of 10 frames rendered"), result.stdout


def test_vague_errors_say_what_and_where(tmp_path, data, trained):
    # An empty split is named, with what the dataset has.
    neuman = str(tmp_path / "neuman")
    subprocess.run([SFGS, "synth", "--out", neuman, "--frames", "3", "--width", "32", "--height", "32", "--layout",
                    "neuman"], check=True, capture_output=True)
    run = str(tmp_path / "run")
    assert sfgs_run("train", "--data", neuman, "--out", run, "--config", config(tmp_path, 1), "--quiet").returncode == 0
    result = sfgs_run("eval", "--run", run, "--split", "test")
    assert result.returncode == 1 and "has no frames in its test split (train 3, val 0, test 0" in result.stderr, \
        result.stderr
    # --start-fits naming nothing, and --resume of a folder holding no run, name the option.
    result = sfgs_run("train", "--data", data, "--out", str(tmp_path / "r2"), "--start-fits", str(tmp_path / "none"))
    assert result.returncode == 1 and "--start-fits '" in result.stderr and "neither a trained run" in result.stderr
    result = sfgs_run("train", "--out", str(tmp_path / "empty"), "--resume")
    assert result.returncode == 1 and "--resume:" in result.stderr and "holds no run to resume" in result.stderr
