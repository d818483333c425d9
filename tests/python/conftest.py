"""Markers of the pytest suite: CTest runs the command-line tests (`-m cli`), the web viewer's (`-m web`) and the
Python module tests (`-m "not cli and not web"`) as three entries, so a failure shows which of them broke. The tiny
run that the avatar tests share is trained once a session by the `sfgs` executable SFGS_EXECUTABLE names."""
import os
import subprocess

import pytest

SFGS = os.environ.get("SFGS_EXECUTABLE", "")

TINY_CONFIG = """
run: {seed: 3, log_every: 1, validate_every: 2, checkpoint_every: 4}
avatar: {subdivision_levels: 0, plane_channels: 4, plane_resolution: 16, time_resolution: 4,
         face_plane_resolution: 16, hidden_width: 16}
loss: {use_lpips: false}
schedule: {iterations: 4, warmup_iterations: 1}
"""


def pytest_configure(config):
    config.addinivalue_line("markers", "cli: drives the sfgs executable as a user would (CTest entry 'cli')")
    config.addinivalue_line("markers", "web: the web viewer in headless Chromium (CTest entry 'web')")


@pytest.fixture(scope="session")
def run(tmp_path_factory):
    """A tiny avatar trained 4 iterations on a synthetic 10-frame, 40 x 32 dataset, evaluated with its images."""
    if not os.path.isfile(SFGS):
        pytest.skip("SFGS_EXECUTABLE does not name the sfgs executable")
    root = tmp_path_factory.mktemp("avatar_api")
    (root / "tiny.yaml").write_text(TINY_CONFIG)
    data, out = str(root / "data"), str(root / "run")
    subprocess.run([SFGS, "synth", "--out", data, "--frames", "10", "--width", "40", "--height", "32"], check=True)
    subprocess.run([SFGS, "train", "--data", data, "--out", out, "--config", str(root / "tiny.yaml"), "--quiet"],
                   check=True)
    subprocess.run([SFGS, "eval", "--run", out, "--data", data, "--save-images"], check=True)
    return out
