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
    status = main(["figures", "--only", "fig02,fig5,fig06,fig09", "--quick", "--out", str(tmp_path)])
    assert status == 0
    lines = [s for s in capsys.readouterr().out.splitlines() if s.startswith("fig")]
    by_name = {line.split(":")[0]: line for line in lines}
    assert set(by_name) == {"fig02", "fig05", "fig06", "fig09"}
    # figures whose study has not been run: one line each, naming the command that makes the data
    assert "virheo study landscapes" in by_name["fig06"] and "Traceback" not in by_name["fig06"]
    assert "virheo study conditioning" in by_name["fig09"]
    for name, series in (("fig02_1d_model", [PURPLE]), ("fig05_simple_shear", [PURPLE, RED])):
        img = _rgb(tmp_path / f"{name}.png")
        assert 0.03 < ink_fraction(img) < 0.5, name
        for rgb in series:  # every series spans the panels' time axis (six panels over the whole width)
            w, h = colour_extent(img, rgb)
            assert w > 0.7 and h > 0.4, (name, rgb, w, h)
    assert not (tmp_path / "fig06_landscapes.png").exists()


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
