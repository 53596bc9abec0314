"""``virheo simulate``: one dam-break through a camera, with silhouettes, a GIF, particle snapshots and, given
an experiment folder, the loss against its footage and side-by-side comparison images."""
from __future__ import annotations

import argparse
import time
import warnings
from pathlib import Path

import numpy as np

from mpm.params import DEFAULT_DENSITY_KG_M3, DEFAULT_DEPTH_MM, FLOW_RULES
from studies.commands.context import check_engine, integer, real

HELP = """Simulate a Herschel-Bulkley dam-break for 1/3 s (8 frames at 24 fps).
Units: --material ETA,N,SIGMA_Y in SI (Pa s^n, -, Pa); --setup WIDTHxHEIGHT in mm (20..70);
--density in kg/m^3; --cell-mm grid cell width in mm.
Accepted materials: the paper's material space (eta 1e-4..30 Pa s^n, n 0.3..1, sigma_y 0..40 Pa),
and beyond it with a warning up to eta 3000 Pa s^n, n 0.1..2 (n > 1: shear-thickening), sigma_y 4000 Pa;
values beyond these limits are refused (extreme ones, e.g. eta = 1e30, make the solver crawl)."""


def register(sub) -> None:
    p = sub.add_parser("simulate", help="simulate a dam-break and render its silhouettes",
                       description=HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--material", required=True, metavar="ETA,N,SIGMA_Y",
                   help="eta [Pa s^n], n [-], sigma_y [Pa], e.g. 3,0.5,15")
    p.add_argument("--setup", metavar="WxH", help="width x height in mm (default: the experiment's)")
    src = p.add_mutually_exclusive_group()
    src.add_argument("--experiment", metavar="DIR", help="experiment folder: camera, density, depth and footage")
    src.add_argument("--camera", metavar="XML", help="camera_params.xml (default: the built-in default camera)")
    p.add_argument("--density", type=real, default=None, metavar="KG_M3",
                   help=f"density in kg/m^3 (default {DEFAULT_DENSITY_KG_M3:g}, or the experiment's)")
    p.add_argument("--depth-mm", type=real, default=None, metavar="MM",
                   help=f"box depth in mm (default {DEFAULT_DEPTH_MM:g}, or the experiment's)")
    p.add_argument("--dim", type=integer, choices=(2, 3), default=3, help="3 (default) or 2 (plane strain)")
    p.add_argument("--cell-mm", type=real, default=None, metavar="MM",
                   help="grid cell width in mm (default: the solver's)")
    p.add_argument("--ppc", type=integer, default=None,
                   help="particles per cell per axis, 1-4 (default: the solver's; the paper: --cell-mm 1.26 --ppc 2)")
    p.add_argument("--flow-rule", choices=FLOW_RULES, default=FLOW_RULES[0], metavar="RULE",
                   help="plastic flow rule, one of: %(choices)s (default %(default)s: the paper's, appendix B)")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="output folder (silhouette_01..08.png, flow.gif, particles.npz, summary.json)")
    p.set_defaults(func=run)


def _mask_png(mask: np.ndarray, path: Path) -> None:
    from PIL import Image

    Image.fromarray(np.where(mask, 0, 255).astype(np.uint8)).save(path, optimize=True)


def run(args) -> int:
    from mpm import camera as cam
    from mpm import experiment as xp
    from mpm.forward import Forward, ForwardModel, blank_experiment
    from mpm.ranges import check_cell_mm, check_density, check_ppc, check_simulable
    from mpm.params import Material, Setup
    from studies.report import overlay_pngs, write_json

    material = Material.parse(args.material)
    check_simulable(material.eta, material.n, material.sigma_y)
    if not material.in_space():
        try:
            material.check_in_space()
        except ValueError as exc:
            warnings.warn(f"{exc}: simulated, but estimation never searches there")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out} is a file, not a folder: name a folder")
    if args.camera and Path(args.camera).is_dir():
        raise ValueError(f"--camera {args.camera} is a folder: name a camera_params.xml file")
    exp = xp.load(args.experiment) if args.experiment else None
    if args.setup:
        setup = Setup.parse(args.setup).check_in_space()
    elif exp is not None:
        setup = Setup(exp.width_mm, exp.height_mm)
        try:
            setup.check_in_space()
        except ValueError as exc:
            raise ValueError(f"{exp.name}: {exc}") from None
    else:
        raise ValueError("--setup WxH is required without --experiment")
    if exp is not None and (abs(setup.width_mm - exp.width_mm) > 0.5 or abs(setup.height_mm - exp.height_mm) > 0.5):
        raise ValueError(f"--setup {setup} does not match the experiment's {exp.width_mm:g}x{exp.height_mm:g} mm")
    if args.density is not None:
        check_density(args.density, "--density")
    if args.cell_mm is not None:
        check_cell_mm(args.cell_mm, "--cell-mm")  # the model's own checks, naming the option
    if args.ppc is not None:
        check_ppc(args.ppc, "--ppc")
    if args.depth_mm is not None and not args.depth_mm > 0:
        raise ValueError(f"--depth-mm {args.depth_mm:g} must be > 0 mm")
    camera = exp.camera if exp else (cam.Camera.from_xml(args.camera) if args.camera else cam.Camera.default())
    density = args.density or (exp.density if exp else DEFAULT_DENSITY_KG_M3)
    depth_mm = args.depth_mm or (exp.depth_mm if exp else DEFAULT_DEPTH_MM)
    model = ForwardModel(cell_mm=args.cell_mm, ppc=args.ppc, flow_rule=args.flow_rule)
    check_engine()
    out.mkdir(parents=True, exist_ok=True)

    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    t0 = time.perf_counter()
    with Progress(TextColumn("{task.description}"), BarColumn(), TimeElapsedColumn()) as bar:
        task = bar.add_task(f"simulating {setup} mm, {material.eta:g}/{material.n:g}/{material.sigma_y:g}",
                            total=8)

        def progress(frame: int, total: int) -> None:
            bar.update(task, completed=frame, total=total)

        shot = blank_experiment(setup, density=density, camera=camera, depth_mm=depth_mm, name="simulate")
        with Forward() as forward:
            sim = forward.simulate(material, shot, model, dim=args.dim, progress=progress)
        bar.update(task, completed=8)
    wall = time.perf_counter() - t0

    for k, mask in enumerate(sim.silhouettes, start=1):
        _mask_png(mask, out / f"silhouette_{k:02d}.png")
    np.savez_compressed(out / "particles.npz", times_s=sim.times,
                        **{f"frame_{k:02d}": f.astype(np.float32) for k, f in enumerate(sim.frames, start=1)})
    _gif(sim.silhouettes, exp.frames if exp is not None else None, out / "flow.gif")
    summary = {
        "material": material.to_dict(), "setup": setup.to_dict(), "density_kg_m3": density, "depth_mm": depth_mm,
        "dim": args.dim, "flow_rule": args.flow_rule, "camera": camera.to_dict(), "times_s": sim.times,
        "front_m": sim.front_m, "wall_seconds": wall, "stats": sim.stats,
    }
    if exp is not None:
        from mpm.loss import frame_losses

        losses = frame_losses(sim.silhouettes, exp.frames)
        summary.update(experiment=str(exp.path), frame_losses=losses, loss=float(np.mean(losses)))
        overlay_pngs(out, sim.silhouettes, exp.frames, prefix="compare")
        print(f"loss (eq. 3, fraction of differing pixels at 960x540): {np.mean(losses):.5f}")
    write_json(out / "summary.json", summary)
    print(f"runout after 1/3 s: {1e3 * sim.front_m[-1]:.1f} mm; {sim.stats.get('n_particles')} particles, "
          f"{sim.stats.get('steps')} steps, {wall:.1f} s; written to {out}/")
    return 0


def _gif(simulated: np.ndarray, captured, path: Path) -> None:
    """Animated GIF of the silhouettes (overlaid on the footage when given), 24 fps played at 6 fps."""
    import imageio.v3 as iio

    from studies.report import overlay

    frames = [overlay(s, c) if captured is not None else np.where(s[..., None], 40, 255).repeat(3, -1)
              for s, c in zip(simulated, captured if captured is not None else simulated)]
    frames = [f[::2, ::2].astype(np.uint8) for f in frames]
    iio.imwrite(path, np.stack(frames), duration=160, loop=0)
