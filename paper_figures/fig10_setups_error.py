"""Paper Fig. 10: relative error vs simulation count, one setup vs two setups, and the flow curves.

Runs the cases of the section 7.1 emulation study (``studies.emulation.run_case``; resumable through the store)
and plots, per case, E_rel (eq. of section 7.1) of the best candidate so far against the simulation count: black the
single setup, orange the first setup of the two-setup run, blue its second stage; right, the flow curves
(eq. 1) of the final estimates and the ground truth (dotted).
Quick: one material, one run, 2 generations per stage on the 5 mm model; full: three random first setups of that
material at the paper's budget of 100 generations per stage, like the paper's three panels. These are the first
three cases of the 6 x 3 emulation study (``virheo study emulation``), whose statistics are in docs/validation.md.
Usage: python -m paper_figures.fig10_setups_error [OUT_DIR] [--quick]
"""
from __future__ import annotations

from pathlib import Path

from paper_figures._plot import Context, flow_curves, pyplot
from studies.report import save_figure, write_json

# (materials, runs, generations per stage)
SETTINGS = {True: (1, 1, 2), False: (1, 3, 100)}
GOOD = 0.1


def quick_preset_name() -> str:
    return "demo"  # the 5 mm preset of emulation studies


def make(out_dir, quick: bool = False, *, context: Context | None = None) -> list[Path]:
    from similarity.estimate import get_preset
    from studies.emulation import planned_cases, run_case, summary

    context = context or Context()
    materials, runs, generations = SETTINGS[quick]
    forward, preset = context.resolved_forward(out_dir), get_preset(quick_preset_name())
    cases = [run_case(c, preset=preset, generations=generations, forward=forward)
             for c in planned_cases(None, materials=materials, runs=runs, seed=0)]
    write_json(Path(out_dir) / "fig10_emulation.json",
               {"summary": summary(cases), "generations": generations, "cases": [c.case_dict() for c in cases]})
    plt = pyplot()
    fig, axes = plt.subplots(len(cases), 2, figsize=(10, 3.2 * len(cases)), dpi=90, squeeze=False)
    for (ax, ax_flow), c in zip(axes, cases):
        for key, colour, label, lw in (("single", "k", "one setup", 2.5), ("first", "tab:orange", "setup 1", 1.5),
                                       ("second", "tab:blue", "setups 1+2", 1.5)):
            if c.curves[key]:
                x, y = zip(*c.curves[key])
                ax.plot(x, y, color=colour, lw=lw, label=label, zorder=2 if key == "single" else 3)
        ax.axhline(GOOD, color="grey", ls=":", lw=1)
        ax.set_yscale("log")
        ax.set_xlabel("simulation count", fontsize=8)
        ax.set_ylabel("E_rel", fontsize=8)
        t = c.truth
        ax.set_title(f"truth eta={t.eta:.3g}, n={t.n:.3g}, sigma_y={t.sigma_y:.3g}; setups "
                     f"{' + '.join(c.setups)} mm", fontsize=8)
        ax.legend(fontsize=7)
        ax.tick_params(labelsize=7)
        flow_curves(ax_flow, [
            (f"one setup (E_rel {c.single.e_rel:.3f})", c.single.estimate, {"color": "k", "lw": 2}),
            (f"two setups (E_rel {c.two_setups.e_rel:.3f})", c.two_setups.estimate,
             {"color": "tab:blue", "lw": 1.5}),
            ("ground truth", t, {"color": "grey", "ls": ":", "lw": 2}),
        ])
        ax_flow.legend(fontsize=7, loc="upper left")
    s = summary(cases)
    fig.suptitle(f"{len(cases)} case(s), {generations} generations per stage: good (E_rel <= {GOOD}) with one setup "
                 f"{s.good_single}/{s.cases}, with two setups {s.good_two_setups}/{s.cases}", fontsize=9)
    return [save_figure(fig, Path(out_dir) / "fig10_setups_error.png")]
