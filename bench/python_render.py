"""Avatar.render from Python on a trained avatar, as a user calls it: the median and 90th-percentile milliseconds
of a frame (pose moving, camera circling the body's centre, the image returned as a CUDA tensor), for new-motion
frames (no time) and replayed training frames (with their time), after a warm-up that holds the graphs'
recordings; a batch of B frames in one call against B single calls (the same poses and cameras); and the fast frame's
PSNR against the eager, differentiable render of the same pose (without and with a time).

Usage: python3 bench/python_render.py RUN [--frames 200] [--batch 8] [--device cuda]
"""
import argparse
import math
import statistics
import time

import torch

import sfgs


def circling(camera, centre, angle):
    """The dataset camera turned about the vertical axis through the body's centre (the body stays in view)."""
    view = camera["world_to_camera"].double()
    c, s = math.cos(angle), math.sin(angle)
    turn = torch.tensor([[c, 0, s, 0], [0, 1, 0, 0], [-s, 0, c, 0], [0, 0, 0, 1]], dtype=torch.float64)
    to_centre, back = torch.eye(4, dtype=torch.float64), torch.eye(4, dtype=torch.float64)
    to_centre[:3, 3], back[:3, 3] = centre, -centre
    moved = dict(camera)
    moved["world_to_camera"] = view @ to_centre @ turn @ back
    return moved


def body_centre(avatar, pose):
    """The centre of the posed avatar's bounding box (the cameras circle it)."""
    means = avatar.gaussians({k: v for k, v in pose.items() if k != "time"})["means"].double().cpu()
    return (means.min(0).values + means.max(0).values) / 2


def time_frames(avatar, camera, pose, frames, timed):
    base = pose.get("body_pose", torch.zeros(21, 3)).double()
    centre = body_centre(avatar, pose)
    times, coverage = [], []
    for k in range(frames + 10):
        p = dict(pose)
        p["body_pose"] = base + 0.1 * math.sin(k / 10.0)
        if timed:
            p["time"] = max(-1.0, min(1.0, math.sin(k / 30.0)))
        else:
            p.pop("time", None)
        cam = circling(camera, centre, 0.02 * k)
        start = time.perf_counter()
        out = avatar.render(cam, p)
        image = out["image"]
        if image.is_cuda:
            torch.cuda.synchronize()
        if k >= 10:
            times.append(1e3 * (time.perf_counter() - start))
            coverage.append(float((out["alpha"] > 0.5).float().mean()))
    times.sort()
    return statistics.median(times), times[int(0.9 * (len(times) - 1))], image, statistics.mean(coverage)


def time_batch(avatar, camera, pose, batch, rounds):
    """Median milliseconds of B single calls and of one call with B poses and cameras (new-motion frames), and the
    largest difference between the two results."""
    base = pose.get("body_pose", torch.zeros(21, 3)).double()
    centre = body_centre(avatar, pose)
    poses, cameras = [], []
    for k in range(batch):
        p = {k2: v for k2, v in pose.items() if k2 != "time"}
        p["body_pose"] = base + 0.1 * math.sin(k / 3.0)
        poses.append(p)
        cameras.append(circling(camera, centre, 0.3 * k))
    singles, batched = [], []
    for r in range(rounds + 5):
        start = time.perf_counter()
        one = [avatar.render(c, p)["image"] for c, p in zip(cameras, poses)]
        torch.cuda.synchronize()
        middle = time.perf_counter()
        many = avatar.render(cameras, poses)["image"]
        torch.cuda.synchronize()
        end = time.perf_counter()
        if r >= 5:
            singles.append(1e3 * (middle - start))
            batched.append(1e3 * (end - middle))
    difference = (torch.stack(one) - many).abs().max().item()
    return statistics.median(singles), statistics.median(batched), difference


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run")
    parser.add_argument("--frames", type=int, default=200)
    parser.add_argument("--batch", type=int, default=8)
    parser.add_argument("--device", default="cuda")
    args = parser.parse_args()
    avatar = sfgs.load_avatar(args.run, device=args.device)
    frame = avatar.frame(0)
    camera, pose = frame["camera"], frame["pose"]
    print(f"python Avatar.render: {avatar.gaussian_count} Gaussians, {camera['width']}x{camera['height']}, "
          f"{args.frames} frames, device {args.device}")
    with torch.no_grad():
        for timed in (False, True):
            median, p90, image, coverage = time_frames(avatar, camera, pose, args.frames, timed)
            kind = "replayed (time)" if timed else "new motion"
            print(f"  {kind:16s} median {median:.3f} ms  p90 {p90:.3f} ms  ({image.device}, {tuple(image.shape)}; "
                  f"the body covers {100 * coverage:.1f} % of the image)")
        if args.device == "cuda" and args.batch > 0:
            singles, batched, difference = time_batch(avatar, camera, pose, args.batch, 50)
            print(f"  {args.batch} single calls {singles:.3f} ms, one batch of {args.batch} {batched:.3f} ms: "
                  f"{singles / batched:.2f}x ({batched / args.batch:.3f} ms a frame; results differ by {difference:.1e})")
    # The fast frame against the eager render of the same pose (a pose that asks for a gradient takes that path, in
    # float32; the fast frame's networks take TF32 products), without and with the frame's time.
    for timed in (False, True):
        fast_pose = {k: v for k, v in pose.items() if k != "time"}
        if timed:
            fast_pose["time"] = 0.25
        fast = avatar.render(camera, fast_pose)["image"]
        eager_pose = dict(fast_pose)
        eager_pose["body_pose"] = pose.get("body_pose", torch.zeros(21, 3)).clone().float().requires_grad_(True)
        eager = avatar.render(camera, eager_pose)["image"].detach()
        kind = "replayed (time)" if timed else "new motion"
        # Renders are not clamped (shading may take a colour past 1), so the PSNR is taken on the raw values.
        mse = ((fast.cpu().double() - eager.cpu().double()) ** 2).mean().item()
        print(f"  fast vs eager render, {kind}: PSNR {10 * math.log10(1 / mse) if mse > 0 else math.inf:.1f} dB")


if __name__ == "__main__":
    main()
