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
