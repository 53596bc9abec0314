"""``virheo figures``: the simulation-free figures are drawn with content, missing data is one line, bad input exit 2."""
from __future__ import annotations

import numpy as np
from PIL import Image

from studies.cli import main

PURPLE, RED = (128, 0, 128), (255, 0, 0)  # matplotlib "purple" (paper's flow rule) and "red" (Yue 2015)


def _rgb(path) -> np.ndarray:
    return np.asarray(Image.open(path).convert("RGB")).astype(int)


def ink_fraction(img: np.ndarray) -> float:
    """Fraction of pixels that are not (near) white background."""
    return float((img.min(axis=2) < 235).mean())


def colour_extent(img: np.ndarray, rgb, tol: int = 40) -> tuple[float, float]:
    """(width, height) fraction of the image spanned by pixels of colour ``rgb`` (a plotted data series)."""
    hit = (np.abs(img - np.asarray(rgb)).max(axis=2) <= tol)
    if not hit.any():
        return 0.0, 0.0
    ys, xs = np.nonzero(hit)
    return (xs.max() - xs.min()) / img.shape[1], (ys.max() - ys.min()) / img.shape[0]




def test_simulation_free_figures_have_content(tmp_path, capsys):
    status = main(["figures", "--only", "fig02,fig5", "--quick", "--out", str(tmp_path)])
    assert status == 0
    lines = [s for s in capsys.readouterr().out.splitlines() if s.startswith("fig")]
    assert {line.split(":")[0] for line in lines} == {"fig02", "fig05"}
    for name, series in (("fig02_1d_model", [PURPLE]), ("fig05_simple_shear", [PURPLE, RED])):
        img = _rgb(tmp_path / f"{name}.png")
        assert 0.03 < ink_fraction(img) < 0.5, name
        for rgb in series:  # every series spans the panels' time axis (six panels over the whole width)
            w, h = colour_extent(img, rgb)
            assert w > 0.7 and h > 0.4, (name, rgb, w, h)


def test_landscape_figures_without_data_name_the_command(tmp_path, capsys):
    # not quick and no --landscapes: nothing is simulated, one line per figure names the study command
    status = main(["figures", "--only", "fig06,fig07,fig09", "--out", str(tmp_path)])
    assert status == 0
    out = capsys.readouterr().out
    by_name = {line.split(":")[0]: line for line in out.splitlines() if line.startswith("fig")}
    assert set(by_name) == {"fig06", "fig07", "fig09"} and "Traceback" not in out
    assert "virheo study landscapes" in by_name["fig06"] and "virheo study landscapes" in by_name["fig07"]
    assert "virheo study conditioning" in by_name["fig09"]
    assert not list(tmp_path.glob("fig0*.png"))
    # a folder without the study's files is one line too
    (tmp_path / "empty").mkdir()
    main(["figures", "--only", "fig06,fig09", "--out", str(tmp_path), "--landscapes", str(tmp_path / "empty")])
    out = capsys.readouterr().out
    assert "landscapes.json" in out and "conditioning.json" in out and "Traceback" not in out


def test_landscape_figures_from_a_tiny_study(tmp_path, capsys, monkeypatch):
    """Quick mode runs a tiny landscape and conditioning study (fake forward model) and draws Figs. 6, 7, 9;
    a second run, given the study's folder, draws them again without simulating."""
    monkeypatch.setenv("VIRHEO_SIMULATOR", "fake_forward:simulate")
    out = tmp_path / "quick"
    assert main(["figures", "--only", "fig06,fig07,fig09", "--quick", "--workers", "0", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert printed.count(".png") == 3, printed
    study = out / "landscape-study"
    assert (study / "landscapes.json").is_file() and (study / "conditioning" / "conditioning.json").is_file()
    for name in ("fig06_landscapes", "fig07_views", "fig09_conditioning"):
        img = _rgb(out / f"{name}.png")
        assert 0.05 < ink_fraction(img) < 0.8, name
    # Fig. 6 marks the ground truth and the matched Poiseuille plane in red in every panel's column
    w, h = colour_extent(_rgb(out / "fig06_landscapes.png"), RED, tol=60)
    assert w > 0.5 and h > 0.4, (w, h)
    # Fig. 9: the coloured condition-number map fills a large part of the figure
    img = _rgb(out / "fig09_conditioning.png")
    assert (img.max(axis=2) - img.min(axis=2) > 60).mean() > 0.25

    monkeypatch.setenv("FAKE_FORWARD_LOG", str(tmp_path / "sims.log"))
    again = tmp_path / "again"
    assert main(["figures", "--only", "fig06,fig09", "--out", str(again), "--landscapes", str(study)]) == 0
    assert (again / "fig06_landscapes.png").is_file() and (again / "fig09_conditioning.png").is_file()
    assert not (tmp_path / "sims.log").exists()  # drawn from the folder, nothing simulated


def test_unknown_figure_is_a_one_line_error(tmp_path, capsys):
    assert main(["figures", "--only", "fig99", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "fig99" in err[0] and "fig13" in err[0]


def test_difference_image_marks_each_side():
    from paper_figures._plot import crop_box, difference_rgb

    a = np.zeros((40, 60), bool)
    b = np.zeros((40, 60), bool)
    a[10:20, 10:30] = True
    b[10:20, 20:40] = True
    img = difference_rgb(a, b)
    assert np.allclose(img[15, 12], (0.16, 0.43, 0.90)) and np.allclose(img[15, 35], (0.90, 0.24, 0.16))
    assert np.allclose(img[15, 25], 0.85) and np.allclose(img[0, 0], 1.0)
    rows, cols = crop_box([a, b], pad=2)
    assert (rows.start, rows.stop, cols.start, cols.stop) == (8, 22, 8, 42)


def _bench_folder(root, material, estimate, one_setup, loss, loss_paper, seed=0):
    """A folder as bench/bench_real_estimates.py writes it, for one material of the shared footage."""
    import json

    from mpm.datasets import manifest

    rows = [r for r in manifest() if r["material"] == material]
    slug = root / "one"
    slug.mkdir(parents=True)
    stages = [{"material": one_setup}, {"material": estimate}]
    (slug / "result.json").write_text(json.dumps({
        "experiments": [{"name": r["folder"]} for r in rows], "setups": ["21x40", "30x20"], "stages": stages,
        "estimate": estimate, "loss": loss, "seed": seed, "preset": "footage",
        "model": {"cell_mm": 1.26, "ppc": 2}}))
    (root / "real_estimates.json").write_text(json.dumps({"one": {"material": material, "loss_paper": loss_paper}}))


def test_fig13_is_drawn_from_the_bench_estimate_folders(shared_data, tmp_path, capsys):
    import json

    sauce = "Japanese thickened Worcestershire sauce"
    table1 = {"eta": 0.55, "n": 0.81, "sigma_y": 1.95}
    runny = {"eta": 0.1, "n": 0.9, "sigma_y": 0.0}
    _bench_folder(tmp_path / "s0", sauce, table1, runny, loss=0.0049, loss_paper=0.0050)
    assert main(["figures", "--only", "fig13", "--estimates", str(tmp_path / "s0"), "--out", str(tmp_path / "out")]) == 0
    (row,) = json.loads((tmp_path / "out" / "table1.json").read_text())["rows"]
    assert row["material"] == sauce and row["seed"] == 0 and row["loss_paper"] == 0.0050
    # the two-setup estimate is Table 1 here: the same flow curve, the RMS docs/validation.md gives for Table 1
    assert row["rms_two_setups"] == row["rms_paper"] and abs(row["rms_paper"] - 0.067) < 5e-4
    assert row["rms_one_setup"] > 3 * row["rms_paper"]  # a Newtonian tenth of the consistency misses the rheometer
    assert "| 0.00490 |" in (tmp_path / "out" / "table1.md").read_text()
    img = _rgb(tmp_path / "out" / "fig13_flow_curves.png")
    assert 0.03 < ink_fraction(img) < 0.5


def test_fig13_without_estimate_folders_names_the_bench(shared_data, tmp_path, capsys):
    assert main(["figures", "--only", "fig13", "--estimates", str(tmp_path / "none"), "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "fig13: not made" in out and "bench_real_estimates.py" in out
