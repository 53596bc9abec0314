"""Posterior over (eta, n, sigma_y) given dam-break footage: emcee on an emulated likelihood.

* Prior: uniform on the paper's material space, i.e. on [0, 1]^3 in normalised coordinates
  (:mod:`similarity.space`), restricted to the emulator's trust region: the box estimate +- ``half_width``
  clipped to the material space, where its training simulations lie.  It starts as the first that reaches
  the face of every law asked for (:func:`similarity.trust_box.first_box`), with every smaller box's batch of
  new simulations, and doubles, with a new batch each time, while the posterior reaches one of its faces
  inside the material space: a sample in the box's outer ``EDGE`` there within ``REACH_NATS`` of the best
  (:func:`reaches_a_face`), up to the whole space, which replaces any box of half-width 0.8 or more
  (:func:`similarity.trust_box.box_widths`).  A face on the material space's own boundary is where the
  prior ends, so a posterior resting there is not cut.
* Likelihood: eq. (1) of :mod:`similarity.likelihood`, log p = -tau L(x), with the video loss L
  emulated by :class:`surrogate.emulator.LossEmulator` (quadratic trend + GP) trained on the
  simulations already in the store near the estimate (the CMA-ES archive) plus a scrambled-Sobol
  batch of new ones; its error where the likelihood reaches
  (:func:`similarity.emulator_check.emulator_error`) enters the noise variance.
* Check: posterior draws are simulated, and join the training set while the emulator promised them a better fit
  than the simulator gives (:mod:`similarity.emulator_check`).
* Sampler: :func:`similarity.mcmc.sample` (emcee, resumable HDF5 backend ``posterior.h5`` in the run
  folder), walkers started in a small ball around the CMA-ES optimum.
* Laws: the evidence of Herschel-Bulkley and its special cases on the same emulated likelihood
  (:mod:`similarity.law_evidence`); the box also grows until it reaches each law's face and
  holds each law's posterior on it, and draws of those posteriors are simulated as the posterior's are.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from mpm.files import write_json
from mpm.params import Material
from similarity.best_fit import best_fit
from similarity.evidence import parse_laws, summarise
from similarity.face_search import search_faces
from similarity.law_evidence import LAW_NAMES, TRAINING_FILE, face_draws, law_evidences
from similarity.trust_box import box_widths, cut_fraction, first_box, reaches_a_face
from similarity.flow_band import flow_band
from similarity.mcmc import Posterior, check_backend
from similarity.posterior_summary import (EmulatorSummary, PosteriorCheck, PosteriorStats, PosteriorSummary,  # noqa: F401
                                          read_posterior)
from similarity.run_folder import Run, load_run, read_result  # noqa: F401 (re-exported)
from similarity.space import denormalize, normalize
from similarity.progress import Message, first_line
from similarity.emulator_check import CHECK_ROUNDS, box_log_posterior, checked_posterior, posterior_check

NOISE_COUNT = "frames"  # how N_eff is counted (similarity/likelihood.py), chosen by the calibration study


# -- posterior inputs of a run --------------------------------------------------------------------
def mean_losses(run: Run, X) -> np.ndarray:
    """Mean video loss over the run's setups for normalised candidates X (simulated where not in the store)."""
    X = np.atleast_2d(X)
    if len(X) == 0:
        return np.zeros(0)
    materials = [Material.from_array(denormalize(np.clip(x, 0, 1))) for x in X]
    return run.forward.losses(materials, run.experiments, run.preset.final).mean(axis=1)


def archive(run: Run, center, half_width: float) -> np.ndarray:
    """Normalised materials simulated in the store in every setup of the run with its forward model,
    inside the box ``center +- half_width``: the CMA-ES archive near the estimate."""
    X = normalize(run.forward.simulated(run.experiments, run.preset.final))
    near = np.all(np.abs(X - np.asarray(center)) <= half_width + 1e-12, axis=1)
    return X[near]


def discretisation_error(run: Run) -> float:
    """delta_disc: loss between the estimate simulated at the run's final discretisation (the one of its
    reported loss) and at half its cell width, averaged over the run's setups."""
    from similarity.information import discretisation_losses

    vals = [v for v in discretisation_losses(run.estimate, run.experiments, run.preset.final, run.forward)
            if v is not None]
    return float(np.mean(vals)) if vals else 0.0


def not_among(X, known, tol: float) -> np.ndarray:
    """Mask of the rows of ``X`` that match no row of ``known`` within ``tol`` in every coordinate."""
    return ~np.any(np.all(np.abs(X[:, None] - known[None]) < tol, axis=2), axis=1)


@dataclass
class Analysis:
    """Everything :func:`analyse` computes for a run (``summary`` is what posterior.json holds)."""

    run: Run
    posterior: Posterior
    noise: object
    emulator: object
    summary: PosteriorSummary
    frames: list
    log_prob: Callable[[np.ndarray], np.ndarray]  # the sampled log-posterior (normalised space, vectorised)


def analyse(folder, *, forward=None, new_simulations: int = 24, half_width: float = 0.1,
            seed: int = 0, nwalkers: int = 32, min_ess: float = 1000.0, max_steps: int = 20000,
            discretisation: bool = True, noise_count: str = NOISE_COUNT, laws=LAW_NAMES,
            progress: Callable[[dict], None] | None = None) -> Analysis:
    """Noise scale, emulator, posterior, ellipsoids, ranked next setups and the evidence of the ``laws`` (names,
    :mod:`similarity.evidence`; Herschel-Bulkley always) of a run; writes ``posterior.json``,
    ``posterior_samples.npy``, the resumable ``posterior.h5`` and the checks' draws ``posterior_draws.npy`` into
    the folder.  The box grows until it reaches every law's face and holds every law's posterior.
    ``forward``: the store and executor that simulate (default: the run's store, in this process)."""
    from similarity.design import rank_setups
    from similarity.simulated_design import SIMULATION_PRESET, rank_by_simulation
    from similarity.ellipsoid import alignment, ellipsoid
    from similarity.fd_hessian import fd_hessian
    from similarity.presets import get_preset
    from similarity.estimate import simulated_frames
    from similarity.likelihood import noise_scale
    from similarity.normals import loss_normal
    from surrogate.emulator import box, space_filling

    def say(text):
        if progress:
            progress(Message(text))

    laws = parse_laws(",".join(laws))  # an unknown name stops here, before any work
    run = load_run(folder, forward=forward)
    check_backend(run.folder / "posterior.h5")  # before any simulation
    x_hat = normalize(run.estimate.as_array())
    frames = simulated_frames(run.estimate, run.experiments, preset=run.preset, forward=run.forward)
    if any(f is None for f in frames):
        raise ValueError(f"{run.folder}: the estimate's simulation failed; no posterior")
    delta = discretisation_error(run) if discretisation else 0.0
    say(f"discretisation error (loss, cell vs half cell): {delta:.5f}")
    base_noise = noise_scale(frames, [e.frames for e in run.experiments], discretisation=delta, method=noise_count)
    # The emulator's box grows (half-width doubled, a new space-filling batch each time) while the posterior
    # reaches one of its inner faces: a cut posterior is the box's, not the footage's.
    X_all, y_all = np.zeros((0, 3)), np.zeros(0)
    rng = np.random.default_rng(seed)
    widths = box_widths(half_width)
    batches = [space_filling(x_hat, w, new_simulations, seed=seed + k) if new_simulations else np.zeros((0, 3))
               for k, w in enumerate(widths)]
    stored = archive(run, x_hat, 1.0)  # one pass over the store; each box takes its part
    # the posterior checks' draws, listed before they are simulated: on a re-run they are no archive either
    draws_file = run.folder / "posterior_draws.npy"
    drawn = [np.load(draws_file)] if draws_file.is_file() else []

    def simulate_draws(X):
        new = not_among(X, np.vstack([np.zeros((0, 3)), *drawn]), 1e-12)
        if new.any():  # a replay lists nothing twice
            drawn.append(X[new])
            tmp = draws_file.with_suffix(".tmp.npy")
            np.save(tmp, np.vstack(drawn))
            tmp.replace(draws_file)
        return mean_losses(run, X)

    if new_simulations:  # each special law's best fit, found by the simulator on its face
        X_all, y_all = search_faces(simulate_draws, laws, x_hat, seed=seed, say=say)

    # every law's face must lie in the box, so the loop starts at the first box that reaches them all, with the
    # smaller boxes' batches simulated at once: the design stays densest at the estimate
    first = first_box(x_hat, widths, laws)
    attempt, face_rounds, face_check, retry, fit = first, 0, None, False, None
    while True:
        half_width = widths[attempt]
        # a refit after a failed laws' check adds no batch
        X_new = np.zeros((0, 3)) if retry else np.vstack(batches[:first + 1]) if attempt == first else batches[attempt]
        in_box = np.all(np.abs(stored - x_hat) <= half_width + 1e-12, axis=1)
        X_old = np.vstack([stored[in_box], x_hat[None]])
        # a re-run finds every batch of new simulations in the store: those are not archive, so the training
        # set (and the backend) stay the same
        known = np.vstack([*batches, X_all, *drawn])
        X_old = X_old[not_among(X_old, known, 1e-9)]
        say(f"emulator box +-{half_width:g}: {len(X_old)} simulated candidates from the store, {len(X_new)} new")
        X_add = np.vstack([X_old, X_new])
        X_all, y_all = np.vstack([X_all, X_add]), np.concatenate([y_all, mean_losses(run, X_add)])
        lo, hi = box(x_hat, half_width)
        fit, X_all, y_all = checked_posterior(
            simulate_draws, X_all, y_all, x_hat, lo, hi, base_noise, draws=new_simulations,
            split=rng, seed=seed, stage=attempt, nwalkers=nwalkers, min_ess=min_ess, max_steps=max_steps,
            backend=run.folder / "posterior.h5", progress=progress,
            kernel=None if fit is None else fit.kernel,
            too_few=f"{run.folder}: the emulator's box +-{half_width:g} holds too few simulated candidates "
                    f"({len(X_old)} from the store made with this solver, {len(X_new)} new) to fit it and hold a "
                    f"fifth out: raise --new-simulations")
        emu, validation, noise, post, check = fit.emulator, fit.validation, fit.noise, fit.posterior, fit.check
        cut = cut_fraction(post.samples, lo, hi)
        evidences, faces, retry = None, [], False
        if reaches_a_face(post.samples, post.log_prob, lo, hi):
            why = (f"the posterior reaches an inner face of the emulator's box ({100 * cut:.1f} % of it lies "
                   f"there)")
        else:
            evidences, why, faces = law_evidences(laws, noise, emu, post.samples, lo, hi, seed=seed)
        if why is None and faces and new_simulations and face_rounds < CHECK_ROUNDS:
            # the special laws' posteriors on their faces, checked against the simulator as the posterior's draws are
            face_rounds += 1
            X_chk, which = face_draws(faces, max(4, new_simulations // 4), seed, face_rounds)
            y_chk = simulate_draws(X_chk)
            face_check = posterior_check(noise, emu, X_chk, y_chk, rounds=face_rounds, groups=which)
            X_all, y_all = np.vstack([X_all, X_chk]), np.concatenate([y_all, y_chk])
            say(f"laws' check: {len(y_chk)} draws on the special laws' faces simulated, the emulator is "
                f"{face_check.optimism_nats:+.2f} nats optimistic on them (RMS {face_check.rms_nats:.2f}; "
                f"{face_check.worst_face_nats or 0.0:+.2f} on the worst face), {face_check.failed} failed: "
                f"{'trusted' if face_check.passed else 'retraining'}")
            if not face_check.passed:
                retry = True
                continue
        if half_width >= 1.0 or why is None or attempt == len(widths) - 1:
            break
        say(f"{why}: growing it")
        attempt += 1
    if evidences is None:
        evidences, why, _ = law_evidences(laws, noise, emu, post.samples, lo, hi, seed=seed)
    if why is not None:
        say(f"warning: {why}, and the box may grow no further: the laws' evidence is cut by the box")
    for e in evidences:
        say(f"evidence of {e.law}: ln Z {e.log_z:.2f} ± {e.log_z_err:.2f} ({e.ess:.0f} effective draws)")
    if check is not None and not check.passed:
        say(f"warning: after {check.rounds} checks the emulator is still {check.optimism_nats:.1f} nats optimistic on "
            f"the posterior's draws ({check.failed} of {check.draws} simulations failed): the posterior is not trusted")
    simulated_best = best_fit(X_all, y_all, float(mean_losses(run, x_hat)[0]), base_noise.precision, laws)
    truth = run.truth
    # ellipsoids: posterior covariance and the Laplace approximation (finite-difference Hessian)
    ell = ellipsoid(post.mean, post.cov, 0.9)
    try:
        step = max(1e-5, 0.5 * float(np.sqrt(np.min(np.diag(post.cov)))))
        h = fd_hessian(lambda x: -noise.log_likelihood(emu.predict(x)), post.mean, step)
        laplace = ellipsoid(post.mean, np.linalg.inv(h), 0.9)
    except (ValueError, np.linalg.LinAlgError):
        laplace = None
    m_mean = Material.from_array(denormalize(np.clip(post.mean, 0, 1)))
    normals = {}
    for s in run.setups:
        try:
            q = loss_normal(m_mean, s)
            normals[str(s)] = {"normal": q.tolist(), "alignment_thin_axis": alignment(ell.thin, q)}
        except ValueError:
            normals[str(s)] = None
    # flow-curve band
    band = flow_band(post.si())
    # next setups by expected information gain (and by perpendicularity, for comparison)
    eig_grid, eig = None, None
    try:
        eig = rank_setups(m_mean, run.setups, criterion="eig", covariance=post.cov)
        order = np.argsort(-eig.score)[:10]
        eig_grid = eig.grid().tolist()
        next_eig = [{"setup": f"{eig.width_mm[i]:g}x{eig.height_mm[i]:g}", "eig_nats": float(eig.score[i])}
                    for i in order]
    except ValueError as exc:
        next_eig = []
        say(f"next setups by expected information gain skipped: {first_line(exc)}")
    try:
        best, sp = rank_setups(m_mean, run.setups).best()
        hit = np.array([], int) if eig is None else np.flatnonzero((eig.width_mm == best.width_mm)
                                                                    & (eig.height_mm == best.height_mm))
        next_perp = {"setup": str(best), "score": sp, "eig_nats": float(eig.score[hit[0]]) if hit.size else None}
    except ValueError as exc:
        next_perp = {"error": first_line(exc)}
    say(f"next setup by simulated information ({SIMULATION_PRESET} preset's model)")
    try:
        info = rank_by_simulation(m_mean, run.setups, preset=SIMULATION_PRESET, forward=run.forward,
                                  covariance=post.cov, noise=noise)
        best, gain = info.best()
        top = info.top(3, get_preset(SIMULATION_PRESET).generations)
        next_info = {"setup": str(best), "eig_nats" if info.nats else "score": gain, "preset": SIMULATION_PRESET,
                     "top": [t.to_dict() for t in top], "check": info.check.to_dict()}
    except ValueError as exc:
        next_info = {"error": str(exc).splitlines()[0]}
    summary = PosteriorSummary(
        estimate=run.estimate, estimate_normalised=x_hat.tolist(), setups=[str(s) for s in run.setups], noise=noise,
        emulator=EmulatorSummary(**validation.to_dict(), trust_region=[lo.tolist(), hi.tolist()],
                                 half_width=half_width, cut_fraction=cut, roughness_std=emu.noise_std, check=check,
                                 laws_check=face_check),
        posterior=PosteriorStats.from_dict(post.summary()),
        truth=truth, truth_normalised=None if truth is None else normalize(truth.as_array()).tolist(),
        ellipsoid_posterior=ell, ellipsoid_laplace=laplace, normals=normals, flow_band=band, eig_grid=eig_grid,
        next_setups_eig=next_eig, next_setup_perpendicular=next_perp, next_setup_information=next_info,
        evidence=summarise(evidences, lo, hi, next_setup=(next_info or {}).get("setup")
                           or (next_eig[0]["setup"] if next_eig else None), filmed=run.setups) if evidences else None,
        best_fit=simulated_best)
    np.save(run.folder / "posterior_samples.npy", post.samples)
    np.save(run.folder / "posterior_log_prob.npy", post.log_prob)  # one log-posterior per sample
    # `virheo laws` fits the same emulator again from it
    np.savez(run.folder / TRAINING_FILE, X=fit.X, y=fit.y, seed=seed, theta=fit.kernel.theta)
    write_json(run.folder / "posterior.json", summary)
    return Analysis(run, post, noise, emu, summary, frames, box_log_posterior(noise, emu, lo, hi))

