#!/usr/bin/env python3
"""Regression guard of the splatting benchmark: compares bench_splat_cuda's figures with a baseline file.

Reads the "bench-case" lines bench_splat_cuda prints last (one per workload: forward, forward + backward and forward
blend milliseconds), prints each baselined figure beside its baseline with the ratio, and the case comparable with
gsplat (issue 40: 167,390 Gaussians, 800x1200) against the gsplat reference in the baseline file. Exits 1 when a
figure is slower than its baseline by more than the tolerance (the file's, default 10%), or when a baselined case is
missing from the output; 2 on unreadable input. Figures whose baseline is null are shown, not judged.

  python3 scripts/bench_guard.py BENCH_LOG [--baseline bench/baselines/splat_h200.json]
  python3 scripts/bench_guard.py BENCH_LOG --record   rewrites the baseline's figures from BENCH_LOG
"""
import argparse
import json
import re
import sys
from pathlib import Path

DEFAULT_BASELINE = Path(__file__).resolve().parent.parent / "bench" / "baselines" / "splat_h200.json"
DEFAULT_TOLERANCE = 0.10
METRICS = ("fwd_ms", "fwd_bwd_ms", "blend_ms")
GSPLAT_CASE = "167390@800x1200"
CASE_LINE = re.compile(
    r"^bench-case n=(\d+) image=(\d+)x(\d+) fwd_ms=([\d.]+) fwd_bwd_ms=([\d.]+) blend_ms=([\d.]+)\s*$")


def parse_cases(text):
    """{"N@WxH": {metric: ms}} from the bench-case lines of a bench_splat_cuda log."""
    cases = {}
    for line in text.splitlines():
        m = CASE_LINE.match(line.strip())
        if m:
            n, w, h, fwd, fwd_bwd, blend = m.groups()
            cases[f"{n}@{w}x{h}"] = {"fwd_ms": float(fwd), "fwd_bwd_ms": float(fwd_bwd), "blend_ms": float(blend)}
    return cases


def compare(cases, baseline):
    """Rows (case, metric, baseline, now, ratio, verdict) and whether every judged figure is within the tolerance."""
    tolerance = float(baseline.get("tolerance", DEFAULT_TOLERANCE))
    rows, ok = [], True
    for name, figures in baseline.get("cases", {}).items():
        measured = cases.get(name)
        for metric in METRICS:
            reference = figures.get(metric)
            if measured is None:
                if reference is not None:
                    rows.append((name, metric, reference, None, None, "MISSING"))
                    ok = False
                continue
            now = measured[metric]
            if reference is None:
                rows.append((name, metric, None, now, None, "no baseline"))
                continue
            ratio = now / reference
            slower = ratio > 1.0 + tolerance
            ok = ok and not slower
            rows.append((name, metric, reference, now, ratio, f"SLOWER than +{tolerance:.0%}" if slower else "ok"))
    return rows, ok


def format_ms(value):
    return "-" if value is None else f"{value:.4f}"


def print_table(rows):
    print(f"{'case':<18} {'figure':<11} {'baseline':>9} {'now':>9} {'now/base':>9}  verdict")
    for name, metric, reference, now, ratio, verdict in rows:
        ratio_text = "-" if ratio is None else f"{ratio:.3f}"
        print(f"{name:<18} {metric:<11} {format_ms(reference):>9} {format_ms(now):>9} {ratio_text:>9}  {verdict}")


def print_gsplat_case(cases, baseline):
    reference = baseline.get("gsplat_reference", {})
    measured = cases.get(GSPLAT_CASE)
    print(f"\ngsplat-comparable case (167,390 Gaussians, 800x1200; {reference.get('source', 'no gsplat reference')}):")
    if measured is None:
        print("  not in the benchmark output")
        return
    for metric, label, target in (("fwd_ms", "forward", 1.7), ("fwd_bwd_ms", "forward + backward", 2.5)):
        gsplat = reference.get(metric)
        line = f"  {label}: sfgs {measured[metric]:.4f} ms"
        if gsplat is None:
            line += ", gsplat figure not recorded"
        else:
            ratio = gsplat / measured[metric]
            line += (f", gsplat {gsplat:.4f} ms: sfgs {ratio:.2f}x gsplat's speed (target {target}x; an indication: "
                     "the gsplat figure is of the reference's scene, which bench/gsplat_compare.py renders with both)")
        print(line)


def record(cases, baseline):
    """The baseline with every case's figures replaced by the measured ones (gsplat reference and tolerance kept)."""
    updated = dict(baseline)
    updated["cases"] = {name: dict(figures) for name, figures in sorted(cases.items())}
    updated.pop("provisional", None)
    return updated


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("bench_log", type=Path, help="bench_splat_cuda's output")
    parser.add_argument("--baseline", type=Path, default=DEFAULT_BASELINE)
    parser.add_argument("--record", action="store_true", help="rewrite the baseline from the log instead of judging")
    args = parser.parse_args(argv)
    try:
        cases = parse_cases(args.bench_log.read_text())
        baseline = json.loads(args.baseline.read_text())
    except (OSError, ValueError) as error:
        print(f"bench_guard: {error}", file=sys.stderr)
        return 2
    if not cases:
        print(f"bench_guard: no bench-case lines in {args.bench_log}", file=sys.stderr)
        return 2
    if args.record:
        args.baseline.write_text(json.dumps(record(cases, baseline), indent=2) + "\n")
        print(f"bench_guard: recorded {len(cases)} cases in {args.baseline}")
        return 0
    if baseline.get("provisional"):
        print(f"baseline {args.baseline.name}: PROVISIONAL ({baseline['provisional']})")
    rows, ok = compare(cases, baseline)
    print_table(rows)
    print_gsplat_case(cases, baseline)
    print("\nbench_guard: " + ("within the baseline" if ok else "REGRESSION (or a baselined case missing)"))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
