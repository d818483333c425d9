"""`sfgs prepare`'s landmarks against MediaPipe's own: the npm package's WebAssembly build of Holistic, run in headless
Chromium on the same synthetic frame, is the reference. The package's tarball is fetched with the models
(scripts/fetch_mediapipe_models.py keeps it beside them, checked against its SHA-256); skipped without Chromium, the sfgs executable or the
models. The body's and the hands' COCO-WholeBody keypoints are compared (the face's go through a correspondence)."""
import functools
import html
import http.server
import io
import json
import math
import os
import re
import shutil
import subprocess
import sys
import tarfile
import threading

import pytest

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "..", "scripts"))
import fetch_mediapipe_models  # noqa: E402

SFGS = os.environ.get("SFGS_EXECUTABLE", "")
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
MODELS = os.environ.get("SFGS_MEDIAPIPE_DIR", fetch_mediapipe_models.default_folder())
pytestmark = [pytest.mark.web,
              pytest.mark.skipif(not os.path.isfile(SFGS), reason="SFGS_EXECUTABLE does not name the sfgs executable"),
              pytest.mark.skipif(CHROMIUM is None, reason="Chromium is not installed (scripts/install_deps.sh)"),
              pytest.mark.skipif(not os.path.isfile(os.path.join(MODELS, "models.json")),
                                 reason=f"no MediaPipe models in {MODELS} (scripts/install_deps.sh fetches them)")]

# COCO-WholeBody's body keypoints 0-16 as MediaPipe pose landmarks (docs/prepare.md).
COCO_BODY = [0, 2, 5, 7, 8, 11, 12, 13, 14, 15, 16, 23, 24, 25, 26, 27, 28]
PAGE = """<!doctype html><html><body><img id="img" src="frame.png"><div id="out">pending</div>
<script src="holistic.js"></script><script>
const out = document.getElementById('out');
const holistic = new Holistic({locateFile: f => f});
holistic.setOptions({modelComplexity: 1, smoothLandmarks: false, enableSegmentation: false,
                     refineFaceLandmarks: false, selfieMode: false});
holistic.onResults(r => { out.textContent = JSON.stringify({pose: r.poseLandmarks, left: r.leftHandLandmarks,
                                                           right: r.rightHandLandmarks}); });
(async () => {
  try { const img = document.getElementById('img'); await img.decode(); await holistic.initialize();
        await holistic.send({image: img}); } catch (e) { out.textContent = 'error: ' + e; }
})();
</script></body></html>"""


def reference_landmarks(folder, frame):
    """MediaPipe's landmarks of `frame` (a PNG) from the package's WebAssembly build, served over HTTP."""
    package = fetch_mediapipe_models.tarball(MODELS)
    if package is None:
        pytest.skip(f"no package tarball in {MODELS} (scripts/install_deps.sh fetches it)")
    with tarfile.open(fileobj=io.BytesIO(package), mode="r:gz") as archive:
        archive.extractall(folder)
    site = os.path.join(folder, "package")
    shutil.copy(frame, os.path.join(site, "frame.png"))
    with open(os.path.join(site, "index.html"), "w") as f:
        f.write(PAGE)
    handler = functools.partial(http.server.SimpleHTTPRequestHandler, directory=site)
    handler.log_message = lambda *args: None
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    command = [CHROMIUM, "--headless=new", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
               f"--user-data-dir={folder}/profile", "--virtual-time-budget=60000", "--dump-dom",
               f"http://127.0.0.1:{server.server_address[1]}/index.html"]
    if os.geteuid() == 0:
        command.insert(1, "--no-sandbox")
    try:
        dom = subprocess.run(command, capture_output=True, text=True, timeout=240).stdout
    finally:
        server.shutdown()
    found = re.search(r'<div id="out">(.*?)</div>', dom, re.S)
    assert found and found.group(1).startswith("{"), "the reference page gave: " + (found.group(1) if found else dom[:300])
    return json.loads(html.unescape(found.group(1)))


def test_landmarks_match_mediapipes_own_build(tmp_path):
    video = str(tmp_path / "video")
    shared = os.environ.get("SFGS_SHARED_DIR", os.path.join(os.path.dirname(__file__), "..", "..", "..", "shared"))
    bodies = os.path.join(shared, "bodies")
    if not os.path.isfile(os.path.join(bodies, "anny_smplx_layout.npz")):
        # The built-in body's blank face leaves front and back ambiguous, and the two builds may read it either way.
        pytest.skip(f"the CC0 stand-in person is absent ({bodies}; set SFGS_SHARED_DIR)")
    subprocess.run([SFGS, "synth", "--out", video, "--motions", "wave", "--frames", "1", "--width", "540",
                    "--height", "960", "--body", os.path.join(bodies, "anny_smplx_layout.npz"), "--texture",
                    os.path.join(bodies, "anny_albedo.png")], check=True, capture_output=True)
    frames = tmp_path / "frames"
    frames.mkdir()
    frame = os.path.join(video, "images", "000000.png")
    shutil.copy(frame, frames / "000000.png")
    result = subprocess.run([SFGS, "prepare", str(frames), "--out", str(tmp_path / "dataset"), "--no-fit", "--quiet"],
                            capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    with open(tmp_path / "dataset" / "keypoints_whole_body" / "0.json") as f:
        ours = json.load(f)
    reference = reference_landmarks(str(tmp_path / "reference"), frame)

    def error(landmark, keypoint):
        return math.hypot(landmark["x"] * 540 - keypoint[0], landmark["y"] * 960 - keypoint[1])

    body = sorted(error(reference["pose"][m], ours[k]) for k, m in enumerate(COCO_BODY))
    hands = sorted(error(reference[side][k], ours[first + k]) for side, first in (("left", 91), ("right", 112))
                   if reference.get(side) and ours[first][2] > 0 for k in range(21))
    print(f"against MediaPipe's build: body median {body[len(body) // 2]:.2f} px (max {body[-1]:.2f}); "
          f"hands both found: {len(hands) // 21}" + (f", median {hands[len(hands) // 2]:.2f} px" if hands else ""))
    # Measured 2.4 px (body, max 6.9) and 1.1 px (both hands); the target is 1 px (docs/prepare.md).
    assert body[len(body) // 2] < 3.0 and body[-1] < 8.0
    found = {side: bool(reference.get(side)) for side in ("left", "right")}
    assert found == {"left": ours[91][2] > 0, "right": ours[112][2] > 0}, "the same hands are found"
    assert not hands or hands[len(hands) // 2] < 3.0
