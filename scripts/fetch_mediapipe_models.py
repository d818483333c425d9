#!/usr/bin/env python3
"""Fetches the MediaPipe Holistic models that `sfgs prepare` runs (docs/prepare.md) from the npm registry: the
package @mediapipe/holistic at a pinned version (Apache-2.0), its tarball checked against a pinned SHA-256. Writes
the .tflite files into DIR (default: models/mediapipe beside this script's repository, which git ignores): the
loose pose landmark models, and those packed into holistic_solution_packed_assets.data, cut out at the offsets its
loader script lists, and the tarball itself (the reference that tests/python/test_prepare_parity.py runs in Chromium).
Each model is checked for the TFLite file identifier and written atomically. Standard library only; a second run
with the files in place downloads nothing."""
import argparse
import hashlib
import io
import json
import os
import re
import sys
import tarfile
import tempfile
import urllib.request

PACKAGE = "@mediapipe/holistic"
VERSION = "0.5.1675471629"
TARBALL_URL = f"https://registry.npmjs.org/{PACKAGE}/-/holistic-{VERSION}.tgz"
TARBALL_SHA256 = "8a3c0632e40e761e637d020738e96dc54d9bbbd4330ce2b206469fe467fd708b"
LOOSE = ["pose_landmark_lite.tflite", "pose_landmark_full.tflite", "pose_landmark_heavy.tflite"]
PACKED = ["pose_detection.tflite", "face_detection_short_range.tflite", "face_landmark.tflite",
          "face_landmark_with_attention.tflite", "hand_landmark_full.tflite", "hand_recrop.tflite"]
MANIFEST = "models.json"
TARBALL = f"holistic-{VERSION}.tgz"


def default_folder():
    return os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "models", "mediapipe")


def write_atomically(path, data):
    handle, temporary = tempfile.mkstemp(dir=os.path.dirname(path), prefix=".tmp-")
    with os.fdopen(handle, "wb") as f:
        f.write(data)
    os.chmod(temporary, 0o644)
    os.replace(temporary, path)


def is_tflite(data):
    return len(data) > 8 and data[4:8] == b"TFL3"


def complete(folder):
    """Whether every model is in `folder` with the checksum the manifest recorded when it was written."""
    try:
        with open(os.path.join(folder, MANIFEST)) as f:
            manifest = json.load(f)
    except (OSError, ValueError):
        return False
    if manifest.get("version") != VERSION:
        return False
    for name in LOOSE + PACKED + [TARBALL]:
        path = os.path.join(folder, name)
        if not os.path.isfile(path):
            return False
        with open(path, "rb") as f:
            if hashlib.sha256(f.read()).hexdigest() != manifest["sha256"].get(name):
                return False
    return True


def check_tarball(data):
    digest = hashlib.sha256(data).hexdigest()
    if digest != TARBALL_SHA256:
        raise SystemExit(f"fetch_mediapipe_models: {TARBALL_URL} has SHA-256 {digest}, expected {TARBALL_SHA256}; "
                         "not using it")
    return data


def download():
    with urllib.request.urlopen(TARBALL_URL, timeout=120) as response:
        return check_tarball(response.read())


def tarball(folder):
    """The package's tarball as fetched into `folder` (checked), or None when it is not there."""
    path = os.path.join(folder, TARBALL)
    if not os.path.isfile(path):
        return None
    with open(path, "rb") as f:
        return check_tarball(f.read())


def models_of(tarball):
    """{name: bytes} of the package's models."""
    with tarfile.open(fileobj=io.BytesIO(tarball), mode="r:gz") as archive:
        def member(name):
            return archive.extractfile(f"package/{name}").read()
        models = {name: member(name) for name in LOOSE}
        loader = member("holistic_solution_packed_assets_loader.js").decode()
        packed = member("holistic_solution_packed_assets.data")
    entries = re.findall(r'"filename":\s*"([^"]+)",\s*"start":\s*(\d+),\s*"end":\s*(\d+)', loader)
    offsets = {os.path.basename(path): (int(start), int(end)) for path, start, end in entries}
    for name in PACKED:
        if name not in offsets:
            raise SystemExit(f"fetch_mediapipe_models: the package's loader lists no {name}")
        start, end = offsets[name]
        models[name] = packed[start:end]
    for name, data in models.items():
        if not is_tflite(data):
            raise SystemExit(f"fetch_mediapipe_models: {name} of {PACKAGE}@{VERSION} is not a TFLite model")
    return models


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folder", nargs="?", default=default_folder())
    folder = os.path.abspath(parser.parse_args().folder)
    os.makedirs(folder, exist_ok=True)
    if complete(folder):
        print(f"MediaPipe Holistic {VERSION} models are in {folder}")
        return
    package = download()
    models = models_of(package)
    for name, data in models.items():
        write_atomically(os.path.join(folder, name), data)
    write_atomically(os.path.join(folder, TARBALL), package)
    models[TARBALL] = package
    manifest = {"package": PACKAGE, "version": VERSION, "license": "Apache-2.0", "tarball": TARBALL_URL,
                "sha256": {name: hashlib.sha256(data).hexdigest() for name, data in models.items()}}
    write_atomically(os.path.join(folder, MANIFEST), (json.dumps(manifest, indent=1) + "\n").encode())
    print(f"fetched MediaPipe Holistic {VERSION}: {len(models) - 1} models and the package in {folder}")


if __name__ == "__main__":
    sys.exit(main())
