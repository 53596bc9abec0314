"""The laws' evidence on a report's emulated likelihood: :mod:`similarity.evidence` over the emulator's trust region.

:func:`law_evidences` is what :func:`similarity.posterior.analyse` calls in its box loop (and why the box must grow
for the laws); :func:`evidence_of_report` computes the same again from the files a report left (``virheo laws``).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from similarity.evidence import LAWS, EvidenceSummary, law_evidence, parse_laws, summarise
from similarity.posterior_summary import read_posterior
from similarity.progress import first_line
from similarity.trust_box import reaches_a_face

TRAINING_FILE = "posterior_training.npz"  # the emulator a report keeps: training set X, y, seed, hyperparameters theta
LAW_NAMES = tuple(LAWS)  # the laws whose evidence a report computes by default


def law_evidences(laws, noise, emu, samples, lo, hi, *, seed: int = 0):
    """The evidence (:func:`similarity.evidence.law_evidence`) of each of ``laws`` on the emulated eq. (1) in the box
    [lo, hi] (``samples``: the Herschel-Bulkley posterior's), and why the box must grow (None when it need not): a
    law's face outside the box (the emulator is never extrapolated to it), or a law's posterior on its face reaching
    an inner face of the box.  Returns (the evidences computed, the reason or None, each special law's posterior
    samples on its face)."""
    away = [law.name for law in laws if not law.on_face(lo, hi)]
    if away:
        return [], f"the emulator's box does not reach the face of {', '.join(away)}", []

    def log_like(x):
        return noise.log_likelihood(emu.predict(np.atleast_2d(x)))

    found, cut, faces, inward = {}, [], [], []
    for law in sorted(laws, key=lambda law: not law.fixed):  # the faces first: the general laws' proposal uses them
        # a general law's importance proposal also covers the special laws' posteriors near their faces, where its
        # own posterior's sampler (started at the estimate) may have missed a mode of the likelihood
        ev, face = law_evidence(log_like, law, lo, hi, samples=None if law.fixed else np.vstack([samples, *inward]),
                                seed=seed)
        found[law.name] = ev
        if law.fixed:
            faces.append(face)
            inward.append(off_the_face(face, law, samples, lo, hi, seed))
            if reaches_a_face(face, log_like(face), lo, hi):
                cut.append(law.name)
    return [found[law.name] for law in laws], (f"the posterior of {', '.join(cut)} on its face reaches an inner face "
                                               "of the emulator's box" if cut else None), faces


def off_the_face(face, law, samples, lo, hi, seed: int = 0) -> np.ndarray:
    """A special law's posterior samples on its face (normalised, (k, 3)) moved into the box along each fixed
    coordinate by half-normal steps as wide as the general posterior ``samples`` there: where the general law's
    likelihood has a mode pressed against the face, these cover it (the face samples alone have no width across it)."""
    rng = np.random.default_rng([seed, 7])
    out = np.array(face, float)
    spread = np.std(np.atleast_2d(samples), axis=0)
    for i, v in law.fixed:
        inward = 1.0 if v <= 0.5 * (lo[i] + hi[i]) else -1.0
        out[:, i] = np.clip(v + inward * np.abs(rng.normal(0.0, max(spread[i], 1e-6), len(out))), lo[i], hi[i])
    return out


def face_draws(faces, count: int, seed: int, round_: int) -> tuple[np.ndarray, np.ndarray]:
    """``count`` draws of each special law's posterior samples on its face (normalised), to simulate, and the index
    of the face each draw comes from."""
    rng = np.random.default_rng([seed, 99, round_])
    picks = [f[rng.choice(len(f), size=min(count, len(f)), replace=False)] for f in faces]
    labels = np.concatenate([np.full(len(p), i) for i, p in enumerate(picks)]) if picks else np.zeros(0, int)
    return (np.vstack(picks) if picks else np.zeros((0, 3))), labels


def evidence_of_report(folder, laws=LAW_NAMES) -> EvidenceSummary:
    """The laws' evidence again from what ``virheo report`` left in ``folder``: posterior.json (noise, box),
    posterior_samples.npy and the emulator's training set (refitted as the report fitted it).  Simulates nothing:
    a law whose face lies outside the report's box is a ValueError (``virheo report --laws`` grows the box)."""
    from surrogate.emulator import LossEmulator

    laws = parse_laws(",".join(laws))
    folder = Path(folder)
    summary = read_posterior(folder)
    for name in ("posterior_samples.npy", TRAINING_FILE):
        if not (folder / name).is_file():
            raise ValueError(f"{folder}: no {name} (posterior samples and emulator); run `virheo report {folder}` first")
    try:
        samples = np.load(folder / "posterior_samples.npy")
        with np.load(folder / TRAINING_FILE) as t:
            X, y, seed = t["X"], t["y"], int(t["seed"])
            theta = t["theta"] if "theta" in t.files else None  # a report before it kept its hyperparameters
    except (OSError, ValueError, KeyError) as exc:
        raise ValueError(f"{folder}: unreadable posterior files ({first_line(exc)}); run `virheo report {folder}` "
                         "again") from None
    if samples.ndim != 2 or samples.shape[1] != 3 or len(samples) == 0:
        raise ValueError(f"{folder}: posterior_samples.npy holds no samples; run `virheo report {folder}` again")
    lo, hi = (np.asarray(v, float) for v in summary.emulator.trust_region)
    try:
        emu = LossEmulator(seed=seed).fit(X, y, theta=theta)
    except ValueError as exc:  # a training file whose arrays do not fit together
        raise ValueError(f"{folder}: unreadable {TRAINING_FILE} ({first_line(exc)}); run `virheo report {folder}` "
                         "again") from None
    evidences, why, _ = law_evidences(laws, summary.noise, emu, samples, lo, hi, seed=seed)
    if not evidences:
        raise ValueError(f"{folder}: {why} (never extrapolated); run `virheo report {folder} --laws "
                         f"{','.join(law.name for law in laws)}`, which grows it")
    nxt = (summary.next_setup_information or {}).get("setup") or (
        summary.next_setups_eig[0]["setup"] if summary.next_setups_eig else None)
    return summarise(evidences, lo, hi, next_setup=nxt, filmed=summary.setups)
