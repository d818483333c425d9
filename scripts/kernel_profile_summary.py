#!/usr/bin/env python3
"""Per-stage summary of an Nsight Compute profile of one frame or training step (device_check.sh stage-profile).

Usage: kernel_profile_summary.py KERNELS.csv
  KERNELS.csv: `ncu --import R --csv --page raw` of a profile taken with `--nvtx` and the metrics
  gpu__time_duration.sum, dram__bytes_read.sum and dram__bytes_write.sum. A kernel's stage is the innermost NVTX
  range of the thread that launched it (the benchmark's StageScopes, bench/profiled_range.h).
Prints per stage: kernels, GPU time (sum of kernel durations), DRAM bytes; then the costliest kernels.
"""
import collections
import csv
import re
import sys

SCALE = {"ns": 1e-3, "nsecond": 1e-3, "us": 1.0, "usecond": 1.0, "ms": 1e3, "msecond": 1e3, "s": 1e6, "second": 1e6,
         "byte": 1e-6, "Kbyte": 1e-3, "Mbyte": 1.0, "Gbyte": 1e3}
NVTX_COLUMN = "thread Domain:Push/Pop_Range"


def table(path):
    with open(path, newline="") as f:
        rows = list(csv.reader(line for line in f if not line.startswith("==")))
    at = next(i for i, r in enumerate(rows) if "Kernel Name" in r)
    header, units = rows[at], rows[at + 1]
    return header, units, [r for r in rows[at + 2:] if len(r) == len(header)]


def main(path):
    header, units, rows = table(path)
    nvtx = next((i for i, name in enumerate(header) if name.startswith(NVTX_COLUMN)), None)
    name_at = header.index("Kernel Name")

    def value(row, key):  # microseconds or megabytes
        i = header.index(key)
        return float(row[i].replace(",", "") or 0) * SCALE.get(units[i], 1.0)

    per_stage = collections.OrderedDict()
    per_kernel = collections.defaultdict(lambda: [0, 0.0])
    total = [0, 0.0, 0.0]
    for r in rows:
        # Each range is "<default domain>:MESSAGE" and six ":"-separated payload fields; messages may hold ":".
        ranges = re.findall(r'"<default domain>:(.*?)(?::[^:"]*){6}"', r[nvtx]) if nvtx is not None else []
        stage = " / ".join(ranges[-2:]) if ranges else "(no stage: another thread, e.g. autograd's backward)"
        us = value(r, "gpu__time_duration.sum")
        megabytes = value(r, "dram__bytes_read.sum") + value(r, "dram__bytes_write.sum")
        for e in (per_stage.setdefault(stage, [0, 0.0, 0.0]), total):
            e[0] += 1
            e[1] += us
            e[2] += megabytes
        kernel = re.sub(r"^void ", "", r[name_at]).split("(")[0][:100]
        per_kernel[kernel][0] += 1
        per_kernel[kernel][1] += us
    print(f"{'stage':70s} {'kernels':>8s} {'GPU us':>10s} {'DRAM MB':>9s}")
    for stage, (count, us, megabytes) in per_stage.items():
        print(f"{stage[:70]:70s} {count:8d} {us:10.1f} {megabytes:9.1f}")
    print(f"{'total':70s} {total[0]:8d} {total[1]:10.1f} {total[2]:9.1f}")
    print("\ncostliest kernels (launches, GPU us):")
    for kernel, (count, us) in sorted(per_kernel.items(), key=lambda kv: -kv[1][1])[:30]:
        print(f"  {count:6d} {us:10.1f}  {kernel}")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    main(sys.argv[1])
