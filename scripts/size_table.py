#!/usr/bin/env python3
"""Run time against error over model sizes (device_check.sh step `sizes`; docs/performance.md).

Usage: size_table.py OUT_DIR VARIANT...
  For each variant NAME it reads OUT_DIR/log-NAME-novel.jsonl (the run's JSON-lines log: its Gaussians, the
  validation PSNR against the training seconds), OUT_DIR/metrics-NAME-novel-test.json (the final test metrics on new
  motions) and OUT_DIR/frame-NAME.log (bench_animate --run: the graph frame at 800 x 1200), and prints a Markdown
  table: Gaussians, ms per training step, seconds to reach each PSNR of THRESHOLDS on validation, final validation
  and test PSNR / SSIM / LPIPS, and frames per second.
"""
import json
import re
import sys

THRESHOLDS = (32.0, 34.0, 36.0)  # validation PSNR (dB) whose first crossing is timed


def read_log(path):
    gaussians, validations, steps = None, [], None
    with open(path) as f:
        for line in f:
            event = json.loads(line)
            if event.get("event") == "start":
                gaussians = event.get("gaussians")
            elif event.get("event") == "validation" and "val_psnr" in event:
                validations.append((event["training_seconds"], event["val_psnr"], event["iteration"]))
            elif event.get("event") == "end":
                steps = (event["training_seconds"], event["iteration"])
    return gaussians, validations, steps


def first_crossing(validations, threshold):
    for seconds, psnr, _ in validations:
        if psnr >= threshold:
            return f"{seconds:.0f} s"
    return "-"


def frame_ms(path):
    try:
        with open(path) as f:
            for line in f:
                m = re.search(r"graph frame: ([0-9.]+) ms", line)
                if m:
                    return float(m.group(1))
    except OSError:
        pass
    return None


def main(out, variants):
    header = ["variant", "Gaussians", "ms / step"] + [f"to {t:.0f} dB (val)" for t in THRESHOLDS]
    header += ["val PSNR", "test PSNR", "test SSIM", "test LPIPS", "frame 800x1200", "frames/s"]
    print("| " + " | ".join(header) + " |")
    print("|" + "---|" * len(header))
    for name in variants:
        gaussians, validations, steps = read_log(f"{out}/log-{name}-novel.jsonl")
        with open(f"{out}/metrics-{name}-novel-test.json") as f:
            test = json.load(f)
        ms = frame_ms(f"{out}/frame-{name}.log")
        row = [name, f"{gaussians:,}" if gaussians else "?",
               f"{1000 * steps[0] / steps[1]:.1f}" if steps else "?"]
        row += [first_crossing(validations, t) for t in THRESHOLDS]
        row += [f"{validations[-1][1]:.2f}" if validations else "-", f"{test['psnr']:.2f}", f"{test['ssim']:.4f}",
                f"{test['lpips']:.4f}" if "lpips" in test else "-",
                f"{ms:.2f} ms" if ms else "-", f"{1000 / ms:.0f}" if ms else "-"]
        print("| " + " | ".join(row) + " |")


if __name__ == "__main__":
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    main(sys.argv[1], sys.argv[2:])
