"""The laws' evidence (similarity/evidence.py) against closed forms, and the verdicts' wording at the thresholds."""
import numpy as np
import pytest
from scipy.stats import norm, truncnorm

from similarity.evidence import (LAWS, N_ONE, QUESTIONS, RESOLVED, SIGMA_Y_ZERO, face_posterior, law_evidence,
                                 parse_laws, strength, summarise, verdict)


def gaussian(mu, sd):
    mu, sd = np.asarray(mu, float), np.asarray(sd, float)
    return lambda x: -0.5 * np.sum(((np.atleast_2d(x) - mu) / sd) ** 2, axis=1)


def box_log_z(mu, sd, lo, hi):
    """ln of the integral of exp(-|x - mu|^2 / (2 sd^2)) over the box [lo, hi]."""
    return float(np.sum(np.log(sd * np.sqrt(2 * np.pi) * (norm.cdf((hi - mu) / sd) - norm.cdf((lo - mu) / sd)))))


def test_face_values_are_the_special_laws():
    from similarity.space import denormalize

    assert denormalize([0.3, N_ONE, SIGMA_Y_ZERO])[1:] == pytest.approx([1.0, 0.0])
    assert LAWS["newtonian"].free == (0,) and LAWS["bingham"].free == (0, 2) and LAWS["power-law"].free == (0, 1)


@pytest.mark.parametrize("mu, sd", [([0.31, 0.97, 0.02], [0.004, 0.03, 0.015]),  # cut by two faces of the space
                                    ([0.5, 0.5, 0.5], [0.05, 0.1, 0.08])])  # inside
def test_gaussian_in_a_box_all_four_laws(mu, sd):
    mu, sd = np.array(mu), np.array(sd)
    lo, hi = np.clip(mu - 6 * sd, 0, 1), np.clip(mu + 6 * sd, 0, 1)
    lo[1], hi[2] = min(lo[1], N_ONE), hi[2]
    hi[1], lo[2] = N_ONE, SIGMA_Y_ZERO  # the box reaches the n = 1 and sigma_y = 0 faces
    ll = gaussian(mu, sd)
    a, b = (lo - mu) / sd, (hi - mu) / sd
    samples = truncnorm.rvs(a, b, loc=mu, scale=sd, size=(4000, 3), random_state=1)
    for law in LAWS.values():
        ev, _ = law_evidence(ll, law, lo, hi, samples=samples if not law.fixed else None, seed=3)
        free = list(law.free)
        exact = box_log_z(mu[free], sd[free], lo[free], hi[free])
        exact += sum(-0.5 * ((v - mu[i]) / sd[i]) ** 2 for i, v in law.fixed)
        assert ev.log_z_err < 0.05, law.name
        assert abs(ev.log_z - exact) < 4 * ev.log_z_err + 1e-3, (law.name, ev.log_z, exact, ev.log_z_err)


@pytest.mark.parametrize("law, mu, sd", [("power-law", [0.3, 0.6], [0.1, 0.2]),  # wide, cut by the box
                                         ("bingham", [0.41, 0.7], [2e-4, 5e-3]),  # far narrower than a first-grid cell
                                         ("newtonian", [0.123], [3e-5])])
def test_face_posterior_matches_a_gaussian_on_the_face(law, mu, sd):
    """The face's grid posterior has the moments of a Gaussian likelihood on the face (truncated by the box), however
    narrow: the grid zooms onto it."""
    law = LAWS[law]
    mu, sd = np.array(mu), np.array(sd)
    full_mu, full_sd = np.full(3, 0.5), np.ones(3)
    full_mu[list(law.free)], full_sd[list(law.free)] = mu, sd
    lo, hi = np.zeros(3), np.ones(3)
    z = face_posterior(gaussian(full_mu, full_sd), law, lo, hi, seed=4)
    a, b = (0 - mu) / sd, (1 - mu) / sd
    mean, var = truncnorm.stats(a, b, loc=mu, scale=sd, moments="mv")
    assert z.shape[1] == len(mu) and np.all((z >= 0) & (z <= 1))
    assert np.abs(z.mean(axis=0) - mean) == pytest.approx(0, abs=0.05 * float(np.max(sd)))
    assert z.std(axis=0) == pytest.approx(np.sqrt(var), rel=0.05)


def test_face_posterior_sees_both_of_two_distant_modes():
    """Two equal narrow modes on the power law's face, far apart: the grid holds half its draws in each (a sampler
    started at one of them keeps to it)."""
    law = LAWS["power-law"]
    one, two = gaussian([0.2, 0.2, 0.0], [0.01, 0.01, 1.0]), gaussian([0.8, 0.7, 0.0], [0.01, 0.01, 1.0])
    z = face_posterior(lambda x: np.logaddexp(one(x), two(x)), law, np.zeros(3), np.ones(3), seed=5)
    near_one = np.all(np.abs(z - [0.2, 0.2]) < 0.06, axis=1)
    near_two = np.all(np.abs(z - [0.8, 0.7]) < 0.06, axis=1)
    assert np.all(near_one | near_two) and abs(near_one.mean() - 0.5) < 0.03


def test_linear_sub_model_closed_form():
    """y = A theta + noise; the power law's face (sigma_y coordinate at 0) is a linear sub-model.  Both evidences
    are Gaussian integrals: the general one cut by the face theta_2 >= 0, the sub-model's whole."""
    rng = np.random.default_rng(7)
    t = np.linspace(0, 1, 40)
    A = np.column_stack([np.ones_like(t), t, t**2])
    truth = np.array([0.4, 0.6, 0.0])
    s = 0.05
    y = A @ truth + s * rng.standard_normal(len(t))

    def ll(x):
        r = y[None] - np.atleast_2d(x) @ A.T
        return -0.5 * np.sum(r * r, axis=1) / s**2

    H = A.T @ A / s**2
    theta = np.linalg.solve(A.T @ A, A.T @ y)
    cov = np.linalg.inv(H)
    exact_general = (ll(theta)[0] + 1.5 * np.log(2 * np.pi) - 0.5 * np.linalg.slogdet(H)[1]
                     + norm.logcdf(theta[2] / np.sqrt(cov[2, 2])))
    Hf = H[:2, :2]
    theta_f = np.linalg.solve(A[:, :2].T @ A[:, :2], A[:, :2].T @ y)
    exact_special = ll(np.r_[theta_f, 0.0])[0] + np.log(2 * np.pi) - 0.5 * np.linalg.slogdet(Hf)[1]
    lo, hi = np.zeros(3), np.ones(3)
    assert SIGMA_Y_ZERO == 0.0
    draws = rng.multivariate_normal(theta, cov, 20000)
    general, _ = law_evidence(ll, LAWS["herschel-bulkley"], lo, hi, seed=1, samples=draws[draws[:, 2] >= 0][:4000])
    special, _ = law_evidence(ll, LAWS["power-law"], lo, hi, seed=2)
    for ev, exact in ((general, exact_general), (special, exact_special)):
        assert abs(ev.log_z - exact) < 4 * ev.log_z_err + 1e-3, (ev.law, ev.log_z, exact, ev.log_z_err)
    # the data were made on the face: the sub-model wins (Occam), and the verdict says sigma_y = 0 or not resolved
    summary = summarise([general, special], lo, hi)
    assert summary.verdicts[0].log_bf == pytest.approx(exact_general - exact_special, abs=0.1)
    assert summary.probabilities["power-law"] > summary.probabilities["herschel-bulkley"]


def test_the_box_must_reach_the_face():
    lo, hi = np.full(3, 0.3), np.full(3, 0.7)
    with pytest.raises(ValueError, match="does not reach the bingham face"):
        law_evidence(gaussian([0.5] * 3, [0.1] * 3), LAWS["bingham"], lo, hi)


def test_jeffreys_grades_at_their_thresholds():
    assert strength(np.log(100.0)) == "decisive" and strength(np.log(100.0) - 1e-9) == "very strong"
    assert strength(-np.log(10.0**1.5)) == "very strong" and strength(np.log(10.0**1.5) - 1e-9) == "strong"
    assert strength(RESOLVED) == "strong" and strength(RESOLVED - 1e-9) == "substantial"
    assert strength(np.log(10.0**0.5) - 1e-9) == "barely worth mentioning" and strength(0.0) == "barely worth mentioning"


def test_verdict_wording_at_the_thresholds():
    yield_stress = QUESTIONS[0]
    v = verdict(yield_stress, 7.3, 0.2)
    assert v.text == "yield stress: resolved, sigma_y > 0 decisively (log BF +7.30 ± 0.20)" and v.holds
    v = verdict(yield_stress, -RESOLVED, 0.1)
    assert v.resolved and v.holds is False and v.text.startswith("yield stress: resolved, sigma_y = 0 strongly")
    v = verdict(yield_stress, RESOLVED - 1e-6, 0.1, next_setup="70x70")
    assert not v.resolved and v.holds is None
    assert v.text == "yield stress: not resolved by these setups (log BF +2.30 ± 0.10, substantial); film 70x70 mm " \
                     "next (the design's next setup)"
    # a next setup already filmed is filmed again
    assert verdict(yield_stress, 0.4, 0.1, next_setup="70x70", filmed=["51x25", "70x70"]).text.endswith(
        "film 70x70 mm again (the design's next setup)")
    assert verdict(QUESTIONS[1], -5.0, 0.3).text == "shear thinning: resolved, n = 1 decisively (log BF -5.00 ± 0.30)"


def test_law_names():
    assert [law.name for law in parse_laws("bingham, newtonian,bingham")] == ["herschel-bulkley", "bingham", "newtonian"]
    with pytest.raises(ValueError, match="unknown law 'casson': choose from herschel-bulkley, bingham"):
        parse_laws("bingham,casson")


def test_the_emulators_box_doubles_to_the_whole_space_which_replaces_half_widths_from_0_8():
    from similarity.trust_box import box_widths

    assert box_widths(0.1) == [0.1, 0.2, 0.4, 1.0]
    assert box_widths(0.5) == [0.5, 1.0] and box_widths(0.3) == pytest.approx([0.3, 0.6, 1.0])
    assert box_widths(0.8) == [1.0] and box_widths(1.0) == [1.0]


def test_the_emulators_box_starts_at_the_first_width_that_reaches_every_laws_face():
    from similarity.trust_box import box_widths, first_box
    from surrogate.emulator import box

    widths = box_widths(0.1)
    special = [LAWS[name] for name in ("bingham", "power-law", "newtonian")]
    rng = np.random.default_rng(7)
    for x in [*rng.random((200, 3)), np.array([0.5, N_ONE, SIGMA_Y_ZERO]), np.zeros(3), np.ones(3)]:
        k = first_box(x, widths, special)
        reach = [all(law.on_face(*box(x, w)) for law in special) for w in widths]
        # the first width that reaches both faces (n = 1, sigma_y = 0), or the last
        assert k == (reach.index(True) if any(reach) else len(widths) - 1)
        assert first_box(x, widths, [LAWS["herschel-bulkley"]]) == 0
    assert first_box(np.array([0.5, N_ONE - 0.15, SIGMA_Y_ZERO + 0.3]), widths, special) == 2


def test_an_emulator_fitted_again_with_its_hyperparameters_predicts_the_same():
    from surrogate.emulator import SEARCH_SUBSET, LossEmulator, frozen

    rng = np.random.default_rng(3)
    X = rng.random((SEARCH_SUBSET + 80, 3))
    y = (X - 0.4) @ np.diag([3.0, 1.0, 0.5]) @ (X - 0.4).T
    y = np.diag(y) + 0.05 * np.sin(9 * X[:, 0]) + 1e-4 * rng.standard_normal(len(X))
    emu = LossEmulator(seed=1).fit(X, y)
    again = LossEmulator(seed=1).fit(X, y, theta=emu.gp.kernel_.theta)
    Q = rng.random((50, 3))
    assert np.allclose(again.predict(Q), emu.predict(Q), rtol=0, atol=1e-12)
    assert frozen(emu.gp.kernel_).n_dims == 0 and np.allclose(frozen(emu.gp.kernel_).theta, [])
    # the fit searched on a subset and refined on all: its hyperparameters are an optimum of every loss's likelihood
    lml, grad = emu.gp.log_marginal_likelihood(emu.gp.kernel_.theta, eval_gradient=True)
    free = (emu.gp.kernel_.theta > emu.gp.kernel_.bounds[:, 0] + 1e-6) & (
        emu.gp.kernel_.theta < emu.gp.kernel_.bounds[:, 1] - 1e-6)
    assert np.all(np.abs(grad[free]) < 1e-2 * max(1.0, abs(lml)))


def test_a_mode_on_a_face_that_the_posterior_sampler_missed_still_counts_in_the_general_laws_evidence():
    """Two Gaussian modes of equal mass: one inside the space (where the Herschel-Bulkley posterior's walkers started
    and stayed) and one pressed against the n = 1 face.  law_evidences integrates the general law with a proposal that
    also covers the special laws' posteriors on their faces, so its ln Z is the exact one of both modes (the interior
    samples alone miss about ln 2)."""
    from scipy.special import logsumexp

    from similarity.law_evidence import law_evidences

    sd = np.array([0.01, 0.01, 0.01])
    mu_in, mu_face = np.array([0.3, 0.6, 0.4]), np.array([0.5, N_ONE - 0.005, 0.3])
    mass_face = float(norm.cdf(0.5))  # mu_face's n-marginal inside the space
    log_norm = -1.5 * np.log(2 * np.pi) - np.sum(np.log(sd))

    def log_like(x):
        x = np.atleast_2d(x)
        a = log_norm - 0.5 * np.sum(((x - mu_in) / sd) ** 2, axis=1)
        b = log_norm - 0.5 * np.sum(((x - mu_face) / sd) ** 2, axis=1) - np.log(mass_face)  # equal masses
        return np.logaddexp(a, b)

    class Noise:
        def log_likelihood(self, loss):
            return -np.asarray(loss)

    class Emulator:
        def predict(self, x):
            return -log_like(x)

    lo, hi = np.zeros(3), np.ones(3)
    inside = np.random.default_rng(2).normal(mu_in, sd, (4000, 3))
    laws = parse_laws("bingham")
    (general, special), why, faces = law_evidences(laws, Noise(), Emulator(), inside, lo, hi, seed=5)
    assert why is None and len(faces) == 1
    assert abs(general.log_z - np.log(2.0)) < 4 * general.log_z_err + 0.02, general
    alone, _ = law_evidence(log_like, LAWS["herschel-bulkley"], lo, hi, samples=inside, seed=5)
    assert alone.log_z < np.log(2.0) - 0.3  # what the interior samples give without the faces'
    exact_face = logsumexp([log_norm - 0.5 * np.sum(((np.array([0.5, N_ONE, 0.3]) - m) / sd)[[1]] ** 2)
                            + np.log(2 * np.pi) + np.sum(np.log(sd[[0, 2]])) for m in (mu_face,)]) - np.log(mass_face)
    assert abs(special.log_z - exact_face) < 4 * special.log_z_err + 0.02
