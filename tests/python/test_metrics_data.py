"""The metrics and dataset reading of `import sfgs`: PSNR, SSIM in its three border conventions and LPIPS against
the shared float64 reference values (../shared/lpips/testdata, skipped without them), and a synthetic dataset read
frame by frame."""
import json
import os
import subprocess

import pytest
import torch

import sfgs
from test_avatar_api import read_png_rgb

SHARED = os.environ.get("SFGS_SHARED_DIR", os.path.join(os.path.dirname(__file__), "..", "..", "..", "shared"))
LPIPS_DIR = os.path.join(SHARED, "lpips")
TESTDATA = os.path.join(LPIPS_DIR, "testdata")
SFGS = os.environ.get("SFGS_EXECUTABLE", "")


def reference_pair(name):
    if not os.path.isfile(os.path.join(TESTDATA, "expected.json")):
        pytest.skip(f"no LPIPS test pairs at {TESTDATA} (set SFGS_SHARED_DIR)")
    pairs = {p["name"]: p for p in json.load(open(os.path.join(TESTDATA, "expected.json")))["pairs"]}
    p = pairs[name]
    # 8-bit values divided in float64, as the reference did.
    a, b = ((read_png_rgb(os.path.join(TESTDATA, p[k])) * 255).round().double() / 255 for k in ("a", "b"))
    return p, a, b


def test_psnr_and_ssim_match_the_reference_values():
    p, a, b = reference_pair("p1_noise_64x64")
    assert abs(sfgs.psnr(b, a).item() - p["psnr"]) < 1e-9
    for border, key in (("valid", "ssim_valid"), ("zero", "ssim_zeropad"), ("reflect", "ssim_reflect")):
        assert abs(sfgs.ssim(b, a, border=border).item() - p[key]) < 1e-9, border
    assert sfgs.psnr(a, a).item() == float("inf")
    with pytest.raises(ValueError, match="expected 'reflect'"):
        sfgs.ssim(a, b, border="same")
    with pytest.raises(TypeError, match="psnr\\(prediction\\): expected a torch.Tensor, got list"):
        sfgs.psnr([0.5], a)


def test_lpips_matches_the_reference_values_and_is_differentiable():
    p, a, b = reference_pair("p1_noise_64x64")
    assert abs(sfgs.lpips(b, a, weights_dir=LPIPS_DIR).item() - p["lpips_alex"]) < 1e-8
    assert abs(sfgs.lpips(b, a, net="squeeze", weights_dir=LPIPS_DIR).item() - p["lpips_squeeze"]) < 1e-8
    x = b.clone().requires_grad_(True)
    sfgs.lpips(x, a, weights_dir=LPIPS_DIR).backward()
    assert x.grad is not None and x.grad.abs().sum() > 0
    with pytest.raises(ValueError, match="expected 'alex' or 'squeeze'"):
        sfgs.lpips(a, b, net="vgg")
    with pytest.raises(RuntimeError, match="LPIPS \\(alex\\) unavailable"):
        sfgs.lpips(a, b, weights_dir=os.path.join(SHARED, "no_such_folder"))


@pytest.mark.skipif(not os.path.isfile(SFGS), reason="SFGS_EXECUTABLE does not name the sfgs executable")
def test_a_dataset_reads_frame_by_frame(tmp_path):
    folder = str(tmp_path / "data")
    subprocess.run([SFGS, "synth", "--out", folder, "--frames", "10", "--width", "40", "--height", "32"], check=True,
                   capture_output=True)
    d = sfgs.read_dataset(folder)
    assert len(d) == 10 and d.format == "sfgs" and d.betas.numel() >= 10
    assert sorted(d.split("train") + d.split("val") + d.split("test")) == list(range(10))
    f = d.frame(d.split("test")[0])
    assert f["image"].shape == (32, 40, 3) and f["mask"].shape == (32, 40) and f["split"] == "test"
    assert f["pose"]["body_pose"].shape == (21, 3) and f["camera"]["width"] == 40
    assert 0 < f["mask"].mean() < 1, "the person covers part of the frame"
    with pytest.raises(ValueError, match="expected 'train', 'val' or 'test'"):
        d.split("all")
    with pytest.raises(RuntimeError, match="frame: index must be in \\[0, 10\\)"):
        d.frame(10)
    with pytest.raises(RuntimeError):
        sfgs.read_dataset(str(tmp_path / "nowhere"))


def test_metrics_refuse_images_of_another_scale_or_layout():
    a = torch.rand(8, 8, 3, dtype=torch.float64)
    with pytest.raises(RuntimeError, match=r"psnr\(prediction\): values must lie in \[0, 1\].*/ 255"):
        sfgs.psnr(a * 255, a)
    with pytest.raises(RuntimeError, match=r"ssim\(prediction\): .*\(x \+ 1\) / 2"):
        sfgs.ssim(a * 2 - 1, a)
    with pytest.raises(RuntimeError, match=r"psnr\(target\): the image holds NaN"):
        sfgs.psnr(a, torch.full_like(a, float("nan")))
    with pytest.raises(RuntimeError, match="channels-last"):
        sfgs.psnr(torch.rand(2, 3, 8, 8), torch.rand(2, 3, 8, 8))


def test_tensors_without_values_are_refused_by_name():
    meta = torch.zeros(4, 4, 3, device="meta")
    with pytest.raises(ValueError, match=r"psnr\(target\): expected a tensor on the CPU or a CUDA device, got one on "
                                         r"meta"):
        sfgs.psnr(torch.rand(4, 4, 3), meta)
