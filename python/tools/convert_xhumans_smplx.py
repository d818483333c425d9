#!/usr/bin/env python3
"""Convert X-Humans' per-frame SMPL-X pickles (TakeN/SMPLX/mesh-fNNNNN_smplx.pkl) to JSON once, so sfgs reads them
without Python. Needs only numpy. Usage: convert_xhumans_smplx.py SUBJECT_FOLDER [--force]

Each .pkl holds a dict of numpy arrays (global_orient, transl, body_pose, left_hand_pose, right_hand_pose, jaw_pose,
leye_pose, reye_pose, expression, betas); the .json written beside it holds the same keys as flat lists.
"""
import argparse
import json
import os
import pickle
import sys
from pathlib import Path

import numpy as np

KEYS = ("global_orient", "transl", "body_pose", "left_hand_pose", "right_hand_pose", "jaw_pose", "leye_pose",
        "reye_pose", "expression", "betas")
REQUIRED = ("global_orient", "transl", "body_pose", "left_hand_pose", "right_hand_pose", "jaw_pose", "leye_pose",
            "reye_pose")


def load_pickle(path):
    with open(path, "rb") as f:
        try:
            return pickle.load(f)
        except UnicodeDecodeError:  # written by Python 2
            f.seek(0)
            return pickle.load(f, encoding="latin1")


def convert(pkl_path, force):
    out_path = pkl_path.with_suffix(".json")
    if out_path.exists() and not force:
        return False
    data = load_pickle(pkl_path)
    if not isinstance(data, dict):
        raise ValueError(f"{pkl_path}: expected a dict of arrays, got {type(data).__name__}")
    missing = [k for k in REQUIRED if k not in data]
    if missing:
        raise ValueError(f"{pkl_path}: missing SMPL-X parameters {missing}")
    values = {k: np.asarray(data[k], dtype=np.float64).reshape(-1).tolist() for k in KEYS if k in data}
    tmp = out_path.with_name(out_path.name + f".tmp-{os.getpid()}")
    tmp.write_text(json.dumps(values))
    os.replace(tmp, out_path)
    return True


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("subject", type=Path, help="X-Humans subject folder holding train/ and test/")
    parser.add_argument("--force", action="store_true", help="rewrite existing .json files")
    args = parser.parse_args(argv)
    pickles = sorted(args.subject.glob("*/Take*/SMPLX/*_smplx.pkl"))
    if not pickles:
        print(f"no */Take*/SMPLX/*_smplx.pkl under {args.subject}", file=sys.stderr)
        return 1
    written = sum(convert(p, args.force) for p in pickles)
    print(f"converted {written} of {len(pickles)} SMPL-X pickles under {args.subject}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
