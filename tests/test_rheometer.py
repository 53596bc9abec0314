"""Rheometer flow curves: reading the instrument export, SI conversion, Herschel-Bulkley fit, CLI."""
import numpy as np
import pytest

from mpm.params import Material
from studies.cli import main
from surrogate.rheometer import fit_herschel_bulkley, log_stress_rms, read_flow_curve

HEADER = ["テスト:\t{name}", "結果:\t粘度測定", "インターバル:\t1",
          "ポイント No.\t時間\tせん断速度\tせん断応力\t粘度\tトルク\t温度", "\t\t\t\t\t\t",
          "\t[s]\t[1/s]\t[Pa]\t[mPa·s]\t[mN·m]\t[°C]"]


def write_export(path, material, rates, noise=None):
    """A file in the instrument's format (UTF-16 LE with BOM, tabs, CRLF) for a known flow curve."""
    stress = material.stress(rates) * (1 if noise is None else noise)
    lines = [h.format(name=path.stem) for h in HEADER]
    for k, (r, s) in enumerate(zip(rates, stress), start=1):
        lines.append(f"{k}\t{60 + 10 * k}\t{r:.6g}\t{s:.8g}\t{1e3 * s / r:.8g}\t{s * 4.6e-3:.6g}\t23.00")
    path.write_bytes("\r\n".join(lines + [""]).encode("utf-16"))
    return path


@pytest.fixture(scope="module")
def curves(shared_data):
    files = sorted((shared_data / "rheometer").glob("*.csv"))
    assert len(files) == 4
    return [read_flow_curve(f) for f in files]


def test_reads_shared_exports_in_si(curves):
    names = {c.material_name for c in curves}
    assert names == {"moisturizing milk", "Japanese thickened Worcestershire sauce", "Japanese cabbage pancake sauce", "lotion"}
    for c in curves:
        assert len(c) == 21 and list(c.point) == list(range(1, 22))
        np.testing.assert_allclose(c.shear_rate[[0, 10, 20]], [0.1, 10.0, 1000.0])
        assert np.all(np.diff(c.shear_rate) > 0) and np.all(np.diff(c.time_s) > 0)
        # viscosity column (mPa s in the file) is stress / rate in Pa s after conversion; the file prints
        # the rates to 3 digits, the instrument used 5 per decade exactly
        np.testing.assert_allclose(c.shear_rate, np.geomspace(0.1, 1000, 21), rtol=4e-3)
        np.testing.assert_allclose(c.viscosity, c.shear_stress / np.geomspace(0.1, 1000, 21), rtol=1e-3)
        np.testing.assert_allclose(c.temperature_k, 296.15, atol=0.5)
        assert np.all((c.torque > 1e-6) & (c.torque < 1e-2))  # N m (the file has mN m)
        assert c.window().sum() == 11


def test_fit_is_good_and_a_minimum(curves):
    for c in curves:
        fit = fit_herschel_bulkley(c)
        m = fit.material
        assert fit.n_points == 11 and fit.rms_log10 < 0.01
        assert fit.rms_log10 == pytest.approx(log_stress_rms(m, c))
        # no coarse-grid material does better, and nudging any parameter makes it worse
        grid = [Material(e, n, s) for e in np.geomspace(0.1, 30, 25) for n in np.linspace(0.3, 1.0, 15)
                for s in np.linspace(0, c.shear_stress[c.window()].min() * 0.99, 12)]
        assert fit.rms_log10 <= min(log_stress_rms(g, c) for g in grid) + 1e-12
        for d in ([1.01, 1, 1], [0.99, 1, 1], [1, 1.01, 1], [1, 0.99, 1], [1, 1, 1.01], [1, 1, 0.99]):
            nudged = Material(m.eta * d[0], m.n * d[1], m.sigma_y * d[2])
            assert log_stress_rms(nudged, c) >= fit.rms_log10 - 1e-12


def test_every_laws_fit_is_its_best_not_a_bound(curves):
    """Each law's fit (its held parameters fixed) is a minimum of the log-stress RMS over its free parameters: nudging
    any of them makes it no better, so its AIC/BIC are its best fit's (on these shear-thinning curves Bingham's
    yield stress lies above the smallest stress, where a bound at the smallest stress held it)."""
    from mpm.laws import LAWS

    for c in curves:
        for law, held in LAWS.items():
            fit = fit_herschel_bulkley(c, law=law)
            m = fit.material
            free = [k for k in ("eta", "n", "sigma_y") if k not in held]
            for k in free:
                for f in (1.01, 0.99):
                    nudged = Material(**{**m.to_dict(), k: getattr(m, k) * f})
                    assert log_stress_rms(nudged, c) >= fit.rms_log10 - 1e-12, (c.material_name, law, k, f)
        bingham = fit_herschel_bulkley(c, law="bingham").material
        assert bingham.sigma_y > c.shear_stress[c.window()].min()


def test_log_stress_rms_definition(curves):
    c = curves[0]
    m = Material(1.0, 0.6, 1.0)
    mask = (c.shear_rate >= 1) & (c.shear_rate <= 100)
    expect = np.sqrt(np.mean((np.log10(m.stress(c.shear_rate[mask])) - np.log10(c.shear_stress[mask])) ** 2))
    assert log_stress_rms(m, c) == pytest.approx(expect, rel=1e-12)
    assert log_stress_rms(m, c, lo=0.1, hi=1000) != pytest.approx(expect)


def test_synthetic_roundtrip_recovers_parameters(tmp_path):
    truth = Material(2.3, 0.62, 4.1)
    rates = np.geomspace(0.1, 1000, 21)
    c = read_flow_curve(write_export(tmp_path / "Synthetic_20230101.csv", truth, rates))
    assert c.name == "Synthetic_20230101"
    fit = fit_herschel_bulkley(c)
    np.testing.assert_allclose([fit.material.eta, fit.material.n, fit.material.sigma_y], [2.3, 0.62, 4.1], rtol=1e-5)
    assert fit.rms_log10 < 1e-6  # the file rounds rates to 6 digits
    # without yield stress too (sigma_y on its bound)
    c0 = read_flow_curve(write_export(tmp_path / "Newtonianish.csv", Material(0.8, 0.9, 0.0), rates))
    f0 = fit_herschel_bulkley(c0)
    assert f0.material.sigma_y < 1e-6 and f0.material.n == pytest.approx(0.9, rel=1e-6)


def test_bad_files(tmp_path):
    with pytest.raises(FileNotFoundError):
        read_flow_curve(tmp_path / "missing.csv")
    with pytest.raises(ValueError, match="folder"):
        read_flow_curve(tmp_path)
    plain = tmp_path / "plain.csv"
    plain.write_text("a,b,c\n1,2,3\n")
    with pytest.raises(ValueError, match="not a rheometer export"):
        read_flow_curve(plain)
    no_units = tmp_path / "nounits.csv"
    no_units.write_bytes("テスト:\tx\r\n1\t2\t3\r\n".encode("utf-16"))
    with pytest.raises(ValueError, match="units row"):
        read_flow_curve(no_units)
    broken = write_export(tmp_path / "broken.csv", Material(1, 0.5, 1), np.geomspace(0.1, 1000, 21))
    text = broken.read_bytes().decode("utf-16").replace("\t10\t", "\tten\t")
    broken.write_bytes(text.encode("utf-16"))
    with pytest.raises(ValueError, match="non-numeric"):
        read_flow_curve(broken)


def test_cli_prints_curve_and_fit(shared_data, capsys):
    f = shared_data / "rheometer" / "Chuno_20230114_1458_23C.csv"
    assert main(["rheometer", str(f), "--material", "0.55,0.81,1.95"]) == 0
    out = capsys.readouterr().out
    assert "Japanese thickened Worcestershire sauce" in out and "Herschel-Bulkley fit over 1-100 1/s" in out
    assert out.count("*\n") == 11
    assert "given material" in out


@pytest.mark.parametrize("args,needle", [(["/nonexistent/x.csv"], "not found"), (["--lo", "100", "--hi", "1", "x.csv"], "--lo")])
def test_cli_bad_input(args, needle, capsys):
    assert main(["rheometer", *args]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and needle in err


def test_cli_not_an_export(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("hello\n")
    assert main(["rheometer", str(bad)]) == 2
    assert "not a rheometer export" in capsys.readouterr().err


def test_cli_json(shared_data, capsys):
    import json

    f = shared_data / "rheometer" / "Lotion_20230114_1204_23C.csv"
    assert main(["rheometer", str(f), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["material_name"] == "lotion" and len(data["shear_rate_per_s"]) == 21
    fit = data["fit"]
    assert fit["n_points"] == 11 and fit["rms_log10_stress"] < 0.01
    assert Material(fit["eta"], fit["n"], fit["sigma_y"]).stress(10.0) == pytest.approx(data["shear_stress_pa"][10], rel=0.02)


@pytest.mark.parametrize("truth, law", [(Material(0.8, 1.0, 4.0), "bingham"), (Material(3.0, 0.45, 0.0), "power-law"),
                                        (Material(0.2, 1.0, 0.0), "newtonian"), (Material(2.0, 0.5, 3.0), "herschel-bulkley")])
def test_special_laws_fit_and_information_criteria(tmp_path, truth, law):
    """A curve made by one law (1 % multiplicative noise): the law's own fit recovers it, the laws without its
    parameters miss, and BIC prefers the true law or a law that contains it within its penalty."""
    from mpm.laws import LAWS

    rates = np.geomspace(0.1, 1000, 21)
    noise = np.exp(0.01 * np.random.default_rng(3).standard_normal(len(rates)))
    curve = read_flow_curve(write_export(tmp_path / "x.csv", truth, rates, noise))
    fits = {name: fit_herschel_bulkley(curve, law=name) for name in LAWS}
    own = fits[law]
    assert own.parameters == 3 - len(LAWS[law]) and own.rms_log10 < 0.01
    for k, v in LAWS[law].items():
        assert getattr(own.material, k) == v
    assert own.material.stress(10.0) == pytest.approx(truth.stress(10.0), rel=0.02)
    for name, f in fits.items():
        contains = all(LAWS[name].get(k) == v for k, v in LAWS[name].items() if k in LAWS[law]) and \
            set(LAWS[name]) <= set(LAWS[law])
        if not contains:
            assert f.rms_log10 > 3 * own.rms_log10 and f.bic > own.bic + 10, name
        assert f.aic == pytest.approx(f.n_points * np.log(f.rms_log10**2) + 2 * f.parameters)
    best = min(fits.values(), key=lambda f: f.bic)
    assert best.law == law or set(LAWS[best.law]) <= set(LAWS[law])
    with pytest.raises(ValueError, match="unknown law 'casson'"):
        fit_herschel_bulkley(curve, law="casson")
