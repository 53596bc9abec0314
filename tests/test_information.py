"""Realised information of a setup (similarity.information): the PSD projection of a known matrix, the log det gain
of a known and of an orthogonal direction, the normalised score's fixed points, the sign test on a known case, and
Spearman on a known ranking."""
import numpy as np
import pytest
from scipy.stats import binom

from similarity import information as I
from similarity.fd_hessian import stencil


def _rotation(seed):
    q, _ = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    return q


def test_setup_hessian_is_the_psd_part_of_the_fd_hessian_of_a_quadratic():
    v = _rotation(0)
    h = v @ np.diag([40.0, 3.0, -5.0]) @ v.T  # one direction curves down: it pins nothing
    offsets = stencil(I.STEP)
    losses = 0.5 * np.einsum("ij,jk,ik->i", offsets, h, offsets)  # central differences are exact on a quadratic
    got = I.setup_hessian(losses)
    np.testing.assert_allclose(got, v @ np.diag([40.0, 3.0, 0.0]) @ v.T, atol=1e-9)
    assert np.all(np.linalg.eigvalsh(got) >= -1e-12)


def test_log_det_gain_of_a_known_direction_is_small_and_of_an_orthogonal_one_large():
    e = np.eye(3)
    h_done = 100.0 * np.outer(e[0], e[0]) + 50.0 * np.outer(e[1], e[1])  # the third direction unknown
    same = 100.0 * np.outer(e[0], e[0])
    orthogonal = 100.0 * np.outer(e[2], e[2])
    eps = I.ridge(h_done)
    assert eps == pytest.approx(I.RIDGE * 100.0)
    g_same, g_orth = I.log_det_gain(h_done, np.stack([same, orthogonal]))
    assert g_same == pytest.approx(np.log(201.0 / 101.0))  # doubling a known direction: log 2, no more
    assert g_orth == pytest.approx(np.log(101.0))  # the unknown direction: from eps to eps + 100
    assert g_orth > 6 * g_same
    # the smallest eigenvalue rises only through the unknown direction
    np.testing.assert_allclose(I.min_eig_gain(h_done, np.stack([same, orthogonal])), [0.0, 50.0])
    # the direction alone: a candidate 10x larger along the same axis gains the same as the unscaled one
    np.testing.assert_allclose(I.shape_gain(h_done, np.stack([same, 10 * same])), I.shape_gain(h_done, same))


def test_ridge_needs_information():
    with pytest.raises(ValueError, match="no information"):
        I.ridge(np.zeros((3, 3)))


def test_normalised_score_is_one_for_the_best_and_zero_at_the_mean():
    c = np.array([1.0, 2.0, 3.0, 6.0])
    assert I.normalised_score(6.0, c) == 1.0
    assert I.normalised_score(3.0, c) == 0.0
    assert I.normalised_score(1.0, c) == pytest.approx(-2.0 / 3.0)
    assert I.normalised_score(8.0, c, best=8.0) == 1.0  # a pick beyond the seeded set is the best
    assert np.isnan(I.normalised_score(1.0, [1.0, 1.0]))


def test_sign_test_on_a_known_case():
    scores = [0.9, 0.5, 0.2, 1.0, -0.3, 0.7, 0.8, 0.1, 0.6, 0.4, 0.0, np.nan]  # 9 wins, 1 loss, 2 undecided
    wins, decided, p = I.sign_test(scores)
    assert (wins, decided) == (9, 10)
    assert p == pytest.approx(binom.sf(8, 10, 0.5)) and p == pytest.approx(11 / 1024)


def test_rank_agreement():
    r = np.array([0.1, 0.5, 0.2, 0.9, 0.3])
    assert I.rank_agreement(r, 3 * r + 1) == pytest.approx(1.0)
    assert I.rank_agreement(-r, r) == pytest.approx(-1.0)
    assert np.isnan(I.rank_agreement([1.0, 1.0, 1.0], r[:3]))


@pytest.fixture
def fake_forward(monkeypatch):
    import sys
    from pathlib import Path

    from mpm.forward import Forward

    tests = str(Path(__file__).resolve().parent)
    if tests not in sys.path:
        monkeypatch.syspath_prepend(tests)
    with Forward(None, workers=0, simulator="fake_forward:simulate") as fw:
        yield fw


def test_predicted_gain_at_the_truth_is_the_realised_gain_and_a_repeat_adds_a_known_amount(fake_forward):
    """Predicted at the estimate = realised when the estimate is the truth (the same simulations); filming the done
    setup again doubles its Hessian, so its gain is sum log((2 lambda + eps) / (lambda + eps)) over H's eigenvalues."""
    from mpm.params import Material, Setup
    from similarity.presets import get_preset

    truth, first = Material(4.0, 0.6, 8.0), Setup(29.0, 59.0)
    others = [Setup(70.0, 70.0), Setup(20.0, 20.0)]
    preset = get_preset("demo")
    pred = I.predicted_gains(truth, [first], [first] + others, preset=preset, forward=fake_forward)
    hs = I.setup_hessians(I.stencil_losses(truth, [first] + others, preset=preset, fd_step=I.STEP,
                                           forward=fake_forward))
    np.testing.assert_allclose(pred[1:], I.realised_gains(hs[0], hs[1:]), rtol=1e-12)
    lam = np.linalg.eigvalsh(hs[0])
    eps = I.RIDGE * lam[-1]
    assert pred[0] == pytest.approx(np.sum(np.log((2 * lam + eps) / (lam + eps))), rel=1e-9)
    assert np.all(np.isfinite(pred)) and np.all(pred > 0)


def test_an_estimate_on_a_face_of_the_space_is_moved_inward_by_the_step(fake_forward):
    """Every probe of the stencil must be a material of the space: an estimate with sigma_y = 0 (a face) is scored
    as the material one step inside it."""
    from mpm.params import Material, Setup
    from similarity.presets import get_preset
    from similarity.space import denormalize, normalize

    face = Material(4.0, 0.6, 0.0)
    u = normalize(face.as_array())
    inside = Material.from_array(denormalize(np.clip(u, I.STEP, 1 - I.STEP)))
    kw = dict(preset=get_preset("demo"), forward=fake_forward)
    setups = [Setup(70.0, 70.0), Setup(40.0, 20.0)]
    np.testing.assert_array_equal(I.predicted_gains(face, [Setup(29.0, 59.0)], setups, **kw),
                                  I.predicted_gains(inside, [Setup(29.0, 59.0)], setups, **kw))


def _noise(frames=8, misfit=2e-3, disc=1e-3, emul=5e-4):
    from similarity.likelihood import NoiseScale

    return NoiseScale(frames * 1000, float(frames), misfit, disc, emul, frames)


def test_a_new_setups_noise_keeps_the_runs_misfit_and_residuals_per_frame_and_takes_its_own_discretisation():
    run = _noise(frames=16)
    new = run.for_new_setup(8, 4e-3)
    assert new.frames == 8 and new.n_eff == pytest.approx(8.0) and new.n_pixels == 8000
    assert new.variance == pytest.approx(2e-3 + 4e-3 + 5e-4)
    assert new.precision == pytest.approx(8.0 / (2 * (2e-3 + 4e-3 + 5e-4)))  # tau = N_eff / (2 s^2), eq. (1)
    h = np.diag([3.0, 2.0, 1.0])
    np.testing.assert_allclose(I.fisher_information(h, new), new.precision * h)


def test_the_information_check_agrees_where_the_posterior_is_the_laplace_posterior_of_the_hessians():
    """Sigma^-1 = 12 I + tau H_done: the setups done carry the same nats by their Hessians and in the posterior."""
    from similarity.simulated_design import information_check

    v = _rotation(3)
    h = v @ np.diag([900.0, 40.0, 2.0]) @ v.T
    noise = _noise()
    cov = np.linalg.inv(12.0 * np.eye(3) + noise.precision * h)
    c = information_check(h, noise, cov)
    assert c.hessian_nats == pytest.approx(c.posterior_nats, rel=1e-9) and c.scale == pytest.approx(1.0, rel=1e-6)
    assert c.posterior_nats == pytest.approx(0.5 * np.sum(np.log(1 + noise.precision * np.array([900, 40, 2]) / 12)))
    # a posterior twice as precise in every direction carries 3/2 log 2 nats more than the Hessians say; the factor
    # that makes them carry it is the one that solves the same equation
    sharper = information_check(h, noise, cov / 2)
    assert sharper.posterior_nats - c.hessian_nats == pytest.approx(1.5 * np.log(2))
    prior = np.eye(3) / 12.0
    lam = np.linalg.eigvalsh(prior @ (sharper.scale * noise.precision * h))
    assert 0.5 * np.sum(np.log1p(lam)) == pytest.approx(sharper.posterior_nats, rel=1e-8) and sharper.scale > 1
    # a posterior no narrower than the prior: no factor, so no nats
    assert information_check(h, noise, np.eye(3) / 6.0).scale is None


def test_with_a_posterior_the_criterion_scores_in_nats_each_setup_weighted_by_its_own_noise(monkeypatch):
    """The information criterion with a posterior's covariance and noise: each candidate's score is
    1/2 log det(I + Sigma tau_c H_c) with tau_c from its own discretisation; a noisier setup scores lower than the same
    Hessian with less noise would."""
    from mpm.params import Material, Setup
    from similarity import simulated_design as design
    from similarity.fd_hessian import stencil as stencil_offsets

    rng = np.random.default_rng(5)
    mats = {}

    def stencil(truth, setups, **kw):  # a quadratic loss per setup: its Hessian is known exactly
        out = []
        for s in setups:
            a = rng.normal(size=(3, 3)) if str(s) not in mats else None
            if a is not None:
                mats[str(s)] = a @ a.T * s.width_mm * s.height_mm / 400.0
            o = stencil_offsets(I.STEP)
            out.append(0.5 * np.einsum("ij,jk,ik->i", o, mats[str(s)], o))
        return np.array(out)

    deltas = {}

    def noises(estimate, setups, noise, **kw):
        return [noise.for_new_setup(8, deltas.setdefault(str(s), 1e-4 * s.width_mm)) for s in setups]

    monkeypatch.setattr(I, "stencil_losses", stencil)
    monkeypatch.setattr(I, "candidate_noise", noises)
    monkeypatch.setattr(design, "_FactCollector", lambda center, tick=None: type(
        "F", (), {"__call__": lambda self, *a: None, "facts": lambda self: {}})())
    material, done = Material(3.0, 0.6, 5.0), [Setup(29.0, 59.0)]
    noise = _noise()
    cov = np.linalg.inv(12.0 * np.eye(3) + 50.0 * np.eye(3))
    r = design.rank_by_simulation(material, done, forward=None, covariance=cov, noise=noise)
    assert r.nats and r.check is not None and len(r) == 16
    assert r.check.scale is not None and r.check.scale > 0
    for w, h, score in zip(r.width_mm, r.height_mm, r.score):
        s = Setup(w, h)
        tau = r.check.scale * noise.for_new_setup(8, deltas[str(s)]).precision
        hs = I.setup_hessian(stencil(material, [s])[0])
        assert score == pytest.approx(0.5 * np.linalg.slogdet(np.eye(3) + cov @ (tau * hs))[1], rel=1e-9)
    deltas.update({k: 10 * v for k, v in deltas.items()})  # every setup noisier: every score lower
    noisier = design.rank_by_simulation(material, done, forward=None, covariance=cov, noise=noise)
    assert np.all(noisier.score < r.score)
    unweighted = design.rank_by_simulation(material, done, forward=None)
    assert not unweighted.nats and unweighted.check is None
    with pytest.raises(ValueError, match="both the posterior's covariance and its noise"):
        design.rank_by_simulation(material, done, forward=None, covariance=cov)


def test_a_run_without_a_discretisation_term_gives_its_candidates_none(fake_forward):
    """`virheo report --no-discretisation`: the run's noise has delta_disc = 0, and so has every candidate's (nothing is
    simulated at half the cell width); with the term, each candidate's is its own simulated loss."""
    from mpm.params import Material, Setup
    from similarity.presets import get_preset

    setups, preset = [Setup(70.0, 70.0), Setup(30.0, 20.0)], get_preset("demo")
    zero = I.candidate_noise(Material(4.0, 0.6, 8.0), setups, _noise(disc=0.0), preset=preset, forward=fake_forward)
    assert [z.discretisation for z in zero] == [0.0, 0.0] and all(z.frames == 8 for z in zero)
    own = I.candidate_noise(Material(4.0, 0.6, 8.0), setups, _noise(), preset=preset, forward=fake_forward)
    center = I.interior(Material(4.0, 0.6, 8.0))
    from similarity.emulation import emulate

    expected = I.discretisation_losses(center, emulate(center, setups, preset=preset, forward=fake_forward),
                                       preset.final, fake_forward)
    assert [z.discretisation for z in own] == pytest.approx(expected)
