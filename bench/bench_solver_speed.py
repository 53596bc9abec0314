"""CPU solver speed, old and new side by side in one process, one Taichi thread.

The old solver is the ``mpm`` package of a git revision (default ``main``), extracted with ``git archive``
into a temporary package ``mpm_base``; the new one is this checkout's ``mpm``. Both run the same
evaluations alternately (so that the load of a shared machine hits both alike) and the script prints
particle-steps per CPU-second (process CPU time of the simulation; silhouettes rendered afterwards), their ratio, and
how far the new results are from the old (silhouette IoU through ``Camera.default()``, runout):

    python bench/bench_solver_speed.py                         # 30 x 20 mm at 1.5 and 5 mm, 2 rounds
    python bench/bench_solver_speed.py --cells 1.5 --rounds 3 --base main~3
    python bench/bench_solver_speed.py --dim 2 --cells 0.75 2    # plane strain
"""
import argparse
import os
import re
import subprocess
import sys
import tarfile
import tempfile
import time
from io import BytesIO
from pathlib import Path
from types import SimpleNamespace as NS

os.environ["VIRHEO_THREADS"] = "1"  # before Taichi starts: one thread, as batch evaluation runs
ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402


def extract_base(rev: str, into: Path) -> str:
    """Write ``rev``'s mpm package to ``into/mpm_base`` with its imports renamed; returns the commit."""
    commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", rev], check=True,
                            capture_output=True, text=True).stdout.strip()
    blob = subprocess.run(["git", "-C", str(ROOT), "archive", rev, "mpm"], check=True, capture_output=True).stdout
    with tarfile.open(fileobj=BytesIO(blob)) as tar:
        tar.extractall(into, filter="data")
    pkg = into / "mpm"
    for f in pkg.rglob("*.py"):
        text = f.read_text()
        text = re.sub(r"\bfrom mpm(\.|\s)", r"from mpm_base\1", text)
        text = re.sub(r"\bimport mpm(\.|\s|$)", r"import mpm_base\1", text, flags=re.M)
        text = text.replace('"mpm.', '"mpm_base.')
        f.write_text(text)
    pkg.rename(into / "mpm_base")
    return commit


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", default="main", help="git revision of the old solver (default main)")
    ap.add_argument("--cells", type=float, nargs="+", default=[1.5, 5.0], help="cell widths in mm")
    ap.add_argument("--setup", default="30x20", help="W x H in mm")
    ap.add_argument("--material", default="1,0.8,5", help="eta,n,sigma_y (Pa s^n, -, Pa)")
    ap.add_argument("--dim", type=int, default=3, help="3, or 2 for plane strain")
    ap.add_argument("--rounds", type=int, default=2, help="old/new pairs per cell width")
    a = ap.parse_args(argv)
    w, h = (float(v) for v in a.setup.lower().split("x"))
    eta, n, sy = (float(v) for v in a.material.split(","))
    material, setup = NS(eta=eta, n=n, sigma_y=sy), NS(width_mm=w, height_mm=h)

    tmp = tempfile.mkdtemp(prefix="virheo-base-")
    commit = extract_base(a.base, Path(tmp))
    sys.path.insert(0, tmp)
    import mpm  # noqa: E402
    import mpm_base  # noqa: E402
    from mpm.camera import Camera  # noqa: E402
    from mpm.loss import iou  # noqa: E402
    from mpm.silhouette import render  # noqa: E402

    cam = Camera.default()
    solvers = (("old", mpm_base.simulate), ("new", mpm.simulate))
    print(f"# old = {a.base} ({commit}), new = this checkout; one thread; {a.dim}D; material {a.material}, "
          f"setup {a.setup} mm, "
          f"density 1000; load {os.getloadavg()[0]:.1f}")
    for name, sim in solvers:  # compile or load the kernels outside the timings
        t = time.perf_counter()
        sim(material, setup, density=1000.0, cell_mm=6.0, dim=a.dim)
        print(f"# {name}: first call (kernels compiled or loaded from the cache) {time.perf_counter() - t:.1f} s",
              flush=True)
    print(f"{'cell mm':>7} {'run':>4} {'particles':>9} {'steps':>5} {'cpu s':>7} {'wall s':>7} {'Mpstep/cpu-s':>12}")
    for cell in a.cells:
        rates = {"old": [], "new": []}
        last = {}
        for _ in range(a.rounds):
            for name, sim in solvers:
                c0 = time.process_time()
                s = sim(material, setup, density=1000.0, cell_mm=cell, dim=a.dim)  # no camera: simulation only
                cpu = time.process_time() - c0
                ps = s.stats["n_particles"] * s.stats["steps"]
                rates[name].append(ps / cpu / 1e6)
                last[name] = s
                print(f"{cell:7.2f} {name:>4} {s.stats['n_particles']:9d} {s.stats['steps']:5d} {cpu:7.2f} "
                      f"{s.stats['wall_s']:7.2f} {ps / cpu / 1e6:12.3f}", flush=True)
        sil = {k: [render(f, cam, spacing_m=v.stats["spacing_m"]) for f in v.frames] for k, v in last.items()}
        ious = [iou(x, y) for x, y in zip(sil["old"], sil["new"])]
        df = np.abs(last["old"].front_m - last["new"].front_m).max() * 1e3
        ratio = np.median(rates["new"]) / np.median(rates["old"])
        print(f"# cell {cell:g} mm: median Mpstep/cpu-s old {np.median(rates['old']):.3f}, new "
              f"{np.median(rates['new']):.3f}, speed-up {ratio:.2f}x; new vs old silhouettes IoU mean "
              f"{np.mean(ious):.4f} min {np.min(ious):.4f}, runout differs by <= {df:.2f} mm", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
