"""scripts/bench_guard.py on synthetic bench_splat_cuda output (Python's standard library only; CTest: bench_guard)."""
import contextlib
import io
import json
import sys
import tempfile
import unittest
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "scripts"))
import bench_guard  # noqa: E402

BASELINE = {
    "tolerance": 0.10,
    "gsplat_reference": {"source": "synthetic", "fwd_ms": 0.630, "fwd_bwd_ms": None},
    "cases": {"167390@800x1200": {"fwd_ms": 0.330, "fwd_bwd_ms": 1.000, "blend_ms": None}},
}


def bench_log(fwd_ms, fwd_bwd_ms=1.0, n=167390):
    return ("device: NVIDIA H200 (132 SMs), median of 50 runs after 10 warm-ups, float32\n"
            "bench-case n=10000 image=800x1200 fwd_ms=0.1000 fwd_bwd_ms=0.3000 blend_ms=0.0300\n"
            f"bench-case n={n} image=800x1200 fwd_ms={fwd_ms:.4f} fwd_bwd_ms={fwd_bwd_ms:.4f} blend_ms=0.1000\n")


class BenchGuardTest(unittest.TestCase):
    def setUp(self):
        self.folder = tempfile.TemporaryDirectory()
        self.addCleanup(self.folder.cleanup)
        self.baseline = Path(self.folder.name) / "baseline.json"
        self.baseline.write_text(json.dumps(BASELINE))

    def guard(self, log_text, *extra):
        log = Path(self.folder.name) / "bench.log"
        log.write_text(log_text)
        output = io.StringIO()
        with contextlib.redirect_stdout(output), contextlib.redirect_stderr(io.StringIO()):
            status = bench_guard.main([str(log), "--baseline", str(self.baseline), *extra])
        return status, output.getvalue()

    def test_passes_within_ten_percent(self):
        status, output = self.guard(bench_log(0.330 * 1.09, 1.09))
        self.assertEqual(status, 0, output)
        self.assertIn("within the baseline", output)

    def test_fails_at_eleven_percent(self):
        self.assertEqual(self.guard(bench_log(0.330 * 1.11))[0], 1)
        self.assertEqual(self.guard(bench_log(0.330, 1.11))[0], 1)

    def test_a_faster_run_passes_and_an_unbaselined_figure_is_not_judged(self):
        status, output = self.guard(bench_log(0.2, 0.5))
        self.assertEqual(status, 0, output)
        self.assertIn("no baseline", output)

    def test_prints_the_gsplat_comparable_case(self):
        _, output = self.guard(bench_log(0.315))
        self.assertIn("sfgs 2.00x gsplat's speed", output)

    def test_a_missing_case_fails_and_no_cases_is_an_error(self):
        self.assertEqual(self.guard(bench_log(0.330, n=200000))[0], 1)
        self.assertEqual(self.guard("bench_splat_cuda: no CUDA device\n")[0], 2)

    def test_record_takes_the_measured_figures(self):
        self.assertEqual(self.guard(bench_log(0.3))[0], 0)
        self.assertEqual(self.guard(bench_log(0.5), "--record")[0], 0)
        recorded = json.loads(self.baseline.read_text())
        self.assertEqual(recorded["cases"]["167390@800x1200"]["fwd_ms"], 0.5)
        self.assertEqual(recorded["gsplat_reference"]["fwd_ms"], 0.630)
        self.assertEqual(self.guard(bench_log(0.5 * 1.11))[0], 1)


if __name__ == "__main__":
    unittest.main()
