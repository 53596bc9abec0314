"""Per-material uncertainty report: one self-contained HTML page (no scripts, no network) with PNG figures.

Figures: the estimate with 90 % credible intervals, a corner plot of the posterior, the flow curve with
its 90 % band (and a rheometer curve when given), the similarity ellipsoids with the setups' loss
normals, captured vs simulated silhouettes per frame (differences coloured) and the ranked next setups.
"""
from __future__ import annotations

import html
from pathlib import Path

import numpy as np

from similarity.flow_band import band_coverage
from studies.report import overlay, save_figure

NAMES = ("eta", "n", "sigma_y")
LABELS = (r"$\eta$ [Pa s$^n$]", r"$n$ [-]", r"$\sigma_y$ [Pa]")
PLAIN = ("eta [Pa s^n]", "n [-]", "sigma_y [Pa]")


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def intervals_png(path, summary) -> Path:
    plt = _plt()
    quantiles, est, truth = summary.posterior.quantiles, summary.estimate, summary.truth
    fig, axes = plt.subplots(1, 3, figsize=(9, 2.4), dpi=110)
    for ax, name, label in zip(axes, NAMES, LABELS):
        lo, med, hi = (getattr(quantiles[k], name) for k in ("5", "50", "95"))
        ax.plot([lo, hi], [0, 0], lw=6, color="tab:blue", alpha=0.5, label="90 % credible interval")
        ax.plot(med, 0, "o", color="tab:blue", label="posterior median")
        ax.plot(getattr(est, name), 0, "kx", ms=10, mew=2, label="CMA-ES estimate")
        if truth is not None:
            ax.plot(getattr(truth, name), 0, "r*", ms=12, label="truth")
        ax.set_yticks([])
        ax.set_xlabel(label)
        span = max(hi - lo, 1e-6)
        xs = [lo, hi, getattr(est, name)] + ([getattr(truth, name)] if truth is not None else [])
        ax.set_xlim(min(xs) - 0.3 * span, max(xs) + 0.3 * span)
    axes[1].legend(fontsize=7, loc="lower center", bbox_to_anchor=(0.5, 1.02), ncol=4, frameon=False)
    return save_figure(fig, path)


def corner_png(path, samples_si, summary) -> Path:
    plt = _plt()
    fig, axes = plt.subplots(3, 3, figsize=(6.5, 6.5), dpi=110)
    truth, est = summary.truth, summary.estimate
    for i in range(3):
        for j in range(3):
            ax = axes[i, j]
            if j > i:
                ax.axis("off")
                continue
            if i == j:
                ax.hist(samples_si[:, i], bins=40, color="tab:blue", alpha=0.7)
                for q in ("5", "95"):
                    ax.axvline(getattr(summary.posterior.quantiles[q], NAMES[i]), color="k", ls=":", lw=1)
                ax.set_yticks([])
            else:
                ax.hist2d(samples_si[:, j], samples_si[:, i], bins=40, cmap="Blues")
                ax.plot(getattr(est, NAMES[j]), getattr(est, NAMES[i]), "kx", ms=8, mew=2)
                if truth is not None:
                    ax.plot(getattr(truth, NAMES[j]), getattr(truth, NAMES[i]), "r*", ms=10)
            if i == 2:
                ax.set_xlabel(LABELS[j])
            if j == 0 and i > 0:
                ax.set_ylabel(LABELS[i])
            ax.tick_params(labelsize=7)
    fig.suptitle("posterior (x: CMA-ES estimate" + (", red star: truth)" if truth is not None else ")"), fontsize=9)
    return save_figure(fig, path)


def flow_band_png(path, summary, rheometer=None) -> Path:
    plt = _plt()
    band = summary.flow_band
    rate = np.asarray(band["shear_rate"])
    fig, ax = plt.subplots(figsize=(6, 4.3), dpi=110)
    ax.fill_between(rate, band["5"], band["95"], color="tab:blue", alpha=0.3, label="90 % posterior band")
    ax.loglog(rate, band["50"], color="tab:blue", lw=2, label="posterior median")
    ax.loglog(rate, np.maximum(summary.estimate.stress(rate), 1e-6), "k--", lw=1.5, label="CMA-ES estimate")
    if summary.truth is not None:
        ax.loglog(rate, np.maximum(summary.truth.stress(rate), 1e-6), "r:", lw=2, label="truth")
    if rheometer is not None:
        ax.loglog(rheometer.shear_rate, rheometer.shear_stress, "o", ms=3, color="tab:orange",
                  label=f"rheometer ({rheometer.name})")
    ax.axvspan(1, 100, color="grey", alpha=0.08, lw=0)
    ax.set(xlabel="shear rate [1/s]", ylabel="shear stress [Pa]", xlim=(rate[0], rate[-1]),
           title="flow curve (eq. 1); shaded: 1-100 1/s")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, loc="upper left")
    return save_figure(fig, path)


def _ellipse(ax, center, cov, level_chi2, i, j, **kw):
    sub = np.asarray(cov)[np.ix_([i, j], [i, j])]
    lam, vec = np.linalg.eigh(sub)
    t = np.linspace(0, 2 * np.pi, 100)
    pts = vec @ (np.sqrt(np.maximum(lam, 0) * level_chi2)[:, None] * np.array([np.cos(t), np.sin(t)]))
    ax.plot(center[i] + pts[0], center[j] + pts[1], **kw)


def ellipsoids_png(path, summary, samples) -> Path:
    """90 % ellipsoids (posterior, Laplace) projected on the coordinate planes of the normalised space,
    with the setups' plane-Poiseuille loss normals as arrows."""
    from scipy.stats import chi2

    plt = _plt()
    c2 = chi2.ppf(0.9, 2)
    names = ("eta", "n", "sigma_y")
    ep = summary.ellipsoid_posterior
    mean = ep.center
    cov = np.cov(samples, rowvar=False)
    lap = summary.ellipsoid_laplace
    fig, axes = plt.subplots(1, 3, figsize=(10, 3.6), dpi=110)
    scale = 2.0 * max(ep.lengths)
    for ax, (i, j) in zip(axes, ((0, 1), (0, 2), (1, 2))):
        ax.plot(samples[::20, i], samples[::20, j], ".", ms=1, color="tab:blue", alpha=0.3)
        _ellipse(ax, mean, cov, c2, i, j, color="tab:blue", lw=2, label="posterior 90 %")
        if lap is not None:
            lam = lap.lengths ** 2 / chi2.ppf(0.9, 3)
            _ellipse(ax, lap.center, lap.axes @ np.diag(lam) @ lap.axes.T, c2, i, j, color="k", ls="--",
                     lw=1.2, label="Laplace 90 %")
        for k, (setup, q) in enumerate((summary.normals or {}).items()):
            if q is None:
                continue
            v = np.asarray(q["normal"])
            ax.annotate("", xy=(mean[i] + scale * v[i], mean[j] + scale * v[j]), xytext=(mean[i], mean[j]),
                        arrowprops=dict(arrowstyle="->", color=f"C{k + 1}", lw=1.5))
            ax.plot([], [], color=f"C{k + 1}", label=f"loss normal {setup}")
        ax.set(xlabel=f"{names[i]} (normalised)", ylabel=f"{names[j]} (normalised)")
        ax.set_aspect("equal", adjustable="datalim")
        ax.tick_params(labelsize=7)
    axes[0].legend(fontsize=6, loc="best")
    return save_figure(fig, path)


def _crop_box(frames_a, frames_b, margin: int = 12):
    union = np.any(np.asarray(frames_a, bool), axis=0) | np.any(np.asarray(frames_b, bool), axis=0)
    rows, cols = np.flatnonzero(union.any(axis=1)), np.flatnonzero(union.any(axis=0))
    if rows.size == 0:
        return slice(None), slice(None)
    h, w = union.shape
    return (slice(max(rows[0] - margin, 0), min(rows[-1] + margin + 1, h)),
            slice(max(cols[0] - margin, 0), min(cols[-1] + margin + 1, w)))


def overlays_png(path, simulated, captured, title: str) -> Path:
    """Frames 1..F as coloured overlays: grey both, blue captured only, red simulated only."""
    plt = _plt()
    rs, cs = _crop_box(simulated, captured)
    n = len(simulated)
    cols = 4
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(10, 1.9 * rows + 0.4), dpi=110, squeeze=False)
    for k, ax in enumerate(axes.ravel()):
        ax.axis("off")
        if k < n:
            s, c = np.asarray(simulated[k], bool)[rs, cs], np.asarray(captured[k], bool)[rs, cs]
            ax.imshow(overlay(s, c), interpolation="nearest")
            ax.set_title(f"frame {k + 1}: {100 * np.mean(s ^ c) * (s.size / np.asarray(simulated[k]).size):.2f} % px",
                         fontsize=7)
    fig.suptitle(f"{title}: grey both, blue captured only, red simulated only", fontsize=9)
    return save_figure(fig, path)


def eig_map_png(path, summary) -> Path | None:
    plt = _plt()
    rows = summary.eig_grid
    if not rows:
        return None
    grid = np.asarray(rows, float)
    fig, ax = plt.subplots(figsize=(5.2, 4.5), dpi=110)
    im = ax.imshow(grid, origin="lower", extent=(19.5, 70.5, 19.5, 70.5), cmap="viridis")
    fig.colorbar(im, ax=ax, label="expected information gain [nats]")
    for s in summary.setups:
        w, h = (float(v) for v in s.split("x"))
        ax.plot(w, h, "X", color="w", mec="k", ms=10)
    if summary.next_setups_eig:
        w, h = (float(v) for v in summary.next_setups_eig[0]["setup"].split("x"))
        ax.plot(w, h, "r*", ms=14, mec="k", label="best by EIG")
    perp = summary.next_setup_perpendicular or {}
    if perp.get("setup"):
        w, h = (float(v) for v in perp["setup"].split("x"))
        ax.plot(w, h, "o", color="orange", mec="k", ms=8, label="most perpendicular (S_p)")
    ax.set(xlabel="width W [mm]", ylabel="height H [mm]", title="next setup (X: done)")
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.15), ncol=2, frameon=False)
    return save_figure(fig, path)


def _fmt(v) -> str:
    return "–" if v is None else f"{v:.4g}"


def write_html(out, summary, figures: dict, *, overlays: list, rheometer=None, coverage=None,
               preset: str | None = None) -> Path:
    """index.html in ``out`` referring to the PNGs by relative name (all in ``out``)."""
    from similarity.emulator_check import FOLDS

    out = Path(out)
    post, truth = summary.posterior, summary.truth
    e = html.escape
    rows = []
    for name, plain in zip(NAMES, PLAIN):
        cells = [plain, _fmt(getattr(summary.estimate, name)), _fmt(getattr(post.mean, name))]
        cells += [_fmt(getattr(post.quantiles[k], name)) for k in ("5", "50", "95")]
        if truth is not None:
            cells.append(_fmt(getattr(truth, name)))
        rows.append("<tr>" + "".join(f"<td>{e(c)}</td>" for c in cells) + "</tr>")
    head = ["parameter", "CMA-ES estimate", "posterior mean", "5 %", "50 %", "95 %"]
    head += ["truth"] if truth is not None else []
    noise, emu = summary.noise, summary.emulator
    ell = summary.ellipsoid_posterior
    axes_rows = "".join(
        f"<tr><td>{k + 1}</td><td>({', '.join(f'{v:+.3f}' for v in ax)})</td><td>{ln:.4g}</td></tr>"
        for k, (ax, ln) in enumerate(zip(ell.axes.T, ell.lengths)))
    normals = "".join(
        f"<li>setup {e(s)} mm: |cos(thin axis, loss normal)| = {q['alignment_thin_axis']:.3f}</li>"
        for s, q in (summary.normals or {}).items() if q)
    nexts = "".join(f"<tr><td>{k + 1}</td><td>{e(r['setup'])}</td><td>{r['eig_nats']:.4f}</td></tr>"
                    for k, r in enumerate(summary.next_setups_eig or []))
    perp = summary.next_setup_perpendicular or {}
    perp_line = (f"<p>Most perpendicular setup (section 6): <b>{e(perp['setup'])}</b> mm, S_p = {perp['score']:.4f}"
                 + (f", EIG {perp['eig_nats']:.4f} nats" if perp.get("eig_nats") is not None else "") + ".</p>"
                 if perp.get("setup") else "")
    from studies.design_validation import reliability_line, validation

    reliability = (f"<p>EIG ranking, {'<br>'.join(map(e, reliability_line(validation('eig', 'reference')).splitlines()))}"
                   ".</p>" if nexts else "")
    info = summary.next_setup_information or {}
    if info.get("setup"):
        info_line = "<br>".join(map(e, reliability_line(validation("information", "reference")).splitlines()))
        from similarity.posterior_summary import information_gain

        gain, unit = information_gain(info)
        reliability += (f"<p>Setup of largest simulated information (the loss Hessians of 16 setups simulated at "
                        f"the posterior mean, {e(info['preset'])} preset's model"
                        f"{', each weighted by its own noise' if unit == 'nats' else ''}): "
                        f"<b>{e(info['setup'])}</b> mm{e(summary.again)}, {gain:.4f} {e(unit)}. {info_line}.</p>")
        if info.get("check"):
            c = info["check"]
            reliability += (f"<p>Calibration: the setups done carry {c['hessian_nats']:.2f} nats by their simulated "
                            f"Hessians, {c['posterior_nats']:.2f} nats in the posterior"
                            + (f"; every Fisher information is scaled by {c['scale']:.3g}" if c.get("scale") is not None
                               else "") + ".</p>")
        if info.get("top"):
            reliability += (f"<table><tr><th>setup</th><th>gain ({e(unit.split(',')[0])})</th><th>material</th><th>CPU min per "
                            "estimation stage</th><th>runout at the estimate</th><th>flags</th></tr>" + "".join(
                                f"<tr><td>{e(t['setup'])} mm</td><td>{t['score']:.3f}</td><td>{t['volume_ml']:.0f} ml"
                                f"</td><td>{t['cost_cpu_min']:.1f}</td><td>{t['runout_mm']:.0f} mm</td>"
                                f"<td>{e('; '.join(t['flags'] or []))}</td></tr>" for t in info["top"]) + "</table>")
    elif info.get("error"):
        reliability += f"<p>Simulated information: not available ({e(info['error'])}).</p>"
    rheo = ""
    if rheometer is not None:
        rheo = (f"<p>Rheometer curve: {e(rheometer.name)}; {100 * coverage:.0f} % of its points between 1 and "
                f"100 1/s lie inside the 90 % band.</p>")
    laws = _laws_html(summary.evidence, preset)
    better = better_fit_html(summary.best_fit)
    img = lambda key, alt: f'<img src="{e(figures[key].name)}" alt="{e(alt)}">' if figures.get(key) else ""
    ovl = "".join(f'<h3>setup {e(s)} mm</h3><img src="{e(p.name)}" alt="overlays {e(s)}">' for s, p in overlays)
    status = "converged" if post.converged else "NOT converged (increase the step budget)"
    page = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>virheometry report</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:1em auto;color:#222}}
table{{border-collapse:collapse;margin:.5em 0}}td,th{{border:1px solid #bbb;padding:2px 8px;text-align:right}}
img{{max-width:100%;display:block;margin:.5em 0}}h2{{border-bottom:1px solid #ccc}}</style></head><body>
<h1>Herschel-Bulkley parameters with uncertainty</h1>
<p>Setups: {e(', '.join(summary.setups))} mm. Posterior from emcee on an emulated likelihood; {status}:
{post.iterations} steps x {post.nwalkers} walkers, integrated autocorrelation time
{max(post.tau):.1f} steps, effective sample size {post.ess:.0f}.</p>
<h2>Estimate and 90 % credible intervals</h2>
<table><tr>{''.join(f'<th>{h}</th>' for h in head)}</tr>{''.join(rows)}</table>{better}
{img('intervals', 'credible intervals')}
<h2>Posterior (corner plot)</h2>{img('corner', 'corner plot')}
<h2>Flow curve with 90 % band</h2>{img('flow', 'flow curve band')}{rheo}
<h2>Which law: yield stress, shear thinning</h2>{laws}
<h2>Similarity ellipsoids (normalised material space)</h2>
<p>90 % posterior ellipsoid, axes thin to long (eta, n, sigma_y):</p>
<table><tr><th>axis</th><th>direction</th><th>semi-axis length</th></tr>{axes_rows}</table>
<ul>{normals}</ul>{img('ellipsoids', 'ellipsoids')}
<h2>Captured vs simulated silhouettes</h2>{ovl}
<h2>Next setup</h2>{img('eig', 'expected information gain map')}
<table><tr><th>rank</th><th>setup [mm]</th><th>EIG [nats]</th></tr>{nexts}</table>{reliability}{perp_line}
<h2>Noise model and emulator</h2>
<p>Noise: {noise.frames} frames, N_eff = {noise.n_eff:.0f} independent residuals, loss at the optimum
{noise.loss_at_optimum:.3g}, discretisation error {noise.discretisation:.3g}, emulator error
{noise.emulator:.3g}; s<sup>2</sup> = {noise.variance:.3g}, tau = {noise.precision:.4g}.
Emulator: {emu.n_train} training simulations; {FOLDS}-fold cross-validated RMSE {emu.rmse:.3g} on the {emu.n_test} whose
loss the likelihood reaches (largest error {emu.max_abs:.3g}, their loss range {emu.loss_range:.3g}).{_check_line(emu.check)}</p>
</body></html>
"""
    path = out / "index.html"
    path.write_text(page, encoding="utf-8")
    return path


def better_fit_html(fit) -> str:
    """The best simulated fit as a paragraph where it beats the estimate by ``NOTE_NATS`` (similarity.best_fit), else
    nothing."""
    if fit is None or not fit.better:
        return ""
    return f"<p><b>{html.escape(fit.text[0].upper() + fit.text[1:])}.</b></p>"


def _laws_html(evidence, preset: str | None) -> str:
    """The verdicts and the laws' evidence table (:mod:`similarity.evidence`) with how the verdicts fared at the run's
    preset, or a line saying there are none."""
    from studies.law_validation import calibration_line

    if evidence is None:
        return "<p>No evidence of the laws in this posterior (written before it existed): run the report again.</p>"
    e = html.escape
    verdicts = "".join(f"<li><b>{e(v.text)}</b></li>" for v in evidence.verdicts)
    ref = evidence.of("herschel-bulkley")
    rows = "".join(
        f"<tr><td style='text-align:left'>{e(ev.law)}</td><td>{ev.log_z:.2f} ± {ev.log_z_err:.2f}</td>"
        f"<td>{ev.log_z - ref.log_z:+.2f}</td><td>{evidence.probabilities[ev.law]:.3f}</td>"
        f"<td>{ev.best.eta:.4g}, {ev.best.n:.4g}, {ev.best.sigma_y:.4g}</td><td>{ev.ess:.0f}</td></tr>"
        for ev in evidence.laws)
    return (f"<ul>{verdicts}</ul><table><tr><th>law</th><th>ln evidence</th><th>ln BF vs HB</th>"
            f"<th>probability (equal prior odds)</th><th>best eta, n, sigma_y</th><th>effective draws</th></tr>"
            f"{rows}</table><p>Each law is eq. 1 with n = 1 (Bingham), sigma_y = 0 (power law) or both (Newtonian), "
            f"with the same likelihood and the same prior restricted to its face; the evidence is integrated over the "
            f"emulator's box (never beyond it) by importance sampling. Jeffreys' scale in ln BF: 1.15 substantial, "
            f"2.3 strong (resolved), 3.45 very strong, 4.6 decisive.</p><p>{e(calibration_line(preset))}.</p>")


def _check_line(check) -> str:
    """The posterior's check against the simulator, in words ('' without one)."""
    if check is None:
        return ""
    verdict = "trusted" if check.passed else "<b>not trusted</b>: the emulator still promises a better fit than the simulator gives"
    return (f" Check: {check.draws} posterior draws simulated after {check.rounds} fit(s) of the emulator; it was "
            f"{check.optimism_nats:+.2f} nats optimistic on them on average (RMS {check.rms_nats:.2f}), "
            f"{check.failed} simulations failed: {verdict}.")


def write_report(out, analysis, *, rheometer=None) -> Path:
    """All figures and index.html for a :class:`similarity.posterior.Analysis` into folder ``out``."""
    from similarity.space import denormalize

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    summary = analysis.summary
    samples = analysis.posterior.samples
    figures = {
        "intervals": intervals_png(out / "intervals.png", summary),
        "corner": corner_png(out / "corner.png", denormalize(samples), summary),
        "flow": flow_band_png(out / "flow_band.png", summary, rheometer),
        "ellipsoids": ellipsoids_png(out / "ellipsoids.png", summary, samples),
        "eig": eig_map_png(out / "next_setup_eig.png", summary),
    }
    overlays = []
    for e, sim in zip(analysis.run.experiments, analysis.frames):
        s = f"{float(e.width_mm):g}x{float(e.height_mm):g}"
        overlays.append((s, overlays_png(out / f"overlay_{s}.png", sim, e.frames, f"setup {s} mm")))
    coverage = band_coverage(summary.flow_band, rheometer) if rheometer is not None else None
    if coverage is not None:
        summary.rheometer_band_coverage = coverage
    return write_html(out, summary, figures, overlays=overlays, rheometer=rheometer, coverage=coverage,
                      preset=analysis.run.preset.name)
