"""``virheo check``: exit 0 / 1 / 2, one line per warning or error, an overlay PNG."""
import re
import shutil
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

from mpm import experiment
from mpm.camera import Camera
from mpm.silhouette import box_mask
from studies.cli import main

WORCESTER_2 = "ref_JapaneseThickenedWorcestershireSauce_2.0_3.0_2"


def run(capsys, *argv):
    status = main(["check", *map(str, argv)])
    out, err = capsys.readouterr()
    assert "Traceback" not in out + err
    return status, out, err


@pytest.fixture()
def good(tmp_path):
    cam = Camera.default()
    frames = np.stack([box_mask(cam, (30 + 2 * k) / 1000, 0.02, 0.04) for k in range(8)])
    return experiment.write(tmp_path / "ref_Emulated_2.0_3.0_1", frames, width_mm=30, height_mm=20, camera=cam,
                            density=1100.0)


def test_fine_folder(capsys, good, tmp_path):
    overlay = tmp_path / "out" / "overlay.png"
    status, out, err = run(capsys, good, "--overlay", overlay)
    assert status == 0 and err == ""
    iou = float(re.search(r"IoU (\d\.\d+)", out).group(1))
    assert iou > 0.9 and "status: ok" in out and f"overlay: {overlay}" in out
    img = np.asarray(Image.open(overlay).convert("RGB"))
    red = (img[..., 0] > 200) & (img[..., 1] < 50) & (img[..., 2] < 50)
    assert red.sum() > 100  # the cuboid outline is drawn


def test_no_overlay_unless_asked(capsys, good, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    before = sorted(p.name for p in tmp_path.iterdir())
    status, out, err = run(capsys, good)
    assert status == 0 and "overlay" not in out
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # nothing written into the current folder


def test_overlay_path_of_the_wrong_kind(capsys, good, tmp_path):
    status, out, err = run(capsys, good, "--overlay", tmp_path)
    assert status == 2 and err.strip() == f"virheo check: error: --overlay {tmp_path} is a folder: name a .png file"


def test_setup_outside_the_setup_space_is_refused_like_estimate(capsys, good, tmp_path):
    (good / "settings.xml").write_text(experiment.settings_xml(10, 20, 40, 1100))
    status, out, err = run(capsys, good)
    assert status == 2
    check_line = err.strip()
    assert check_line.endswith("width_mm=10 lies outside the setup space 20..70 mm")
    assert main(["estimate", str(good), "--out", str(tmp_path / "o"), "--quiet"]) == 2
    estimate_line = capsys.readouterr().err.strip()
    assert estimate_line.split(": error: ")[1] == check_line.split(": error: ")[1]
    assert not (tmp_path / "o").exists()


def test_white_footage_is_one_summary_line(capsys, good, tmp_path):
    for k in range(1, 9):
        Image.new("RGB", (1920, 1080), "white").save(good / f"config_{k:02d}.png")
    status, out, err = run(capsys, good)
    assert status == 2
    assert err.strip().splitlines() == ["virheo check: error: ref_Emulated_2.0_3.0_1: frames 1-8 of 8 show no "
                                        "material: nothing to estimate from (check the silhouettes)"]


def test_shared_folders(capsys, shared_data, tmp_path):
    status, out, err = run(capsys, shared_data / "real_world" / "ref_Carbonara_3.7_6.4_1", "--overlay",
                           tmp_path / "a.png")
    assert status == 0, err
    status, out, err = run(capsys, shared_data / "real_world" / WORCESTER_2, "--overlay", tmp_path / "b.png")
    assert status == 1  # usable, but its camera file had to be repaired
    assert len(err.strip().splitlines()) == 1 and "setup3D" in err


def test_swapped_setup_is_flagged(capsys, shared_data, tmp_path):
    src = shared_data / "real_world" / "ref_Carbonara_3.7_6.4_1"
    dst = tmp_path / "carbonara_swapped"
    shutil.copytree(src, dst)
    exp = experiment.load(src, frames=False)
    (dst / "settings.xml").write_text(experiment.settings_xml(exp.height_mm, exp.width_mm, exp.depth_mm, exp.density))
    status, out, err = run(capsys, dst, "--overlay", tmp_path / "c.png")
    assert status == 1
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "swapped" in lines[0] and "clearly worse" in lines[0]


def test_swapped_emulated_setup_is_flagged(capsys, good, tmp_path):
    (good / "settings.xml").write_text(experiment.settings_xml(20, 30, 40, 1100))
    status, out, err = run(capsys, good, "--overlay", tmp_path / "d.png")
    assert status == 1 and "swapped" in err


def one_line_exit_2(capsys, folder, tmp_path, match):
    status, out, err = run(capsys, folder, "--overlay", tmp_path / "e.png")
    assert status == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("virheo check: error:") and match in lines[0], err


def test_bad_folders_exit_2(capsys, good, tmp_path):
    (good / "config_08.png").unlink()  # 7 frames
    one_line_exit_2(capsys, good, tmp_path, "missing config_08.png")
    Image.new("RGB", (1000, 500), "white").save(good / "config_08.png")
    one_line_exit_2(capsys, good, tmp_path, "1000x500")
    photo = np.random.default_rng(0).integers(0, 256, (1080, 1920, 3), dtype=np.uint8)
    Image.fromarray(photo).save(good / "config_08.png")
    one_line_exit_2(capsys, good, tmp_path, "not a binary silhouette")
    shutil.copy(good / "config_01.png", good / "config_08.png")
    (good / "camera_params.xml").write_text("<setup3D>\n</setup3D>\n")
    one_line_exit_2(capsys, good, tmp_path, "no <camera> element")
    one_line_exit_2(capsys, tmp_path / "nowhere", tmp_path, "not found")


def test_real_process_exit_code(good, tmp_path):
    (good / "config_02.png").unlink()
    proc = subprocess.run([sys.executable, "-m", "studies.cli", "check", str(good), "--overlay",
                           str(tmp_path / "f.png")], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr and "config_02" in proc.stderr


def test_estimate_refuses_a_negative_slip_length_before_any_work(capsys, good, tmp_path):
    assert main(["estimate", str(good), "--out", str(tmp_path / "o"), "--slip-mm", "-1", "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "virheo estimate: error: --slip-mm -1 must be within 0-1000 mm (0: sticking walls)"
    assert not (tmp_path / "o").exists()
