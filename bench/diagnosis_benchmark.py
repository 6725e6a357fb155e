#!/usr/bin/env python3
"""Benchmark of ``webline diagnose`` (issue #4, "Proof"): writes
bench/diagnosis_results.json and bench/diagnosis_results.md and prints the table.

    python bench/diagnosis_benchmark.py [--family own|independent|both] [--cases N] [--seed S] [--out DIR] [--quick] [--jobs J]

Same as ``webline diagnose-bench --results bench/diagnosis_results.json``; the
case files (blind inputs, truth, reports) go to --out (default
out/diagnose-bench; --quick writes its results there too, not to bench/). Default: both
families side by side. The own family's 24 cases take about 20-30 min on 2 cores; the
independent family's 60 s records (1-3 per case) cost the diagnosis about 6-18 times as
much per case while it co-simulates (hours; --family own or --cases N to shorten).
Generators and scorer: diagnosis/benchmark.py, diagnosis/benchmark_independent.py.
"""
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from webline.diagnosis import benchmark_cmd  # noqa: E402


def main(argv=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    if "--quick" not in argv and not any(a == "--results" or a.startswith("--results=") for a in argv):
        argv += ["--results", str(ROOT / "bench" / "diagnosis_results.json")]
    return benchmark_cmd.main(argv)


if __name__ == "__main__":
    sys.exit(main())
