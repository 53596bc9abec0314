"""Taichi CPU solver speed and cold start (VIRHEO_ARCH=taichi-cpu), old and new side by side, one thread each.

The old solver is the ``mpm`` package of a git revision (default ``main``), extracted with ``git archive``
into a temporary package ``mpm_base``; the new one is this checkout's ``mpm``. Each runs in its own worker
process (Taichi holds one compile configuration per process, and the two solvers may choose different ones),
started together; the workers run the same evaluations alternately (so that the load of a shared machine hits
both alike), and the script prints particle-steps per CPU-second (process CPU time of the simulation), their
ratio, and how far the new results are from the old (silhouette IoU through ``Camera.default()``, rendered
afterwards, and runout). The first call of each worker (6 mm cells) compiles the kernels or loads them from
Taichi's offline cache; ``--fresh-cache`` gives each worker an empty cache, so that it measures a first run on
a fresh machine:

    python bench/bench_solver_speed.py                         # 30 x 20 mm at 1.5 and 5 mm, 2 rounds
    python bench/bench_solver_speed.py --cells 1.5 --rounds 3 --base main~3
    python bench/bench_solver_speed.py --dim 2 --cells 0.75 2    # plane strain
    python bench/bench_solver_speed.py --fresh-cache --cells      # cold compile only
"""
import argparse
import json
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

ROOT = Path(__file__).resolve().parent.parent

import numpy as np  # noqa: E402
from measured import how_measured  # noqa: E402  (bench/ is this script's folder)


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


def worker(package: str, material: str, setup: str, dim: int) -> int:
    """Serve simulations of ``package`` (mpm or mpm_base): one JSON request per stdin line ({"cell": mm,
    "frames": path or null}), one JSON answer per stdout line; frames are saved to ``frames`` (npz)."""
    import importlib

    out = sys.stdout
    sys.stdout = sys.stderr  # Taichi's start-up lines stay off the answer channel
    sim = importlib.import_module(package).simulate
    eta, n, sy = (float(v) for v in material.split(","))
    w, h = (float(v) for v in setup.lower().split("x"))
    mat, box = NS(eta=eta, n=n, sigma_y=sy), NS(width_mm=w, height_mm=h)
    for line in sys.stdin:
        req = json.loads(line)
        c0, t0 = time.process_time(), time.perf_counter()
        s = sim(mat, box, density=1000.0, cell_mm=req["cell"], dim=dim)  # no camera: simulation only
        cpu, wall = time.process_time() - c0, time.perf_counter() - t0
        if req.get("frames"):
            np.savez(req["frames"], front=s.front_m, spacing=s.stats["spacing_m"], *s.frames)
        print(json.dumps(dict(cpu=cpu, wall=wall, n=s.stats["n_particles"], steps=s.stats["steps"])), file=out,
              flush=True)
    return 0


class Worker:
    def __init__(self, name: str, package: str, path: str, a, env: dict):
        self.name = name
        cmd = [sys.executable, __file__, "--worker", package, "--material", a.material, "--setup", a.setup,
               "--dim", str(a.dim)]
        env = dict(env, PYTHONPATH=os.pathsep.join([path, env.get("PYTHONPATH", "")]))
        self.proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env)

    def run(self, cell: float, frames: str | None = None) -> dict:
        self.proc.stdin.write(json.dumps(dict(cell=cell, frames=frames)) + "\n")
        self.proc.stdin.flush()
        line = self.proc.stdout.readline()
        if not line:
            raise RuntimeError(f"the {self.name} worker stopped")
        return json.loads(line)

    def close(self):
        self.proc.stdin.close()
        self.proc.wait()


def load_frames(path: str):
    z = np.load(path)
    return [z[f"arr_{k}"] for k in range(8)], z["front"], float(z["spacing"])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", default="main", help="git revision of the old solver (default main)")
    ap.add_argument("--cells", type=float, nargs="*", default=[1.5, 5.0], help="cell widths in mm")
    ap.add_argument("--setup", default="30x20", help="W x H in mm")
    ap.add_argument("--material", default="1,0.8,5", help="eta,n,sigma_y (Pa s^n, -, Pa)")
    ap.add_argument("--dim", type=int, default=3, help="3, or 2 for plane strain")
    ap.add_argument("--rounds", type=int, default=2, help="old/new pairs per cell width")
    ap.add_argument("--fresh-cache", action="store_true",
                    help="empty Taichi offline cache per worker: the first call measures the cold compile")
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.worker:
        return worker(a.worker, a.material, a.setup, a.dim)

    tmp = Path(tempfile.mkdtemp(prefix="virheo-base-"))
    commit = extract_base(a.base, tmp)
    env = dict(os.environ, VIRHEO_THREADS="1")  # one thread, as batch evaluation runs
    workers = []
    for name, package, path in (("old", "mpm_base", str(tmp)), ("new", "mpm", str(ROOT))):
        # Taichi's CPU path on both sides (named "cpu" before the native engine came)
        runtime_py = Path(path) / package / "runtime.py"
        wenv = dict(env, VIRHEO_ARCH="taichi-cpu" if "taichi-cpu" in runtime_py.read_text() else "cpu")
        if a.fresh_cache:
            cache = tmp / f"ticache-{name}"
            cache.mkdir()
            wenv["TI_OFFLINE_CACHE_FILE_PATH"] = str(cache)
        workers.append(Worker(name, package, path, a, wenv))
    print(f"# measured: {how_measured()}", flush=True)
    print(f"# old = {a.base} ({commit}), new = this checkout; one thread per worker process; {a.dim}D; "
          f"material {a.material}, setup {a.setup} mm, density 1000; load {os.getloadavg()[0]:.1f}")
    for wk in workers:  # one at a time, so that a cold compile has the machine to itself
        r = wk.run(6.0)
        how = "empty Taichi cache: compiled" if a.fresh_cache else "compiled or loaded from the cache"
        print(f"# {wk.name}: first call at 6 mm (kernels {how}) {r['cpu']:.1f} CPU s, {r['wall']:.1f} s wall, "
              f"load {os.getloadavg()[0]:.1f}", flush=True)
    if a.cells:
        print(f"{'cell mm':>7} {'run':>4} {'particles':>9} {'steps':>5} {'cpu s':>7} {'wall s':>7} "
              f"{'Mpstep/cpu-s':>12}")
    from mpm.camera import Camera
    from mpm.loss import iou
    from mpm.silhouette import render

    cam = Camera.default()
    for cell in a.cells:
        rates = {"old": [], "new": []}
        for k in range(a.rounds):
            for wk in workers:
                frames = str(tmp / f"{wk.name}.npz") if k == a.rounds - 1 else None
                r = wk.run(cell, frames)
                ps = r["n"] * r["steps"]
                rates[wk.name].append(ps / r["cpu"] / 1e6)
                print(f"{cell:7.2f} {wk.name:>4} {r['n']:9d} {r['steps']:5d} {r['cpu']:7.2f} {r['wall']:7.2f} "
                      f"{ps / r['cpu'] / 1e6:12.3f}", flush=True)
        res = {wk.name: load_frames(str(tmp / f"{wk.name}.npz")) for wk in workers}
        sil = {k: [render(f, cam, spacing_m=sp) for f in fr] for k, (fr, _, sp) in res.items()}
        ious = [iou(x, y) for x, y in zip(sil["old"], sil["new"])]
        df = np.abs(res["old"][1] - res["new"][1]).max() * 1e3
        ratio = np.median(rates["new"]) / np.median(rates["old"])
        print(f"# cell {cell:g} mm: median Mpstep/cpu-s old {np.median(rates['old']):.3f}, new "
              f"{np.median(rates['new']):.3f}, speed-up {ratio:.2f}x; new vs old silhouettes IoU mean "
              f"{np.mean(ious):.4f} min {np.min(ious):.4f}, runout differs by <= {df:.2f} mm; "
              f"load {os.getloadavg()[0]:.1f}", flush=True)
    for wk in workers:
        wk.close()
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT))
    raise SystemExit(main())
