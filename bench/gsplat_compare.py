"""sfgs.render against gsplat 1.6.0 on the same scenes, in one Python process on one CUDA GPU: the median
milliseconds of the forward pass (autograd on, as in training), of a forward pass without autograd, and of
forward + backward (gradients of means, quaternions, scales, opacities and colours through the scalar loss
sum(image * target), target a fixed random image), each timed with CUDA events over interleaved rounds after a
warm-up (the two renderers alternate, and which goes first alternates too); the time ratio sfgs / gsplat (below 1:
sfgs is faster); and how closely the two agree: PSNR of sfgs's image and alpha against gsplat's (aim: 100 dB or
more), the largest pixel difference, the Gaussians whose projected radius differs, and the relative L2 error of each
gradient.

The scene is bench/bench_splat_cuda.cpp's avatar workload: N Gaussians in a 0.5 x 1.8 x 0.3 m box centred 3 m in
front of a pinhole camera at the origin (fx = fy = 1500, principal point at the image centre, images W x H, portrait),
log-uniform scales 3-15 mm at 167,390 Gaussians (times sqrt(167390 / N) otherwise, each axis times a log-uniform
0.8-1.25 factor), random unit quaternions (w, x, y, z), opacities uniform in (0.05, 0.99), RGB colours uniform in
[0, 1], white background, float32; seeded, made on the CPU, so both renderers and every run see the same scene.

gsplat is called through the functions its rasterization() runs for this configuration (1.6.0's C++ orchestrator,
rasterization_3dgs, with packed=False, rasterize_mode="classic", no spherical harmonics, render_mode="RGB"):
fully_fused_projection with the opacities (opacity-aware radii), isect_tiles with conics and opacities (its AccuTile
ellipse test), isect_offset_encode and rasterize_to_pixels, with eps2d = 0.3, tile size 16, near 0.01, far 1e10 and
the background. The conventions are sfgs's: OpenCV camera, pixel centres at +0.5, the 0.3 px^2 low-pass, alpha capped
at 0.99, pairs below 1/255 skipped, a pixel stops before the Gaussian that takes its transmittance below 1e-4, depth
order per tile with ties by index. --gsplat-api rasterization times gsplat.rasterization() itself instead (needs a
full gsplat build; the trimmed benchmark build registers no kernel for its orchestrator).

gsplat 1.6.0 splits every kernel over all visible GPUs, so this script shows it one (CUDA_VISIBLE_DEVICES=0) unless
CUDA_VISIBLE_DEVICES is already set.

Usage (GPU machine; the sfgs module built with CUDA, gsplat 1.6.0 importable: `pip install gsplat==1.6.0` where a
network is, or a build of its source; docs/performance.md, "Against gsplat", says how the recorded figures were made):
  PYTHONPATH=build/python:/tmp/gsplat-site python3 bench/gsplat_compare.py [--cases 167k-800x1200,1m-800x1200,...]
      [--rounds 50] [--warmup 10] [--seed 0] [--json OUT.json] [--probe]
A case is a name below or COUNT:WIDTHxHEIGHT. Without CUDA or gsplat it stops with a message (exit status 1);
--cpu-check renders one small scene with sfgs on the CPU only (checks the scene and the call; no GPU, no gsplat).
"""
import argparse
import json
import math
import os
import statistics
import sys
import time

# Before torch initialises CUDA: gsplat 1.6.0 would spread its kernels over every visible GPU.
os.environ.setdefault("CUDA_VISIBLE_DEVICES", "0")

import torch  # noqa: E402  (after the environment above)

REFERENCE_COUNT = 167390  # the avatar workload's Gaussian count; scales are sized for it
FOCAL_PX = 1500.0
BOX_SIZE_M = (0.5, 1.8, 0.3)
BOX_CENTRE_M = (0.0, 0.0, 3.0)
SCALE_RANGE_M = (3e-3, 15e-3)
AXIS_FACTOR_RANGE = (0.8, 1.25)
OPACITY_RANGE = (0.05, 0.99)
NEAR_PLANE, FAR_PLANE = 0.01, 1e10  # sfgs's and gsplat's defaults
LOW_PASS_PX2 = 0.3                  # sfgs kLowPassVariancePx2 = gsplat eps2d
TILE_SIZE = 16
PSNR_TARGET_DB = 100.0
NAMED_CASES = {
    "167k-800x1200": (167390, 800, 1200),
    "1m-800x1200": (1000000, 800, 1200),
    "167k-1080x1920": (167390, 1080, 1920),
}
PARAMETER_NAMES = ("means", "quats", "scales", "opacities", "colors")


class Scene:
    """Gaussians, camera and loss target of one case, as tensors on one device."""

    def __init__(self, count, width, height, seed, device, focal=FOCAL_PX):
        generator = torch.Generator().manual_seed(seed)

        def uniform(shape, low, high):
            return torch.rand(shape, generator=generator, dtype=torch.float64) * (high - low) + low

        def log_uniform(shape, low, high):
            return uniform(shape, math.log(low), math.log(high)).exp()

        box_size, box_centre = torch.tensor(BOX_SIZE_M, dtype=torch.float64), torch.tensor(BOX_CENTRE_M)
        means = (uniform((count, 3), -0.5, 0.5) * box_size + box_centre)
        density = math.sqrt(REFERENCE_COUNT / count)
        scales = (log_uniform((count, 1), SCALE_RANGE_M[0] * density, SCALE_RANGE_M[1] * density)
                  * log_uniform((count, 3), *AXIS_FACTOR_RANGE))
        quats = torch.randn((count, 4), generator=generator, dtype=torch.float64)  # (w, x, y, z)
        quats = quats / quats.norm(dim=1, keepdim=True)
        opacities = uniform((count,), *OPACITY_RANGE)
        colors = uniform((count, 3), 0.0, 1.0)
        target = uniform((height, width, 3), -1.0, 1.0)  # d loss / d image

        def on_device(t):
            return t.to(device=device, dtype=torch.float32).contiguous()

        self.count, self.width, self.height, self.seed = count, width, height, seed
        values = (means, quats, scales, opacities, colors)
        self.params = {name: on_device(t) for name, t in zip(PARAMETER_NAMES, values)}
        self.background = torch.ones(3, device=device)
        self.target = on_device(target)
        self.fx = self.fy = focal
        self.cx, self.cy = 0.5 * width, 0.5 * height
        self.world_to_camera = torch.eye(4, dtype=torch.float64)  # sfgs reads it on the host
        self.viewmats = torch.eye(4, device=device)[None]           # gsplat: [C, 4, 4], world to camera
        self.Ks = torch.tensor([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]],
                               device=device)[None]

    def leaves(self, requires_grad):
        return {name: t.detach().requires_grad_(requires_grad) for name, t in self.params.items()}


def render_sfgs(sfgs, scene, p, cx=None, cy=None, low_pass=True, background=None):
    """sfgs.render: image (H, W, 3), alpha (H, W), radii (N, 2)."""
    out = sfgs.render(p["means"], p["opacities"], p["colors"],
                      scene.background if background is None else background, scene.world_to_camera,
                      scene.fx, scene.fy, scene.cx if cx is None else cx, scene.cy if cy is None else cy,
                      scene.width, scene.height, scales=p["scales"], rotations=p["quats"],
                      near_plane=NEAR_PLANE, far_plane=FAR_PLANE, low_pass=low_pass)
    return out["image"], out["alpha"], out["radii"]


def render_gsplat_functions(gsplat, scene, p):
    """gsplat's 3DGS pipeline as rasterization() runs it (unpacked, classic): image (H, W, 3), alpha, radii."""
    width, height, count = scene.width, scene.height, scene.count
    radii, means2d, depths, conics, _ = gsplat.fully_fused_projection(
        p["means"], None, p["quats"], p["scales"], scene.viewmats, scene.Ks, width, height, eps2d=LOW_PASS_PX2,
        near_plane=NEAR_PLANE, far_plane=FAR_PLANE, radius_clip=0.0, packed=False, sparse_grad=False,
        calc_compensations=False, camera_model="pinhole", opacities=p["opacities"])
    view_opacities = p["opacities"].unsqueeze(0).expand(1, count)  # [C, N], as rasterization() expands them
    view_colors = p["colors"].unsqueeze(0).expand(1, count, 3)
    tiles_wide, tiles_high = math.ceil(width / TILE_SIZE), math.ceil(height / TILE_SIZE)
    _, isect_ids, flatten_ids = gsplat.isect_tiles(
        means2d, radii, depths, TILE_SIZE, tiles_wide, tiles_high, sort=True, segmented=False, packed=False,
        conics=conics, opacities=view_opacities)
    isect_offsets = gsplat.isect_offset_encode(isect_ids, 1, tiles_wide, tiles_high)
    image, alpha = gsplat.rasterize_to_pixels(
        means2d, conics, view_colors, view_opacities, width, height, TILE_SIZE, isect_offsets, flatten_ids,
        backgrounds=scene.background[None], packed=False)
    return image[0], alpha[0, ..., 0], radii[0]


def render_gsplat_rasterization(gsplat, scene, p):
    """gsplat.rasterization() itself, same settings."""
    image, alpha, meta = gsplat.rasterization(
        p["means"], p["quats"], p["scales"], p["opacities"], p["colors"], scene.viewmats, scene.Ks, scene.width,
        scene.height, near_plane=NEAR_PLANE, far_plane=FAR_PLANE, radius_clip=0.0, eps2d=LOW_PASS_PX2,
        packed=False, tile_size=TILE_SIZE, backgrounds=scene.background[None], render_mode="RGB",
        rasterize_mode="classic")
    return image[0], alpha[0, ..., 0], meta["radii"][0]


def event_ms(run):
    """Milliseconds between CUDA events recorded around run() on the current stream."""
    start, stop = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
    start.record()
    result = run()
    stop.record()
    stop.synchronize()
    del result  # freed after the stop event: deallocation is not timed
    return start.elapsed_time(stop)


def interleaved_medians(runs, rounds, warmup):
    """runs: {name: callable}. Alternates them every round (and which goes first); the median ms of each."""
    names = list(runs)
    times = {name: [] for name in names}
    for round_index in range(warmup + rounds):
        order = names if round_index % 2 == 0 else names[::-1]
        for name in order:
            elapsed = event_ms(runs[name])
            if round_index >= warmup:
                times[name].append(elapsed)
    return {name: statistics.median(values) for name, values in times.items()}


def psnr_db(a, b):
    """PSNR of a against b (peak 1), in float64; None when identical (infinite)."""
    mse = (a.double() - b.double()).pow(2).mean().item()
    return None if mse == 0.0 else 10.0 * math.log10(1.0 / mse)


def relative_error(a, b):
    norm = b.double().norm().item()
    return (a.double() - b.double()).norm().item() / norm if norm > 0 else (a.double().norm().item())


def peak_mib(run):
    """Peak CUDA memory above what was allocated before run(), in MiB."""
    torch.cuda.synchronize()
    torch.cuda.reset_peak_memory_stats()
    before = torch.cuda.memory_allocated()
    result = run()
    torch.cuda.synchronize()
    peak = torch.cuda.max_memory_allocated() - before
    del result
    return peak / 2**20


def convention_probes(sfgs, scene, p, gsplat_image):
    """sfgs's image with one convention changed at a time, against gsplat's: the variant that matches better names
    the convention in which the two differ."""
    half = 0.5
    black = torch.zeros_like(scene.background)
    # gsplat reading q as (x, y, z, w) is sfgs reading (q3, q0, q1, q2) as (w, x, y, z).
    xyzw = dict(p, quats=p["quats"][:, [3, 0, 1, 2]])
    variants = {
        "as is": lambda: render_sfgs(sfgs, scene, p),
        "principal point +0.5 px (pixel centres at integers)": lambda: render_sfgs(
            sfgs, scene, p, cx=scene.cx + half, cy=scene.cy + half),
        "principal point -0.5 px": lambda: render_sfgs(sfgs, scene, p, cx=scene.cx - half, cy=scene.cy - half),
        "quaternions read as (x, y, z, w)": lambda: render_sfgs(sfgs, scene, xyzw),
        "no low-pass": lambda: render_sfgs(sfgs, scene, p, low_pass=False),
        "black background": lambda: render_sfgs(sfgs, scene, p, background=black),
    }
    with torch.no_grad():
        return {name: psnr_db(render()[0], gsplat_image) for name, render in variants.items()}


def compare_case(sfgs, gsplat, render_gsplat, count, width, height, args):
    scene = Scene(count, width, height, args.seed, "cuda")
    target = scene.target
    renderers = {
        "sfgs": lambda p: render_sfgs(sfgs, scene, p),
        "gsplat": lambda p: render_gsplat(gsplat, scene, p),
    }
    leaves = {name: scene.leaves(requires_grad=True) for name in renderers}
    frozen = scene.leaves(requires_grad=False)

    def forward(name):
        return lambda: renderers[name](leaves[name])

    def forward_no_grad(name):
        def run():
            with torch.no_grad():
                return renderers[name](frozen)
        return run

    def forward_backward(name):
        def run():
            image = renderers[name](leaves[name])[0]
            params = [leaves[name][k] for k in PARAMETER_NAMES]
            return torch.autograd.grad(image, params, grad_outputs=target)
        return run

    started = time.time()
    timings = {}
    for label, make in (("forward", forward), ("forward_no_grad", forward_no_grad),
                        ("forward_backward", forward_backward)):
        timings[label] = interleaved_medians({name: make(name) for name in renderers}, args.rounds, args.warmup)

    with torch.no_grad():
        image_s, alpha_s, radii_s = renderers["sfgs"](frozen)
        image_g, alpha_g, radii_g = renderers["gsplat"](frozen)
    difference = (image_s.double() - image_g.double()).abs()
    both = (radii_s > 0).all(1) & (radii_g > 0).all(1)
    grads = {name: dict(zip(PARAMETER_NAMES, forward_backward(name)())) for name in renderers}
    result = {
        "count": count, "width": width, "height": height, "seed": args.seed,
        "ms": {label: {name: round(ms, 4) for name, ms in t.items()} for label, t in timings.items()},
        "ratio_sfgs_over_gsplat": {label: round(t["sfgs"] / t["gsplat"], 4) for label, t in timings.items()},
        "psnr_image_db": psnr_db(image_s, image_g),
        "psnr_alpha_db": psnr_db(alpha_s, alpha_g),
        "max_abs_image_difference": difference.max().item(),
        "pixels_differing_over_1_255": int((difference.amax(-1) > 1.0 / 255.0).sum().item()),
        "projected": {"sfgs": int((radii_s > 0).all(1).sum().item()), "gsplat": int((radii_g > 0).all(1).sum().item()),
                      "both": int(both.sum().item())},
        "radii_differing_where_both_projected": int((radii_s[both] != radii_g[both]).any(1).sum().item()),
        "gradient_relative_l2_error": {
            k: relative_error(grads["sfgs"][k], grads["gsplat"][k]) for k in PARAMETER_NAMES},
        "peak_mib_forward_backward": {name: round(peak_mib(forward_backward(name)), 1) for name in renderers},
        "seconds": round(time.time() - started, 1),
    }
    psnr = result["psnr_image_db"]
    if args.probe or (psnr is not None and psnr < PSNR_TARGET_DB):
        result["convention_probes_psnr_db"] = convention_probes(sfgs, scene, frozen, image_g)
    return result


def print_case(r):
    def fmt_db(v):
        return "identical" if v is None else f"{v:.1f} dB"

    print(f"\n{r['count']:,} Gaussians, {r['width']}x{r['height']} (median of the timed rounds, CUDA events):")
    print(f"  {'':18s} {'sfgs ms':>10s} {'gsplat ms':>10s} {'sfgs/gsplat':>12s}")
    for label, t in r["ms"].items():
        print(f"  {label:18s} {t['sfgs']:10.3f} {t['gsplat']:10.3f} {r['ratio_sfgs_over_gsplat'][label]:12.3f}")
    print(f"  image PSNR sfgs vs gsplat {fmt_db(r['psnr_image_db'])} (target >= {PSNR_TARGET_DB:.0f} dB), alpha "
          f"{fmt_db(r['psnr_alpha_db'])}; largest pixel difference {r['max_abs_image_difference']:.3g}, "
          f"{r['pixels_differing_over_1_255']} pixels differ by more than 1/255")
    p = r["projected"]
    print(f"  projected Gaussians: sfgs {p['sfgs']:,}, gsplat {p['gsplat']:,}, both {p['both']:,}; radius differs for "
          f"{r['radii_differing_where_both_projected']:,} of those")
    print("  gradient relative L2 error (sfgs vs gsplat): " +
          ", ".join(f"{k} {v:.2e}" for k, v in r["gradient_relative_l2_error"].items()))
    print(f"  peak memory of forward + backward: sfgs {r['peak_mib_forward_backward']['sfgs']} MiB, gsplat "
          f"{r['peak_mib_forward_backward']['gsplat']} MiB")
    if "convention_probes_psnr_db" in r:
        print("  sfgs with one convention changed, PSNR against gsplat (the best match names the difference):")
        for name, value in r["convention_probes_psnr_db"].items():
            print(f"    {name:52s} {fmt_db(value)}")


def parse_cases(text):
    cases = []
    for item in filter(None, (s.strip() for s in text.split(","))):
        if item in NAMED_CASES:
            cases.append(NAMED_CASES[item])
            continue
        try:
            count, size = item.split(":")
            width, height = size.lower().split("x")
            cases.append((int(count), int(width), int(height)))
        except ValueError:
            raise SystemExit(f"gsplat_compare: unknown case '{item}': use one of {', '.join(NAMED_CASES)} "
                             "or COUNT:WIDTHxHEIGHT")
    return cases


def cpu_check(seed):
    """The sfgs half on the CPU: a small scene (2,000 Gaussians, 80x120: the 800x1200 framing at a tenth of the
    focal length), rendered and differentiated."""
    import sfgs
    count, width, height = 2000, 80, 120
    scene = Scene(count, width, height, seed, "cpu", focal=FOCAL_PX / 10)
    p = scene.leaves(requires_grad=True)
    image, alpha, radii = render_sfgs(sfgs, scene, p)
    grads = torch.autograd.grad(image, [p[k] for k in PARAMETER_NAMES], grad_outputs=scene.target)
    covered = (alpha > 0.5).float().mean().item()
    print(f"cpu check: {count} Gaussians at {width}x{height} with sfgs on the CPU: image {tuple(image.shape)}, "
          f"{int((radii > 0).all(1).sum())} projected, {100 * covered:.1f} % of pixels with alpha > 0.5, "
          f"gradient norms " + ", ".join(f"{k} {g.norm():.3g}" for k, g in zip(PARAMETER_NAMES, grads)))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    parser.add_argument("--cases", default=",".join(NAMED_CASES),
                        help="comma-separated: " + ", ".join(NAMED_CASES) + " or COUNT:WIDTHxHEIGHT")
    parser.add_argument("--rounds", type=int, default=50, help="timed rounds per measure (default 50)")
    parser.add_argument("--warmup", type=int, default=10, help="untimed rounds first (default 10)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", metavar="OUT", help="write the results as JSON to OUT")
    parser.add_argument("--gsplat-api", choices=("functions", "rasterization"), default="functions",
                        help="gsplat's functions as rasterization() calls them (default) or rasterization() itself")
    parser.add_argument("--probe", action="store_true",
                        help="always run the convention probes (otherwise only when PSNR < 100 dB)")
    parser.add_argument("--cpu-check", action="store_true",
                        help="render a small scene with sfgs on the CPU only and exit (no CUDA, no gsplat needed)")
    args = parser.parse_args()
    if args.rounds < 1 or args.warmup < 0:
        parser.error("--rounds must be >= 1 and --warmup >= 0")
    cases = parse_cases(args.cases)

    try:
        import sfgs
    except ImportError as error:
        sys.exit(f"gsplat_compare: cannot import sfgs ({error}); put the build's module folder on PYTHONPATH "
                 "(e.g. PYTHONPATH=build/python)")
    if args.cpu_check:
        cpu_check(args.seed)
        return
    if not torch.cuda.is_available():
        sys.exit("gsplat_compare: no CUDA device visible to torch; this benchmark needs a GPU "
                 "(--cpu-check runs the sfgs half on the CPU)")
    if not sfgs.cuda_available():
        sys.exit("gsplat_compare: this sfgs module was built without CUDA (configure with -DSFGS_CUDA=ON)")
    try:
        import gsplat
    except ImportError as error:
        sys.exit(f"gsplat_compare: cannot import gsplat ({error}); install gsplat 1.6.0 or put a build of it "
                 "on PYTHONPATH")
    render_gsplat = render_gsplat_rasterization if args.gsplat_api == "rasterization" else render_gsplat_functions

    build_info_path = os.path.join(os.path.dirname(gsplat.__file__), "sfgs_bench_build.json")
    build_info = json.load(open(build_info_path)) if os.path.exists(build_info_path) else None
    header = {
        "device": torch.cuda.get_device_name(), "torch": torch.__version__, "torch_cuda": torch.version.cuda,
        "visible_gpus": torch.cuda.device_count(), "sfgs_module": sfgs.__file__,
        "gsplat_version": gsplat.__version__, "gsplat_module": gsplat.__file__, "gsplat_build": build_info,
        "gsplat_api": args.gsplat_api, "rounds": args.rounds, "warmup": args.warmup,
    }
    print(f"gsplat_compare: {header['device']}, torch {header['torch']} (CUDA {header['torch_cuda']}), "
          f"{header['visible_gpus']} visible GPU(s); sfgs {sfgs.__file__}; gsplat {gsplat.__version__} "
          f"({gsplat.__file__}, {args.gsplat_api}); {args.rounds} rounds after {args.warmup} warm-up rounds",
          flush=True)
    results = []
    for count, width, height in cases:
        result = compare_case(sfgs, gsplat, render_gsplat, count, width, height, args)
        print_case(result)
        sys.stdout.flush()
        results.append(result)
        torch.cuda.empty_cache()
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"setup": header, "cases": results}, f, indent=1)
        print(f"\nwrote {args.json}")


if __name__ == "__main__":
    main()
