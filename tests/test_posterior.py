"""Posterior sampling, noise model, emulator and expected information gain against closed forms."""
import os
import subprocess
import sys
import textwrap
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from mpm.params import Material, Setup
from similarity.design import expected_information_gain, rank_setups
from similarity.ellipsoid import alignment, ellipsoid
from similarity.fd_hessian import fd_hessian
from similarity.likelihood import correlation_area, noise_scale
from similarity.mcmc import gaussian_moments_check, sample
from surrogate.emulator import LossEmulator, space_filling

ROOT = Path(__file__).resolve().parent.parent
MEAN = np.array([0.5, 0.4, 0.6])
COV = np.array([[4e-4, 3e-4, 0.0], [3e-4, 9e-4, -2e-4], [0.0, -2e-4, 2.5e-3]])


def test_linear_gaussian_posterior_moments_match_closed_form():
    # a linear-Gaussian problem: prior N(m0, P0), data y = G x + e, e ~ N(0, R); posterior in closed form
    rng = np.random.default_rng(3)
    G = rng.normal(size=(5, 3))
    R = np.diag(rng.uniform(0.5, 1.5, 5)) * 1e-3
    m0, P0 = np.full(3, 0.5), np.eye(3) * 0.01
    y = G @ np.array([0.52, 0.45, 0.58]) + rng.multivariate_normal(np.zeros(5), R)
    prec = np.linalg.inv(P0) + G.T @ np.linalg.solve(R, G)
    cov = np.linalg.inv(prec)
    mean = cov @ (np.linalg.solve(P0, m0) + G.T @ np.linalg.solve(R, y))

    def log_prob(x):
        r = y[None] - x @ G.T
        d = x - m0
        lp = -0.5 * np.einsum("ij,jk,ik->i", r, np.linalg.inv(R), r) - 0.5 * np.einsum("ij,jk,ik->i", d, np.linalg.inv(P0), d)
        return np.where(np.all((x >= 0) & (x <= 1), axis=1), lp, -np.inf)

    post = sample(log_prob, m0, nwalkers=32, seed=1, min_ess=2000)
    assert post.converged and post.ess >= 2000
    sd = np.sqrt(np.diag(cov))
    assert np.all(np.abs(post.mean - mean) < 5 * sd / np.sqrt(post.ess))
    rel = np.abs(post.cov - cov) / np.sqrt(np.outer(np.diag(cov), np.diag(cov)))
    assert rel.max() < 0.15
    # quantiles: the 5/95 % of a Gaussian are mean -+ 1.645 sd
    q = np.quantile(post.samples, [0.05, 0.95], axis=0)
    assert np.allclose(q[0], mean - 1.645 * sd, atol=0.12 * sd.max()) and np.allclose(q[1], mean + 1.645 * sd, atol=0.12 * sd.max())


def test_eig_matches_closed_form_and_monte_carlo():
    rng = np.random.default_rng(0)
    cov = COV
    G = rng.normal(size=(2, 3))
    R = np.diag([2e-4, 5e-4])
    F = G.T @ np.linalg.solve(R, G)
    eig = float(expected_information_gain(cov, F))
    # closed form: entropy reduction of the Gaussian update (Kalman form, independent of I + Sigma F)
    post = cov - cov @ G.T @ np.linalg.solve(G @ cov @ G.T + R, G @ cov)
    closed = 0.5 * (np.linalg.slogdet(cov)[1] - np.linalg.slogdet(post)[1])
    assert eig == pytest.approx(closed, rel=1e-10)
    # Monte Carlo mutual information E[log p(y|x) - log p(y)]
    x = rng.multivariate_normal(MEAN, cov, size=40000)
    y = x @ G.T + rng.multivariate_normal(np.zeros(2), R, size=len(x))
    S = G @ cov @ G.T + R

    def logn(r, c):
        return -0.5 * np.einsum("ij,jk,ik->i", r, np.linalg.inv(c), r) - 0.5 * np.linalg.slogdet(2 * np.pi * c)[1]

    mi = logn(y - x @ G.T, R) - logn(y - MEAN @ G.T, S)
    assert eig == pytest.approx(mi.mean(), abs=4 * mi.std() / np.sqrt(len(mi)))


def test_rank_setups_eig_is_consistent_and_default_unchanged():
    material, done = (3.0, 0.5, 15.0), [Setup(40, 50)]
    default = rank_setups(material, done)
    explicit = rank_setups(material, done, criterion="perpendicularity")
    assert default.criterion == "perpendicularity" and np.array_equal(default.score, explicit.score)
    r = rank_setups(material, done, criterion="eig", covariance=COV)
    best, value = r.best()
    assert value == pytest.approx(np.nanmax(r.score)) and np.all(r.score >= 0)
    i = int(np.argmax(r.score))
    assert value == pytest.approx(float(expected_information_gain(r.covariance, r.information[i])))
    # every Fisher matrix has the same trace (one information scale), rank one-ish and PSD
    tr = np.trace(r.information, axis1=1, axis2=2)
    assert np.allclose(tr, tr[0], rtol=1e-9)
    assert np.all(np.linalg.eigvalsh(r.information).min(axis=1) > -1e-9 * tr[0])
    with pytest.raises(ValueError, match="criterion"):
        rank_setups(material, done, criterion="entropy")


def test_noise_scale_counts_components_and_misfit():
    sim = np.zeros((2, 40, 60), bool)
    cap = sim.copy()
    cap[:, 5:8, 5:9] = True  # blob 1 (12 px)
    cap[:, 20:25, 30:32] = True  # blob 2 (10 px)
    cap[0, 35, 50] = True  # a single stray pixel: below MIN_COMPONENT_PX, not counted
    ns = noise_scale([sim], [cap], discretisation=1e-3, emulator=2e-4)
    assert ns.n_eff == 4 and ns.frames == 2 and ns.n_pixels == 2 * 40 * 60
    assert ns.loss_at_optimum == pytest.approx((2 * 22 + 1) / (2 * 40 * 60))
    assert ns.variance == pytest.approx(ns.loss_at_optimum + 1.2e-3)
    assert float(ns.log_likelihood(ns.variance)) == pytest.approx(-ns.n_eff / 2)  # chi-square = N_eff at s^2


def test_noise_scale_counts_one_residual_per_frame_by_default():
    from similarity.posterior import NOISE_COUNT

    sim = np.zeros((3, 40, 60), bool)
    cap = sim.copy()
    cap[:, 5:8, 5:9] = True
    cap[:, 20:25, 30:32] = True
    ns = noise_scale([sim, sim[:2]], [cap, cap[:2]], discretisation=1e-3, method=NOISE_COUNT)
    assert NOISE_COUNT == "frames" and ns.n_eff == 5 == ns.frames
    assert float(ns.log_likelihood(ns.variance)) == pytest.approx(-2.5)


def test_cut_fraction_counts_only_faces_inside_the_material_space():
    from similarity.trust_box import EDGE, cut_fraction

    rng = np.random.default_rng(0)
    u = rng.random((200000, 3))
    lo, hi = np.array([0.2, 0.2, 0.2]), np.array([0.6, 0.6, 0.6])
    inside = 1.0 - (1.0 - 2 * EDGE) ** 3  # uniform in the box: all six faces are inner faces
    assert cut_fraction(lo + (hi - lo) * u, lo, hi) == pytest.approx(inside, abs=0.005)
    lo[0], hi[1] = 0.0, 1.0  # two faces on the material space's own boundary do not cut
    assert cut_fraction(lo + (hi - lo) * u, lo, hi) == pytest.approx(1.0 - (1 - EDGE) ** 2 * (1 - 2 * EDGE),
                                                                     abs=0.005)
    centre = 0.4 + 0.01 * rng.standard_normal((1000, 3))  # a posterior well inside its box
    assert cut_fraction(centre, np.full(3, 0.2), np.full(3, 0.6)) == 0.0


def test_correlation_area_of_block_noise():
    rng = np.random.default_rng(0)
    iid = rng.random((256, 256)) < 0.5
    assert correlation_area(iid) == pytest.approx(1.0, abs=0.3)
    blocks = np.kron(rng.random((64, 64)) < 0.5, np.ones((4, 4), bool))
    assert correlation_area(blocks) == pytest.approx(16.0, rel=0.25)


def test_emulator_recovers_a_smooth_loss_and_reports_held_out_error():
    def f(x):
        d = x - np.array([0.4, 0.5, 0.3])
        return 0.01 + d @ np.diag([2.0, 0.5, 1.0]) @ d.T if d.ndim == 1 else 0.01 + np.einsum("ij,j,ij->i", d, [2.0, 0.5, 1.0], d) + 1e-4 * np.sin(20 * x[:, 0])

    X = space_filling([0.4, 0.5, 0.3], 0.15, 64, seed=1)
    assert np.all(np.abs(X - [0.4, 0.5, 0.3]) <= 0.15 + 1e-12)
    Xt = space_filling([0.4, 0.5, 0.3], 0.12, 16, seed=2)
    emu = LossEmulator(seed=0)
    v = emu.validate(X, f(X), Xt, f(Xt))
    assert v.n_train == 64 and v.n_test == 16 and v.rmse < 0.02 * v.loss_range
    mean, sd = emu.predict(Xt[:3], return_std=True)
    assert np.allclose(mean, emu.predict(Xt[:3])) and np.all(sd >= 0)


def test_ellipsoid_and_laplace_hessian():
    e = ellipsoid(MEAN, COV, 0.9)
    lam = np.linalg.eigvalsh(COV)
    assert np.allclose(e.lengths ** 2 / 6.251388631170325, lam)  # chi2_3(0.9)
    assert np.allclose(e.axes.T @ e.axes, np.eye(3), atol=1e-12)
    prec = np.linalg.inv(COV)
    h = fd_hessian(lambda x: 0.5 * np.einsum("ij,jk,ik->i", x - MEAN, prec, x - MEAN), MEAN, 1e-3)
    assert np.allclose(h, prec, rtol=1e-6)
    assert alignment(e.thin, e.thin) == pytest.approx(1.0) and alignment(e.axes[:, 0], e.axes[:, 2]) < 1e-12


_KILLED = textwrap.dedent("""
    import os, signal, sys
    import numpy as np
    sys.path.insert(0, {root!r})
    from similarity.mcmc import sample
    calls = [0]
    def log_prob(x):
        calls[0] += 1
        if calls[0] == 301:  # about step 150: the first chunk of 100 steps is saved
            os.kill(os.getpid(), signal.SIGKILL)
        return -0.5 * np.sum(((x - 0.5) / 0.05) ** 2, axis=1)
    sample(log_prob, np.full(3, 0.5), nwalkers=16, seed=4, min_ess=1e9, max_steps=300, check_every=100,
           backend={path!r})
""")


def _log_prob(x):
    return -0.5 * np.sum(((x - 0.5) / 0.05) ** 2, axis=1)


def test_killed_run_resumes_from_its_backend(tmp_path):
    path = tmp_path / "chain.h5"
    proc = subprocess.run([sys.executable, "-c", _KILLED.format(root=str(ROOT), path=str(path))], timeout=120)
    assert proc.returncode == -9
    from similarity.mcmc import stored_chain

    done = len(stored_chain(path))
    assert done == 100  # killed mid-run (about step 150), the finished chunk kept
    resumed = sample(_log_prob, np.full(3, 0.5), nwalkers=16, seed=4, min_ess=1e9, max_steps=300, check_every=100,
                     backend=path)
    assert resumed.iterations == 300
    fresh = sample(_log_prob, np.full(3, 0.5), nwalkers=16, seed=4, min_ess=1e9, max_steps=300, check_every=100,
                   backend=tmp_path / "fresh.h5")
    chain_a, chain_b = stored_chain(path), stored_chain(tmp_path / "fresh.h5")
    assert chain_a.shape == (300, 16, 3)
    assert np.array_equal(chain_a, chain_b)  # the resumed chain is the uninterrupted one
    assert fresh.iterations == 300
    for post in (resumed, fresh):  # each kept sample carries the log-posterior emcee computed for it
        assert post.log_prob.shape == (len(post.samples),)
        np.testing.assert_allclose(post.log_prob, _log_prob(post.samples), rtol=1e-12)


def test_corrupt_backend_is_a_one_line_error(tmp_path):
    path = tmp_path / "posterior.h5"
    path.write_bytes(b"not an HDF5 file" * 10)
    with pytest.raises(ValueError, match="corrupt posterior backend") as exc:
        sample(_log_prob, np.full(3, 0.5), nwalkers=8, backend=path, max_steps=10)
    assert "\n" not in str(exc.value)


def test_gaussian_check_helper_is_truncated_to_the_box():
    post = gaussian_moments_check([0.02, 0.5, 0.5], np.eye(3) * 1e-3, nwalkers=16, seed=0, min_ess=200)
    assert post.samples.min() >= 0.0 and post.mean[0] > 0.02  # truncation at 0 pushes the mean up


def test_sampler_matches_closed_form_moments_of_a_valley_cut_by_the_box():
    """A posterior like a report's: a thin valley (standard deviations 20:1 along and across it) whose axis the box
    face x_0 = 0 cuts near its mean.  The samples' moments are checked against those of the truncated Gaussian sampled
    directly (rejection, 10^6 draws)."""
    mean = np.array([0.05, 0.3, 0.5])
    axis = np.array([1.0, 2.0, 0.5]) / np.linalg.norm([1.0, 2.0, 0.5])
    other = np.linalg.qr(np.column_stack([axis, np.eye(3)[:, :2]]))[0][:, 1:]
    basis = np.column_stack([axis, other])
    cov = basis @ np.diag([0.1, 0.005, 0.005]) ** 2 @ basis.T
    rng = np.random.default_rng(11)
    ref = rng.multivariate_normal(mean, cov, 1_000_000)
    ref = ref[np.all((ref >= 0) & (ref <= 1), axis=1)]
    post = gaussian_moments_check(mean, cov, nwalkers=32, seed=2, min_ess=2000)
    assert post.converged and post.ess >= 2000
    sd = np.sqrt(np.diag(ref.T @ ref / len(ref) - np.outer(ref.mean(0), ref.mean(0))))
    assert np.all(np.abs(post.mean - ref.mean(0)) < 5 * sd / np.sqrt(post.ess))
    assert np.allclose(np.sqrt(np.diag(post.cov)), sd, rtol=0.1)


def test_posterior_simulates_at_the_estimates_final_discretisation():
    """A coarse-to-fine run's posterior (emulator jobs, store archive, delta_disc) is built at the discretisation
    of its reported loss, the preset's finishing one, not at the coarse search model."""
    from types import SimpleNamespace

    from mpm.camera import Camera
    from similarity import posterior
    from similarity.presets import get_preset

    class Recorder:  # the forward model's service, recording the model of every call
        def __init__(self):
            self.models = []

        def losses(self, materials, experiments, model, on_result=None):
            self.models.append(model.resolved())
            return np.zeros((len(materials), len(experiments)))

        def simulated(self, experiments, model):
            self.models.append(model.resolved())
            return np.zeros((0, 3))

        def silhouettes(self, material, experiments, model):
            self.models.append(model.resolved())
            return [np.zeros((8, 54, 96), bool)] * len(experiments)

    preset = get_preset("footage")
    final = preset.final.resolved()
    assert final.cell_mm != preset.cell_mm  # the test means something only for a coarse-to-fine preset
    exp = SimpleNamespace(width_mm=30.0, height_mm=20.0, density=1000.0, depth_mm=40.0, camera=Camera.default(),
                          frames=np.zeros((8, 54, 96), bool), name="e")
    run = SimpleNamespace(experiments=[exp, exp], preset=preset, forward=Recorder(), estimate=Material(1.0, 0.5, 5.0))
    assert posterior.mean_losses(run, np.full((2, 3), 0.5)).shape == (2,)
    assert posterior.archive(run, np.full(3, 0.5), 0.1).shape == (0, 3)
    assert run.forward.models == [final, final]
    posterior.discretisation_error(run)
    assert run.forward.models[2:] == [final, replace(final, cell_mm=final.cell_mm / 2)]


def test_posterior_check_retrains_an_emulator_that_promised_too_good_a_fit():
    """The loss has a cusp along x0; a quadratic trend through training points at x0 = 0.1, 0.5, 0.9 promises
    the space between them too low a loss, and the posterior spreads there.  The check simulates posterior draws,
    finds the emulator optimistic by more than CHECK_NATS; with the draws in its training set the emulator's next
    posterior checks at least twice as well."""
    from similarity.likelihood import NoiseScale
    from similarity.emulator_check import CHECK_NATS, checked_posterior, posterior_check

    def true_loss(X):
        X = np.atleast_2d(X)
        return 0.005 + 0.02 * np.sqrt(np.abs(X[:, 0] - 0.5)) + 0.02 * ((X[:, 1] - 0.5) ** 2 + (X[:, 2] - 0.5) ** 2)

    rng = np.random.default_rng(0)
    X = np.column_stack([np.repeat([0.1, 0.5, 0.9], 8), rng.uniform(0.1, 0.9, (24, 2))])
    noise = NoiseScale(n_pixels=16_000, n_eff=16.0, loss_at_optimum=0.005, discretisation=0.0, emulator=0.0, frames=16)
    calls = []

    def losses(Xc):
        calls.append(len(Xc))
        return true_loss(Xc)

    kw = dict(split=np.random.default_rng(0), seed=0, nwalkers=16, min_ess=100, max_steps=2000)
    first, _, _ = checked_posterior(losses, X, true_loss(X), np.full(3, 0.5), np.zeros(3), np.ones(3), noise,
                                    draws=12, rounds=0, **kw)
    assert not first.check.passed and first.check.optimism_nats > 3 * CHECK_NATS and first.check.rounds == 1
    last, X2, y2 = checked_posterior(losses, X, true_loss(X), np.full(3, 0.5), np.zeros(3), np.ones(3), noise,
                                     draws=12, rounds=2, **kw)
    assert len(X2) == len(X) + sum(calls[1:]) and np.allclose(y2, true_loss(X2))  # every draw joined the training
    assert last.check.rounds == len(calls) - 1 and last.check.optimism_nats < 0.5 * first.check.optimism_nats
    # the check's arithmetic: tau times the mean of simulated minus emulated loss; a failed draw fails it
    Xc = X[:4]
    exact = posterior_check(noise, last.emulator, Xc, last.emulator.predict(Xc) + 1e-3, rounds=1)
    assert exact.optimism_nats == pytest.approx(noise.precision * 1e-3) and exact.failed == 0
    failed = posterior_check(noise, last.emulator, Xc, np.r_[last.emulator.predict(Xc[:3]), np.nan], rounds=1)
    assert failed.failed == 1 and not failed.passed


def test_emulator_error_is_measured_where_the_likelihood_reaches():
    """A smooth bowl whose far walls are rough: the emulator is accurate near the optimum and not far from it.
    e_emul counts the cross-validated errors of the training losses within REACH_NATS of the best (eq. 1 without
    e_emul), so it is the small error near the optimum, not the box-wide held-out error that would flatten the
    likelihood there."""
    from similarity.likelihood import NoiseScale
    from similarity.emulator_check import MIN_SCORED, emulator_error, within_reach
    from similarity.trust_box import REACH_NATS

    def loss(X):
        d = np.linalg.norm(X - 0.5, axis=1)
        rough = 0.01 * np.sin(30 * X[:, 0]) * np.sin(30 * X[:, 1]) * np.clip((d - 0.35) / 0.1, 0, 1)
        return 0.005 + 0.2 * d**2 + rough

    X = space_filling(np.full(3, 0.5), 0.5, 160, seed=3)
    y = loss(X)
    noise = NoiseScale(n_pixels=16_000, n_eff=4.0, loss_at_optimum=0.005, discretisation=0.0, emulator=0.0, frames=4)
    near = within_reach(y, noise)
    gap = noise.precision * (y - y.min())
    lowest = np.argsort(np.argsort(y)) < MIN_SCORED
    assert np.array_equal(near, (gap <= REACH_NATS) | lowest) and near.sum() >= MIN_SCORED
    assert np.all(np.linalg.norm(X[near] - 0.5, axis=1) < 0.35)  # the smooth part only
    v = emulator_error(X, y, noise.with_emulator(1.0), np.random.default_rng(0))  # e_emul of noise is ignored
    assert v.n_train == 160 and v.n_test == near.sum()
    test = np.random.default_rng(0).permutation(160) < 32
    box_wide = LossEmulator(seed=0).validate(X[~test], y[~test], X[test], y[test])
    assert v.rmse < 0.25 * box_wide.rmse


def test_box_grows_while_the_posterior_reaches_an_inner_face():
    """A valley that leaves the box through a saddle puts few samples at its face, but the likelihood there is
    within reach of the best: the box must grow.  A posterior that has fallen off before the faces, or that rests
    on the material space's own boundary, does not make it grow, nor does a sample at a face far below the best."""
    from similarity.trust_box import REACH_NATS, cut_fraction, reaches_a_face

    rng = np.random.default_rng(0)
    core = rng.normal(0.5, 0.02, (4000, 3))
    lo, hi = np.full(3, 0.3), np.full(3, 0.7)
    lp = -0.5 * np.sum(((core - 0.5) / 0.02) ** 2, axis=1)
    assert not reaches_a_face(core, lp, lo, hi) and cut_fraction(core, lo, hi) == 0.0
    # a thin arm of the valley reaching the face at x0 = 0.3, as likely as the core: 1 % of the samples
    arm = np.column_stack([rng.uniform(0.3, 0.5, 40), rng.normal(0.5, 0.02, (40, 2))])
    both = np.vstack([core, arm])
    lp_both = np.r_[lp, np.full(40, -1.0)]
    assert cut_fraction(both, lo, hi) < 0.02 and reaches_a_face(both, lp_both, lo, hi)
    # the same arm far below the best does not count
    assert not reaches_a_face(both, np.r_[lp, np.full(40, -REACH_NATS - 5.0)], lo, hi)
    # nor does the material space's own boundary: the prior ends there
    assert not reaches_a_face(both, lp_both, np.r_[0.0, 0.3, 0.3], hi)



def test_quadratic_features_are_the_trends():
    """The emulator's fast prediction builds the trend's features itself: exactly scikit-learn's, bit for bit."""
    from sklearn.preprocessing import PolynomialFeatures

    from surrogate.emulator import LossEmulator, quadratic_features

    X = np.random.default_rng(0).random((64, 3))
    assert np.array_equal(quadratic_features(X), PolynomialFeatures(2).fit(X).transform(X))
    emu = LossEmulator().fit(X, np.sum((X - 0.4) ** 2, axis=1))
    assert np.allclose(emu.predict(X), emu.predict(X, return_std=True)[0], rtol=1e-12, atol=1e-15)


def test_a_chain_in_emcees_own_layout_is_sampled_afresh(tmp_path):
    """A posterior.h5 group written by emcee's HDFBackend (earlier versions) is replaced, not refused."""
    import emcee

    from similarity.mcmc import stored_chain

    path = tmp_path / "posterior.h5"
    old = emcee.EnsembleSampler(16, 3, _log_prob, vectorize=True, backend=emcee.backends.HDFBackend(str(path), name="mcmc"))
    old.run_mcmc(0.5 + 0.01 * np.random.default_rng(0).standard_normal((16, 3)), 20)
    post = sample(_log_prob, np.full(3, 0.5), nwalkers=16, seed=4, min_ess=1e9, max_steps=100, check_every=100,
                  backend=path)
    assert post.iterations == 100 and stored_chain(path).shape == (100, 16, 3)


def test_the_laws_check_is_two_sided_on_each_face():
    """A law's evidence is as wrong when the emulator is pessimistic on its face as when it is optimistic: with
    groups, a face whose simulated fit is better than the emulated one by more than CHECK_NATS fails the check,
    even when another face's optimism cancels it in the mean."""
    from similarity.likelihood import NoiseScale
    from similarity.emulator_check import CHECK_NATS, posterior_check

    class Flat:
        def predict(self, X):
            return np.full(len(np.atleast_2d(X)), 0.01)

    noise = NoiseScale(n_pixels=16_000, n_eff=16.0, loss_at_optimum=0.005, discretisation=0.0, emulator=0.0, frames=16)
    X = np.full((8, 3), 0.5)
    step = 3 * CHECK_NATS / noise.precision  # three nats of loss
    y = np.r_[np.full(4, 0.01 - step), np.full(4, 0.01 + step)]  # face 0 pessimistic, face 1 optimistic
    groups = np.r_[np.zeros(4, int), np.ones(4, int)]
    pooled = posterior_check(noise, Flat(), X, y, rounds=1)
    assert pooled.passed and abs(pooled.optimism_nats) < 1e-9 and pooled.worst_face_nats is None
    split = posterior_check(noise, Flat(), X, y, rounds=1, groups=groups)
    assert not split.passed and abs(split.worst_face_nats) == pytest.approx(3 * CHECK_NATS)
    close = posterior_check(noise, Flat(), X, 0.01 + 0.5 * (y - 0.01) / 3, rounds=1, groups=groups)
    assert close.passed and abs(close.worst_face_nats) == pytest.approx(0.5 * CHECK_NATS)
    assert not posterior_check(noise, Flat(), X, np.r_[y[:7], np.nan] * 0 + 0.01, rounds=1, groups=groups).passed


def test_a_laws_check_whose_every_draw_failed_fails_without_a_face_figure():
    from similarity.likelihood import NoiseScale
    from similarity.emulator_check import posterior_check

    class Flat:
        def predict(self, X):
            return np.full(len(np.atleast_2d(X)), 0.01)

    noise = NoiseScale(n_pixels=16_000, n_eff=16.0, loss_at_optimum=0.005, discretisation=0.0, emulator=0.0, frames=16)
    check = posterior_check(noise, Flat(), np.full((4, 3), 0.5), np.full(4, np.nan), rounds=1, groups=np.arange(4) % 2)
    assert not check.passed and check.failed == 4 and check.worst_face_nats is None


def test_a_saved_chain_resumes_only_in_its_own_box(tmp_path):
    """The same training set in a smaller and a larger box: each box samples its own chain from the same backend
    file (a chain of the smaller box resumed in the larger would keep the smaller box's cut)."""
    import h5py

    from similarity.emulator_check import checked_posterior
    from similarity.likelihood import NoiseScale

    rng = np.random.default_rng(1)
    X = rng.uniform(0.2, 0.8, (30, 3))
    y = 0.005 + 0.02 * np.sum((X - 0.5) ** 2, axis=1)
    noise = NoiseScale(n_pixels=16_000, n_eff=16.0, loss_at_optimum=0.005, discretisation=0.0, emulator=0.0, frames=16)
    path = tmp_path / "posterior.h5"
    kw = dict(draws=0, seed=0, nwalkers=16, min_ess=100, max_steps=2000, backend=path)
    small, _, _ = checked_posterior(None, X, y, np.full(3, 0.5), np.full(3, 0.45), np.full(3, 0.55), noise,
                                    split=np.random.default_rng(0), **kw)
    large, _, _ = checked_posterior(None, X, y, np.full(3, 0.5), np.full(3, 0.2), np.full(3, 0.8), noise,
                                    split=np.random.default_rng(0), **kw)
    with h5py.File(path, "r") as f:
        assert len([k for k in f if k.startswith("mcmc-")]) == 2
    assert small.posterior.samples.max() <= 0.55 and large.posterior.samples.max() > 0.55


def test_the_emulators_fast_prediction_is_scikit_learns_bit_for_bit():
    """MCMC calls the emulator's own kernel arithmetic: its kernel must be scikit-learn's bit for bit and its mean
    scikit-learn's GP mean, for hyperparameters searched on a subset of the losses, on all of them, and kept from an
    earlier fit."""
    from surrogate.emulator import LossEmulator

    rng = np.random.default_rng(3)
    X = rng.random((150, 3))
    y = np.sum((X - 0.4) ** 2 * [1.0, 5.0, 0.2], axis=1) + 1e-3 * rng.standard_normal(150)
    Q = rng.random((37, 3))
    for emu in (LossEmulator(seed=2).fit(X, y), LossEmulator(seed=2).fit(X[:90], y[:90]),
                LossEmulator(seed=1).fit(X, y, theta=LossEmulator(seed=1).fit(X, y).gp.kernel_.theta)):
        reference = emu.trend.predict(Q) + emu.gp.predict(Q)
        fast = emu.predict(Q)
        assert np.array_equal(emu._signal(Q), emu.gp.kernel_.k1(Q, emu.gp.X_train_))
        assert np.allclose(fast, reference, rtol=1e-13, atol=1e-16)
