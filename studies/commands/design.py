"""``virheo design``: which dam-break setup to run next, from the current estimate (section 6)."""
from __future__ import annotations

import json
from pathlib import Path

EXAMPLE = "virheo design --material 3.14,0.74,1.24 --done 29x59"
CRITERIA = ("information", "perpendicularity", "eig")


def register(subparsers) -> None:
    from studies.commands.context import PRESET_NAMES, integer, real
    from studies.design_validation import DEFAULT_CRITERION

    p = subparsers.add_parser(
        "design",
        help="propose the next dam-break setup from the current estimate",
        description="Propose the next dam-break setup. --criterion information (default): among 16 setups "
        "(width and height 20, 37, 53, 70 mm) the one whose simulated loss Hessian at the estimate adds the most "
        "information to the setups already done (log det gain; 19 simulations per setup at the preset's model, "
        "a minute or two on a laptop). --criterion perpendicularity: among the 2601 candidates (20..70 mm in 1 mm "
        "steps) the one whose loss normal is most perpendicular to the normals of the setups done (score S_p, "
        "lower is better; Algorithm 2 with the plane-Poiseuille Hessian and the Theta map), no simulation. "
        f"Units: material in SI (eta in Pa s^n, n dimensionless, sigma_y in Pa); setups WxH in millimetres "
        f"(width along the flow, then height). Example: {EXAMPLE}",
    )
    p.add_argument("--material", default=None, metavar="ETA,N,SIGMA_Y",
                   help="current estimate in SI: eta [Pa s^n], n [-], sigma_y [Pa], e.g. 3.14,0.74,1.24 "
                   "(must lie in the material space: eta 1e-4..30, n 0.3..1, sigma_y 0..40)")
    p.add_argument("--done", default=None, action="append", metavar="WxH",
                   help="a setup already run, width x height in mm (20..70), e.g. 29x59; repeat for several")
    p.add_argument("--theta", default=None, metavar="reference|fitted|PATH",
                   help="Theta map of --criterion perpendicularity or eig: 'reference' (the authors' published map, default), 'fitted' (ours, fitted to MPM "
                   "loss landscapes) or a JSON file saved by ThetaMap.save or 'virheo theta fit'")
    p.add_argument("--plot", default=None, metavar="FILE.png",
                   help="write a heat map of S_p over the (W, H) grid in mm with the done and chosen setups marked "
                   "(.png is added to a name without a suffix)")
    p.add_argument("--json", action="store_true", help="print the result as JSON instead of text")
    p.add_argument("--criterion", default=DEFAULT_CRITERION, choices=CRITERIA,
                   help="information: simulated log det gain at the estimate (default); perpendicularity: S_p "
                   "(section 6); eig: expected information gain in nats (linear-Gaussian approximation with the "
                   "Theta map); docs/uncertainty.md compares them")
    p.add_argument("--preset", default=None, choices=PRESET_NAMES,
                   help="information: the preset whose final model simulates (default demo: 5 mm cells; with "
                   "--posterior RUN, the run's own model)")
    p.add_argument("--workers", type=integer, default=None, metavar="K",
                   help="information: local worker processes (default: one per CPU core; 0: in this process)")
    p.add_argument("--store", default=None, metavar="PATH",
                   help="information: simulation store folder to reuse and fill (default: RUN/store with "
                   "--posterior RUN, else none)")
    p.add_argument("--max-volume-ml", type=real, default=None, metavar="ML",
                   help="only setups that hold at most ML millilitres of material (W x H x 40 mm depth)")
    p.add_argument("--max-cost-min", type=real, default=None, metavar="MIN",
                   help="information: only setups whose estimation stage (the preset's generations x 7 simulations of "
                   "every setup, done ones included) costs at most MIN CPU minutes at the criterion's model, from the "
                   "simulation times it measured")
    p.add_argument("--posterior", default=None, metavar="RUN",
                   help="run folder with posterior.json (virheo report): its posterior mean, covariance and setups "
                   "replace --material and --done")
    p.set_defaults(func=run)


def run(args) -> int:
    from similarity.design import rank_setups
    from similarity.simulated_design import SIMULATION_PRESET
    from similarity.information import SIMULATIONS_PER_SETUP, grid_setups
    from similarity.presets import PRESETS, filming, get_preset
    from mpm.params import Material, Setup
    from studies.design_validation import reliability_line, validation
    from surrogate.theta import load

    covariance, run_model, noise = None, None, None
    if args.posterior is not None:
        from similarity.posterior import read_posterior
        from similarity.run_folder import model_of, read_result

        post = read_posterior(args.posterior)
        result, _ = read_result(args.posterior)
        run_model = (model_of(result), result.get("preset"))
        material = post.posterior.mean.check_in_space()
        done = [Setup.parse(text).check_in_space() for text in (args.done or post.setups)]
        covariance, noise = post.posterior.cov_normalised, post.noise
    elif args.material is None or not args.done:
        raise ValueError("give --material and --done, or --posterior RUN")
    else:
        material = Material.parse(args.material).check_in_space()
        done = [Setup.parse(text).check_in_space() for text in args.done]
    plot_path = None
    if args.plot is not None:
        from studies.report import figure_path

        if Path(args.plot).is_dir():
            raise ValueError(f"--plot {args.plot} is a folder: name a .png file")
        plot_path = figure_path(Path(args.plot).expanduser())
        if not plot_path.resolve().parent.is_dir():
            raise ValueError(f"--plot: folder {plot_path.resolve().parent} does not exist")
    theta_name = args.theta or "reference"
    theta = load(theta_name)
    if args.theta is not None and args.criterion == "information":
        raise ValueError("--theta chooses the Theta map of --criterion perpendicularity or eig; the default criterion, "
                         "information, simulates instead: add --criterion perpendicularity")
    for name in ("max_volume_ml", "max_cost_min"):
        if getattr(args, name) is not None and not getattr(args, name) > 0:
            raise ValueError(f"--{name.replace('_', '-')} {getattr(args, name):g} must be > 0")
    if args.max_cost_min is not None and args.criterion != "information":
        raise ValueError("--max-cost-min needs --criterion information: its simulations measure what each setup costs")
    simulations, preset = 0, args.preset or SIMULATION_PRESET
    model_name = f"the {preset} preset's model"
    generations = get_preset(preset).generations
    if run_model is not None and args.preset is None and args.criterion == "information":
        # the run's own forward model, so that the information is the one its estimate and posterior see
        model, run_preset = run_model
        preset = filming(SIMULATION_PRESET, model, "run")
        model_name = f"the run's model ({model.cell_mm:g} mm cells, {model.ppc} particles per axis)"
        generations = get_preset(run_preset).generations if run_preset in PRESETS else generations
    volume_note = None if args.max_volume_ml is None else f"more than {args.max_volume_ml:g} ml (--max-volume-ml)"
    if args.criterion == "information":
        grid = [g for g in grid_setups() if args.max_volume_ml is None or g.volume_ml() <= args.max_volume_ml]
        if not grid:
            raise ValueError(f"no candidate setup holds {volume_note.replace('more than', 'at most')}")
        ranking, simulations = simulated_ranking(material, done, args, preset, grid, covariance, noise)
    else:
        ranking = rank_setups(material, done, theta=theta, criterion=args.criterion, covariance=covariance)
        if volume_note:
            ranking = ranking.subset([s.volume_ml() <= args.max_volume_ml for s in ranking.setups()],
                                     f"setups holding {volume_note}")
    if args.max_cost_min is not None:
        ranking = ranking.subset([c is not None and c <= args.max_cost_min for c in ranking.costs(generations)],
                                 f"setups whose estimation stage costs more than {args.max_cost_min:g} CPU min "
                                 "(--max-cost-min)")
    best, score = ranking.best()
    top = ranking.top(TOP, generations)
    gain, gain_note = expected_gain(ranking, best, material, done, theta, covariance)
    # the study validated the packaged maps and the demo model only: others are "not validated"
    simulating = get_preset(preset).final if args.criterion == "information" else None
    validated = (validation(args.criterion, theta_name) if (simulating is not None
                                                             and simulating.resolved() == get_preset("demo").final.resolved())
                 or (args.criterion != "information" and theta_name in ("reference", "fitted")) else None)
    if plot_path is not None:
        plot_path = plot(ranking, best, plot_path)
    if args.json:
        print(json.dumps({
            "material": material.to_dict(),
            "done": [s.to_dict() for s in done],
            "theta": None if args.criterion == "information" else theta.name,
            "criterion": args.criterion,
            "preset": (preset if isinstance(preset, str) else None) if args.criterion == "information" else None,
            "model": model_name if args.criterion == "information" else None,
            "simulations": simulations,
            "next": best.to_dict(),
            "score": score,
            "score_unit": score_unit(ranking),
            "information_check": None if ranking.check is None else ranking.check.to_dict(),
            "expected_gain_nats": gain,
            "top": [t.to_dict() for t in top],
            "validation": validated,
            "reliability": reliability_line(validated),
            "valid_candidates": len(ranking),
            "notes": list(ranking.notes),
            "plot": str(plot_path) if plot_path else None,
        }, indent=1))
    else:
        label = {"perpendicularity": "S_p", "eig": "expected information gain [nats]",
                 "information": "expected information gain [nats]" if ranking.nats else "predicted log det gain"
                 }[args.criterion]
        print(f"next setup: {best} mm (width x height), {label} = {score:.6f} ({score_unit(ranking)})")
        how = (f"{SIMULATIONS_PER_SETUP * (len(done) + len(grid))} simulations ({simulations} run now) with "
               f"{model_name}" if args.criterion == "information" else f"Theta map: {theta.name}")
        print(f"  material eta={material.eta:g} Pa s^n, n={material.n:g}, sigma_y={material.sigma_y:g} Pa; "
              f"done: {', '.join(str(s) for s in done)}; {len(ranking)} valid candidates; {how}")
        for note in ranking.notes:
            print(f"  left out: {note}")
        model = ("linear-Gaussian model with the simulated loss Hessians" if args.criterion == "information"
                 else "linear-Gaussian model")
        print("  expected gain: " + (f"{gain:.3f} nats (expected information gain, {model})"
                                     if gain is not None else f"not available ({gain_note})"))
        if ranking.check is not None:
            c = ranking.check
            print(f"  calibration: the setups done carry {c.hessian_nats:.2f} nats by their simulated Hessians and the "
                  f"run's noise, {c.posterior_nats:.2f} nats in the posterior (against the uniform prior); "
                  + (f"every Fisher information is scaled by {c.scale:.3g} to match" if c.scale is not None else
                     "no factor matches them, so the score is not in nats"))
        print(top_table(top, args.criterion, model_name, generations))
        print("  " + reliability_line(validated))
        if plot_path:
            print(f"  heat map written to {plot_path}")
    return 0


TOP = 3  # candidates printed with their volume, cost and flags
SCORE_UNIT = {"perpendicularity": "S_p, unitless, lower is better",
              "eig": "nats under the linear-Gaussian model",
              "information": "a unitless score: the loss Hessians are not scaled by the footage's noise"}
NATS_UNIT = ("nats under the linear-Gaussian model: the simulated Hessians weighted by each setup's noise and "
             "calibrated to the run's posterior, its covariance")
UNCALIBRATED_UNIT = ("a unitless score: the simulated Hessians weighted by each setup's noise, but no factor makes the "
                     "setups done carry the posterior's nats")


def score_unit(ranking) -> str:
    """What the ranking's score is, in words."""
    if ranking.criterion == "information" and ranking.check is not None:
        return NATS_UNIT if ranking.nats else UNCALIBRATED_UNIT
    return SCORE_UNIT[ranking.criterion]


def top_table(top, criterion: str, model_name: str, generations: int) -> str:
    """The best candidates (:meth:`similarity.design.Ranking.top`) as indented lines."""
    lines = [f"  best {len(top)}: setup, score, material needed, "
             + (f"CPU minutes of an estimation stage ({generations} generations x 7 simulations of every setup at "
                f"{model_name}, from measured times), flow at the estimate"
                if criterion == "information" else "(cost and flow need --criterion information)")]
    for t in top:
        extra = "" if t.cost_cpu_min is None else f", {t.cost_cpu_min:.1f} CPU min"
        if t.flags is not None:
            extra += f", runout {t.runout_mm:.0f} mm" + (f" (flag: {'; '.join(t.flags)})" if t.flags else "")
        lines.append(f"    {t.setup:>6} mm: {t.score:.4g}, {t.volume_ml:.0f} ml{extra}")
    return "\n".join(lines)


def simulated_ranking(material, done, args, preset, setups=None, covariance=None, noise=None):
    """(the ``information`` ranking, simulations run): the simulator's information at ``material`` with the final
    model of ``preset``; in nats with a posterior's ``covariance`` and ``noise``."""
    import warnings

    from mpm.forward import Forward
    from similarity.simulated_design import rank_by_simulation
    from studies.commands.context import check_engine, report_data_losses, simulator

    if args.workers is not None and args.workers < 0:
        raise ValueError(f"--workers {args.workers} must be >= 0 (0: simulate in this process)")
    if args.store is not None and Path(args.store).exists() and not Path(args.store).is_dir():
        raise ValueError(f"--store {args.store} is a file, not a folder: name a folder")
    check_engine()
    count = [0]

    def tick(req, res, cached):
        count[0] += not cached

    store = args.store if args.store is not None else (Path(args.posterior) / "store" if args.posterior else None)
    with warnings.catch_warnings():
        report_data_losses()
        with Forward(store, workers=args.workers, simulator=simulator()) as forward:
            return (rank_by_simulation(material, done, preset=preset, forward=forward, tick=tick, setups=setups,
                                       covariance=covariance, noise=noise), count[0])


def expected_gain(ranking, best, material, done, theta, covariance) -> tuple[float | None, str | None]:
    """(expected information gain in nats of the chosen setup, why not): the ranking's own score for ``eig``, none
    for ``information`` (its score is not calibrated in nats), else the EIG ranking's value at the chosen setup."""
    from similarity.design import rank_setups
    if ranking.criterion == "information" and not ranking.nats:
        return None, ("without a posterior (--posterior RUN) the simulated Hessians are not scaled by the footage's "
                      "noise, so their log det gain is a unitless score, not nats")
    if ranking.nats:
        return float(ranking.best()[1]), None
    try:
        eig = rank_setups(material, done, theta=theta, criterion="eig", covariance=covariance)
    except ValueError as exc:
        return None, str(exc).splitlines()[0]
    hit = (eig.width_mm == best.width_mm) & (eig.height_mm == best.height_mm)
    return (float(eig.score[hit][0]), None) if hit.any() else (None, "the chosen setup has no EIG")


def plot(ranking, best, path) -> Path:
    """Heat map of S_p over the candidate grid (NaN = invalid), done setups as crosses, the choice as a star;
    returns the file written."""
    from studies.report import save_figure

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.6, 5.0), dpi=120)
    if ranking.criterion == "information":  # 16 setups: one square each
        im = ax.scatter(ranking.width_mm, ranking.height_mm, c=ranking.score, s=700, marker="s", cmap="viridis")
        ax.set(xlim=(12, 78), ylim=(12, 78))
    else:
        im = ax.imshow(ranking.grid(), origin="lower", extent=(19.5, 70.5, 19.5, 70.5), cmap="viridis",
                       interpolation="nearest")
    fig.colorbar(im, ax=ax, label={"perpendicularity": "perpendicularity score $S_p$ (lower is better)",
                                   "eig": "expected information gain [nats] (higher is better)",
                                   "information": "predicted log det gain (higher is better)"}[ranking.criterion])
    for s in ranking.done:
        ax.plot(s.width_mm, s.height_mm, "X", color="w", mec="k", ms=11, ls="none", clip_on=False,
                label="done" if s is ranking.done[0] else None)
    ax.plot(best.width_mm, best.height_mm, "r*", ms=15, mec="k", clip_on=False, label=f"next {best}")
    m = ranking.material
    ax.set(xlabel="width W [mm]", ylabel="height H [mm]",
           title=f"eta={m.eta:.3g} Pa s^n, n={m.n:.3g}, sigma_y={m.sigma_y:.3g} Pa")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=2, fontsize=8, frameon=False)
    return save_figure(fig, path)
