"""docs/python.md's examples, run in order as one script on conftest.py's tiny run: the reference's code works as
written. File names the examples use stand for files made here (a motion clip, the run's dataset, the stand-in body
models); a block that needs files this machine lacks (the LPIPS weights, the body models of ../shared) is skipped
and named."""
import os
import re

import pytest

from test_motion_render import amass_walk

DOCS = os.path.join(os.path.dirname(__file__), "..", "..", "docs", "python.md")
SHARED = os.environ.get("SFGS_SHARED_DIR", os.path.join(os.path.dirname(__file__), "..", "..", "..", "shared"))
LPIPS_WEIGHTS = os.path.join(SHARED, "lpips", "lpips_alex.safetensors")
BODIES = os.path.join(SHARED, "bodies")


def python_blocks():
    with open(DOCS) as f:
        return re.findall(r"```python\n(.*?)```", f.read(), re.S)


def test_the_docs_have_examples():
    blocks = python_blocks()
    assert len(blocks) >= 10
    assert any("training_loss" in b for b in blocks) and any("requires_grad_(True)" in b for b in blocks)


@pytest.mark.parametrize("device", ["cpu", "cuda"])
def test_every_python_example_runs(run, tmp_path, monkeypatch, device):
    import torch
    import sfgs

    if device == "cuda" and not (torch.cuda.is_available() and sfgs.cuda_available()):
        pytest.skip("the examples on CUDA need a GPU and a CUDA build")

    monkeypatch.chdir(tmp_path)  # what the examples write (finetuned.pt) lands here
    data = sfgs.load_avatar(run).dataset_path
    files = {
        '"sfgs_demo/run"': repr(run),
        '"clip.npz"': repr(amass_walk(tmp_path / "clip.npz", frames=6)),
        '"walk"': repr(data),
        '"SMPLX_NEUTRAL.npz"': repr(os.path.join(BODIES, "anny_smplx_layout.npz")),
        '"MANO_RIGHT.npz"': repr(os.path.join(BODIES, "anny_mano_right.npz")),
        'device="cpu")    # or "cuda"': f'device="{device}")    #',
    }
    needs = {"sfgs.lpips(": LPIPS_WEIGHTS, "sfgs.evaluate(": LPIPS_WEIGHTS,
             "sfgs.Smplx(": os.path.join(BODIES, "anny_smplx_layout.npz")}
    namespace = {}
    skipped = []
    for block in python_blocks():
        missing = [path for call, path in needs.items() if call in block and not os.path.isfile(path)]
        if missing:
            skipped.append(f"{block.splitlines()[0]!r} (needs {missing[0]})")
            continue
        for name, replacement in files.items():
            block = block.replace(name, replacement)
        exec(compile(block, DOCS, "exec"), namespace)
    assert "terms" in namespace and namespace["terms"]["total"].requires_grad
    assert namespace["placement"].grad is not None and namespace["body_pose"].grad is not None
    assert namespace["turntable"].shape[0] == 3
    if skipped:
        pytest.skip("ran every example but " + "; ".join(skipped))
