"""The best simulated fit against the estimate (similarity/best_fit.py): which material, which face, how many nats."""
import numpy as np

from similarity.best_fit import NOTE_NATS, BestFit, best_fit
from similarity.evidence import N_ONE, SIGMA_Y_ZERO, parse_laws
from similarity.space import denormalize

LAWS = parse_laws("herschel-bulkley,bingham,power-law,newtonian")


def test_the_lowest_finite_loss_wins_and_its_nats_follow_eq_1():
    rng = np.random.default_rng(3)
    X = rng.uniform(0.05, 0.95, (40, 3))
    y = rng.uniform(0.004, 0.02, 40)
    y[[3, 17]] = np.nan  # failed simulations never win
    y[11] = 0.0031
    fit = best_fit(X, y, estimate_loss=0.0053, precision=1500.0, laws=LAWS)
    assert np.allclose(fit.material.as_array(), denormalize(X[11]))
    assert fit.loss == 0.0031 and fit.estimate_loss == 0.0053
    assert np.isclose(fit.nats, 1500.0 * (0.0053 - 0.0031)) and fit.better
    assert fit.law == "herschel-bulkley" and "(on the" not in fit.text and "(3.3 nats better)" in fit.text
    assert best_fit(X, np.full(40, np.nan), 0.005, 1500.0, LAWS) is None


def test_the_face_named_is_the_narrowest_law_the_best_material_holds():
    x = np.array([[0.3, 0.6, 0.4]])
    for n, sigma_y, law in [(0.6, 0.4, "herschel-bulkley"), (N_ONE, 0.4, "bingham"), (0.6, SIGMA_Y_ZERO, "power-law"),
                            (N_ONE, SIGMA_Y_ZERO, "newtonian")]:
        x[0, 1:] = n, sigma_y
        fit = best_fit(x, [0.003], 0.004, 1000.0, LAWS)
        assert fit.law == law
        assert (f"(on the {law} face)" in fit.text) == (law != "herschel-bulkley")


def test_a_fit_within_the_noise_or_worse_is_no_news_and_the_record_round_trips():
    x = np.full((1, 3), 0.5)
    just_below = best_fit(x, [0.004], 0.004 + 0.99 * NOTE_NATS / 1000.0, 1000.0, LAWS)
    assert not just_below.better
    assert best_fit(x, [0.004], 0.004 + 1.01 * NOTE_NATS / 1000.0, 1000.0, LAWS).better
    worse = best_fit(x, [0.006], 0.004, 1000.0, LAWS)  # the estimate itself fits better: negative nats
    assert worse.nats < 0 and not worse.better
    assert BestFit.from_dict(worse.to_dict()) == worse


def test_the_report_page_says_it_only_where_the_fit_is_better():
    from studies.html_report import better_fit_html

    x = np.array([[0.3, 1.0, 0.4]])
    x[0, 1] = N_ONE
    better = best_fit(x, [0.0039], 0.0061, 1000.0, LAWS)
    html = better_fit_html(better)
    assert html.startswith("<p><b>A better fit than the estimate was simulated") and "(on the bingham face)" in html
    assert "2.2 nats better" in html
    assert better_fit_html(best_fit(x, [0.0039], 0.0040, 1000.0, LAWS)) == "" and better_fit_html(None) == ""
