"""`sfgs export --web`: the exported folder plays the avatar in a web browser (docs/web_viewer.md).

Headless Chromium (Debian's `chromium`, WebGL2 on SwiftShader, no GPU needed) opens the folder from the disk at a
frame with the still camera of `sfgs render --camera fixed`; its screenshot must match the C++ render of that frame
(PSNR >= 30 dB). Also: every file the page loads is in the folder, and bad folders, motions and options are refused
by name without leaving anything behind. CTest runs this file as its own entry, `web`; it skips without Chromium or
without the sfgs executable (SFGS_EXECUTABLE)."""
import os
import re
import shutil
import subprocess

import numpy as np
import pytest

from test_avatar_api import read_png_rgb

SFGS = os.environ.get("SFGS_EXECUTABLE", "")
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
pytestmark = [pytest.mark.web,
              pytest.mark.skipif(not os.path.isfile(SFGS), reason="SFGS_EXECUTABLE does not name the sfgs executable")]
needs_chromium = pytest.mark.skipif(CHROMIUM is None, reason="Chromium is not installed (Debian: apt-get install "
                                    "chromium; scripts/install_deps.sh installs it), so the viewer is not tested")

# A tiny avatar trained long enough (40 steps, fast learning rates) to have learned colours and shading, so the
# comparison exercises the viewer's albedo, shading and offsets, not a uniform grey body.
WEB_CONFIG = """
run: {seed: 3, log_every: 10, validate_every: 100, checkpoint_every: 100}
avatar: {subdivision_levels: 0, plane_channels: 4, plane_resolution: 16, time_resolution: 4,
         face_plane_resolution: 16, hidden_width: 16}
loss: {use_lpips: false}
schedule: {iterations: 40, warmup_iterations: 1, learning_rate: 0.01, colour_learning_rate: 0.05}
"""
WIDTH, HEIGHT = 144, 192
FRAMES = 6
MIN_PSNR = 30.0


def sfgs_run(*args):
    return subprocess.run([SFGS, *args], capture_output=True, text=True)


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    root = tmp_path_factory.mktemp("web_viewer")
    data, run = str(root / "data"), str(root / "run")
    subprocess.run([SFGS, "synth", "--out", data, "--frames", "8", "--width", "64", "--height", "64"], check=True,
                   capture_output=True)
    (root / "web.yaml").write_text(WEB_CONFIG)
    result = sfgs_run("train", "--data", data, "--out", run, "--config", str(root / "web.yaml"), "--quiet")
    assert result.returncode == 0, result.stderr
    return run


@pytest.fixture(scope="module")
def exported(trained, tmp_path_factory):
    """The web export and the C++ render of the same motion, camera and size."""
    root = tmp_path_factory.mktemp("web_export")
    web, frames = str(root / "web"), str(root / "render")
    common = ["--run", trained, "--motion", "overhead", "--frames", str(FRAMES), "--size", f"{WIDTH}x{HEIGHT}"]
    result = sfgs_run("export", "--web", web, *common)
    assert result.returncode == 0, result.stderr
    assert f"Open {web}/index.html" in result.stdout
    result = sfgs_run("render", "--out", frames, "--camera", "fixed", *common)
    assert result.returncode == 0, result.stderr
    return web, frames


def chromium(url, *options):
    """Runs headless Chromium on `url` with WebGL2 on SwiftShader (the CPU), in a throw-away profile."""
    profile = url.split("file://", 1)[1].split("/index.html")[0] + ".profile"
    command = [CHROMIUM, "--headless=new", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
               "--force-device-scale-factor=1", "--force-color-profile=srgb", "--hide-scrollbars",
               f"--user-data-dir={profile}", "--virtual-time-budget=60000", *options, url]
    if os.geteuid() == 0:
        command.insert(1, "--no-sandbox")  # Chromium refuses to run as root with its sandbox
    try:
        return subprocess.run(command, capture_output=True, text=True, timeout=120)
    finally:
        shutil.rmtree(profile, ignore_errors=True)


def page_message(url):
    """The viewer's error message (empty when it drew), from the page's DOM."""
    dom = chromium(url, "--dump-dom").stdout
    found = re.search(r'<div id="message">(.*?)</div>', dom, re.S)
    return found.group(1) if found else "(no page: " + dom[:200] + ")"


def psnr(a, b):
    return 10 * np.log10(1.0 / float(((a - b) ** 2).mean()))


@needs_chromium
@pytest.mark.parametrize("frame", [0, 4])
def test_the_browser_shows_what_the_cpp_render_shows(exported, tmp_path, frame):
    web, frames = exported
    url = f"file://{os.path.abspath(web)}/index.html?frame={frame}&camera=render"
    shot = str(tmp_path / "shot.png")
    result = chromium(url, f"--window-size={WIDTH},{HEIGHT}", f"--screenshot={shot}")
    assert os.path.isfile(shot), result.stderr[-2000:]
    browser = read_png_rgb(shot).numpy()
    cpp = read_png_rgb(os.path.join(frames, f"frame_{frame:04d}.png")).numpy()
    assert browser.shape == cpp.shape == (HEIGHT, WIDTH, 3)
    assert (cpp < 0.9).any(), "the body should be in view"
    value = psnr(browser, cpp)
    print(f"web viewer frame {frame}: PSNR {value:.1f} dB against sfgs render")
    assert value >= MIN_PSNR, f"PSNR {value:.1f} dB; the page says: {page_message(url)!r}"


def test_the_folder_holds_every_file_its_page_loads(exported):
    web, _ = exported
    page = open(os.path.join(web, "index.html")).read()
    scripts = re.findall(r'<script src="([^"]+)"></script>', page)
    assert "data/manifest.js" in scripts and "viewer.js" in scripts
    assert any(s.startswith("data/frames_") for s in scripts)
    for script in scripts:
        assert os.path.isfile(os.path.join(web, script)), script
    assert not [n for n in os.listdir(os.path.dirname(web)) if ".tmp-" in n], "a temporary was left behind"


def test_bad_folders_motions_and_options_are_named(trained, tmp_path):
    occupied = tmp_path / "notes"
    occupied.mkdir()
    (occupied / "todo.txt").write_text("keep me")
    result = sfgs_run("export", "--run", trained, "--web", str(occupied))
    assert result.returncode == 1 and "exists and is not empty (pass --force" in result.stderr
    result = sfgs_run("export", "--run", trained, "--web", str(occupied), "--force")
    assert result.returncode == 1 and "is not an earlier web export" in result.stderr
    assert (occupied / "todo.txt").read_text() == "keep me"
    (tmp_path / "file").write_text("x")
    result = sfgs_run("export", "--run", trained, "--web", str(tmp_path / "file"), "--force")
    assert result.returncode == 1 and "exists and is not a folder" in result.stderr

    bad = tmp_path / "bad.npz"
    np.savez(bad, poses=np.zeros((4, 165)))
    result = sfgs_run("export", "--run", trained, "--web", str(tmp_path / "w1"), "--motion", str(bad))
    assert result.returncode == 1 and "lacks its frame rate: expected 'mocap_frame_rate'" in result.stderr
    result = sfgs_run("export", "--run", trained, "--web", str(tmp_path / "w2"), "--motion", "moonwalk")
    assert result.returncode == 1 and "moonwalk" in result.stderr
    result = sfgs_run("export", "--run", trained, "--web", str(tmp_path / "w3"), "--size", "48")
    assert result.returncode == 1 and "--size must be WIDTHxHEIGHT" in result.stderr
    result = sfgs_run("export", "--run", trained, "--web", str(tmp_path / "w4"), "--out", str(tmp_path / "a.ply"))
    assert result.returncode == 1 and "give either --out" in result.stderr
    result = sfgs_run("export", "--run", trained, "--web", str(tmp_path / "w5"), "--frame", "2")
    assert result.returncode == 1 and "unknown option(s): --frame" in result.stderr
    assert not [p for p in os.listdir(tmp_path) if p.startswith("w")], "a failed export left a folder"
