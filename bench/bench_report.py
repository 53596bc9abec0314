"""Time `virheo report` on the demo run, the laws' evidence included (target: within 2 minutes on 2 cores).

    python bench/bench_report.py [--demo DIR] [--repeats 1]

Runs `virheo demo --out DIR` once (reused when DIR/result.json exists), then `virheo report` on a fresh copy of DIR
(its store included, without the report's own files) ``--repeats`` times, and prints each wall time, the phases'
share of it as the report's progress lines time them, and the verdicts.
"""
from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from measured import how_measured  # noqa: E402  (bench/ is this script's folder)

TARGET_S = 120.0
PHASES = ("discretisation error", "best fit on its face", "emulator", "posterior check", "laws' check", "the posterior",
          "evidence of", "next setup by simulated information (", "report:")
REPORT_FILES = ("posterior.json", "posterior.h5", "posterior_samples.npy", "posterior_log_prob.npy",
                "posterior_draws.npy", "posterior_training.npz", "report")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--demo", default=os.path.expanduser("~/.cache/virheometry/bench_report_demo"))
    p.add_argument("--repeats", type=int, default=1)
    args = p.parse_args(argv)
    demo = Path(args.demo)
    cli = [sys.executable, "-m", "studies.cli"]
    if not (demo / "result.json").exists():
        subprocess.run([*cli, "demo", "--out", str(demo), "--quiet"], check=True)
    print(f"measured: {how_measured()}")
    for k in range(args.repeats):
        with tempfile.TemporaryDirectory() as tmp:
            run = Path(tmp) / "run"
            shutil.copytree(demo, run, ignore=shutil.ignore_patterns(*REPORT_FILES))
            t0 = time.perf_counter()
            timeline = []  # (seconds since the start, progress line) as the report prints them
            with subprocess.Popen([*cli, "report", str(run)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                  text=True, env=dict(os.environ, PYTHONUNBUFFERED="1")) as proc:
                for line in proc.stdout:
                    timeline.append((time.perf_counter() - t0, line.rstrip()))
                err = proc.stderr.read()
            wall = time.perf_counter() - t0
            if proc.returncode:
                print(err, file=sys.stderr)
                return proc.returncode
            lines = [line for _, line in timeline]
            verdicts = [line for line in lines if line.startswith(("yield stress", "shear thinning"))]
            print(f"virheo report on the demo run, repeat {k + 1}: {wall:.0f} s (target {TARGET_S:.0f} s: "
                  f"{'met' if wall <= TARGET_S else 'NOT met'})")
            for line in verdicts:
                print(f"  {line}")
            print("  phases (seconds at which the report printed each progress line):")
            for t, line in timeline:
                if line.startswith(PHASES) or line.partition(": ")[2].startswith(PHASES):  # "bingham: best fit ..."
                    print(f"  {t:6.1f}  {line[:110]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
