"""The CLI's error boundary, footage without evidence, shared options, honest counters and quiet output."""
import json
import os
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from mpm import experiment
from mpm.camera import Camera
from mpm.silhouette import box_mask
from studies.cli import main

TESTS = Path(__file__).resolve().parent
FAST = ["--generations", "2", "--workers", "0", "--quiet"]


def one_error_line(capsys, argv) -> str:
    assert main(argv) == 2
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


@pytest.fixture()
def fake(monkeypatch):
    monkeypatch.setenv("VIRHEO_SIMULATOR", "fake_forward:simulate")


@pytest.fixture()
def folder(tmp_path):
    cam = Camera.default()
    frames = np.stack([box_mask(cam, (30 + 2 * k) / 1000, 0.02, 0.04) for k in range(8)])
    return experiment.write(tmp_path / "ref_Emulated_2.0_3.0_1", frames, width_mm=30, height_mm=20, camera=cam)


def test_out_that_is_a_file(capsys, tmp_path, fake):
    f = tmp_path / "result"
    f.write_text("x")
    line = one_error_line(capsys, ["demo", "--out", str(f), *FAST])
    assert line == f"virheo demo: error: --out {f} is a file, not a folder: name a folder"


def test_store_that_is_a_file(capsys, tmp_path, folder):
    f = tmp_path / "store"
    f.write_text("x")
    line = one_error_line(capsys, ["estimate", str(folder), "--out", str(tmp_path / "o"), "--store", str(f), *FAST])
    assert line == f"virheo estimate: error: --store {f} is a file, not a folder: name a folder"
    assert not (tmp_path / "o").exists()


def test_out_below_a_file_reaches_the_boundary_as_one_line(capsys, tmp_path, fake):
    f = tmp_path / "file"
    f.write_text("x")
    line = one_error_line(capsys, ["demo", "--out", str(f / "sub"), *FAST])
    assert line.startswith("virheo demo: error: ") and str(f) in line and "name a folder, or move the file" in line


def test_plot_that_is_a_folder(capsys, tmp_path):
    line = one_error_line(capsys, ["design", "--material", "3,0.5,3", "--done", "29x59", "--plot", str(tmp_path)])
    assert line == f"virheo design: error: --plot {tmp_path} is a folder: name a .png file"


def test_plot_reports_the_file_it_wrote(capsys, tmp_path):
    assert main(["design", "--material", "3,0.5,3", "--done", "29x59", "--plot", str(tmp_path / "heat"), "--criterion",
                 "perpendicularity"]) == 0
    out = capsys.readouterr().out
    assert f"heat map written to {tmp_path / 'heat.png'}" in out
    assert (tmp_path / "heat.png").read_bytes()[:4] == b"\x89PNG" and not (tmp_path / "heat").exists()


def test_white_footage_is_refused_before_any_simulation(capsys, tmp_path, folder, fake):
    for k in range(1, 9):
        Image.new("RGB", (1920, 1080), "white").save(folder / f"config_{k:02d}.png")
    line = one_error_line(capsys, ["estimate", str(folder), "--out", str(tmp_path / "o"), *FAST])
    assert line == ("virheo estimate: error: ref_Emulated_2.0_3.0_1: frames 1-8 of 8 show no material: "
                    "nothing to estimate from (check the silhouettes)")
    assert not (tmp_path / "o").exists()


def test_still_and_escaping_footage_are_refused(capsys, tmp_path, folder, fake):
    still = experiment.load(folder).frames[0]
    experiment.write(folder, np.stack([still] * 8), width_mm=30, height_mm=20, camera=Camera.default())
    line = one_error_line(capsys, ["estimate", str(folder), "--out", str(tmp_path / "o"), *FAST])
    assert line.endswith("the material never moves: frames 1-8 are identical: nothing to estimate from "
                         "(check the silhouettes)")
    frames = np.stack([still] * 8)
    frames[6:, 200:260, 900:] = True  # frames 7 and 8 reach the right edge
    experiment.write(folder, frames, width_mm=30, height_mm=20, camera=Camera.default())
    line = one_error_line(capsys, ["estimate", str(folder), "--out", str(tmp_path / "o"), *FAST])
    assert "the material leaves the image in frames 7-8" in line


@pytest.mark.parametrize("argv, message", [
    (["--workers", "-1"], "--workers -1 must be >= 0 (0: simulate in this process)"),
    (["--generations", "0"], "--generations 0 must be >= 1"),
    (["--density", "50"], "--density 50 kg/m^3 lies outside the accepted range 300..5000 kg/m^3"),
])
def test_numbers_are_checked_with_the_projects_messages(capsys, tmp_path, argv, message, fake):
    line = one_error_line(capsys, ["demo", "--out", str(tmp_path / "d"), *argv])
    assert line == f"virheo demo: error: {message}"
    assert not (tmp_path / "d").exists()


@pytest.mark.parametrize("command", [["demo"], ["estimate", "folder"], ["study", "emulation"], ["study", "landscapes"],
                                     ["study", "calibration"], ["report", "run"], ["theta", "fit", "study"]])
def test_a_seed_out_of_range_is_refused_before_any_work(capsys, tmp_path, command):
    with pytest.raises(SystemExit) as exc:
        main([*command, "--seed", "-1", "--out", str(tmp_path / "o")])
    assert exc.value.code == 2
    assert capsys.readouterr().err.strip().endswith("error: argument --seed: -1 is not in 0..2**32-1")
    assert not (tmp_path / "o").exists()


def test_a_word_where_a_number_belongs(capsys, tmp_path):
    with pytest.raises(SystemExit) as exc:
        main(["demo", "--out", str(tmp_path / "d"), "--density", "heavy"])
    assert exc.value.code == 2
    assert capsys.readouterr().err.strip() == "virheo demo: error: argument --density: 'heavy' is not a number"


def test_simulate_states_and_guards_its_ranges(capsys, tmp_path):
    line = one_error_line(capsys, ["simulate", "--material", "1e30,0.5,3", "--setup", "30x30",
                                   "--out", str(tmp_path / "s")])
    assert line == ("virheo simulate: error: eta=1e+30 lies beyond what the solver simulates in reasonable time "
                    "(accepted: eta <= 3000 Pa s^n)")
    f = tmp_path / "file"
    f.write_text("x")
    assert main(["simulate", "--material", "3,1.5,3", "--setup", "30x30", "--out", str(f)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["virheo simulate: warning: n=1.5 lies outside the material space 0.3..1: simulated, but "
                   "estimation never searches there",
                   f"virheo simulate: error: --out {f} is a file, not a folder: name a folder"]
    with pytest.raises(SystemExit):
        main(["simulate", "--help"])
    help_text = capsys.readouterr().out
    assert "n > 1: shear-thickening" in help_text and "one of: paper, yue2015" in help_text


def test_demo_accepts_the_shared_run_options(tmp_path, capsys, fake):
    store = tmp_path / "shared-store"
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--store", str(store), *FAST]) == 0
    first = capsys.readouterr().out
    result = json.loads((out / "result.json").read_text())
    assert (store / "index.sqlite").is_file() and not (out / "store").exists()
    # a fresh run simulates exactly what the estimate counts; the summary says the same
    assert result["simulations_run"] == result["simulations"] > 0
    assert f"{result['simulations']} simulations ({result['simulations']} run now) in " in first
    # results are written with the user's normal mode, not 0600
    umask = os.umask(0o022)
    os.umask(umask)
    assert stat.S_IMODE((out / "result.json").stat().st_mode) == 0o666 & ~umask
    # the same run again is served from the store and says so
    assert main(["demo", "--out", str(out), "--store", str(store), *FAST]) == 0
    again = capsys.readouterr().out
    result2 = json.loads((out / "result.json").read_text())
    assert result2["simulations_run"] == 0 and result2["estimate"] == result["estimate"]
    assert f"{result['simulations']} simulations, all served from the store (none run now)" in again


def test_version_and_every_option_has_help():
    import argparse

    from studies.cli import build_parser

    proc = subprocess.run([sys.executable, "-m", "studies.cli", "--version"], capture_output=True, text=True,
                          cwd=TESTS.parent, timeout=120)
    assert proc.returncode == 0 and proc.stdout.startswith("virheo ") and proc.stdout.split()[1][0].isdigit()
    parser = build_parser()
    stack = [parser]
    seen = 0
    while stack:
        p = stack.pop()
        for action in p._actions:  # the test reads argparse's structure; the CLI itself does not
            if isinstance(action, argparse._SubParsersAction):
                stack.extend(action.choices.values())
            elif action.option_strings and action.dest not in ("help", "version"):
                seen += 1
                assert action.help and action.help != argparse.SUPPRESS, (p.prog, action.option_strings)
    assert seen > 40



def test_disk_full_and_damaged_files_are_one_line(capsys, monkeypatch, tmp_path):
    import errno
    import sqlite3

    from studies.commands import design

    def full(args):
        raise OSError(errno.ENOSPC, "No space left on device", str(tmp_path / "out" / "result.json"))

    monkeypatch.setattr(design, "run", full)
    argv = ["design", "--material", "3,0.5,3", "--done", "29x59"]
    assert one_error_line(capsys, argv) == (
        f"virheo design: error: {tmp_path / 'out' / 'result.json'}: No space left on device; free some disk "
        f"space and run the same command again (finished simulations are kept)")

    def locked(args):
        raise sqlite3.OperationalError("database is locked")

    monkeypatch.setattr(design, "run", locked)
    assert one_error_line(capsys, argv) == (
        "virheo design: error: the simulation store's index cannot be used (database is locked); "
        "if another run uses the same store, wait for it; else pass another --store")


@pytest.mark.parametrize("python_warnings", ["", "ignore"])
def test_quiet_still_reports_a_damaged_store_in_one_line(tmp_path, python_warnings):
    """--quiet silences progress, never a loss of data: the index set aside is one line on stderr, even where
    Python's own warnings are switched off."""
    out = tmp_path / "out"
    store = out / "store"
    store.mkdir(parents=True)
    (store / "index.sqlite").write_bytes(b"this is not a database" * 100)
    env = dict(os.environ, PYTHONPATH=f"{TESTS}{os.pathsep}{TESTS.parent}", VIRHEO_SIMULATOR="fake_forward:simulate",
               PYTHONWARNINGS=python_warnings)
    proc = subprocess.run([sys.executable, "-m", "studies.cli", "study", "emulation", "--materials", "1", "--runs", "1",
                           "--generations", "1", "--workers", "0", "--quiet", "--out", str(out)],
                          env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    aside = [p for p in store.glob("index.sqlite.damaged-*") if p.name[-1].isdigit()]
    assert len(aside) == 1 and (store / "index.sqlite").is_file()
    assert proc.stderr.splitlines() == [
        f"virheo study: warning: store index {store / 'index.sqlite'} was damaged (file is not a database); "
        f"moved to {aside[0].name}; rebuilt from 0 intact simulations on disk"]


def test_estimate_points_to_the_default_design_command(capsys, tmp_path, folder, fake):
    """The next setup `estimate` prints is the paper's criterion's; the line names it and gives the `virheo design`
    command of the default criterion, which runs as printed."""
    import shlex

    assert main(["estimate", str(folder), "--out", str(tmp_path / "o"), "--preset", "demo", *FAST]) == 0
    lines = capsys.readouterr().out.splitlines()
    line = next(ln for ln in lines if ln.startswith("next setup: "))
    assert "the paper's perpendicularity criterion, which proved weak" in line
    # the laws' verdicts come from the report, and the last line says so with the command to run
    assert "yield stress and shear thinning decided by the laws' evidence" in lines[-1]
    assert lines[-1].endswith(f"virheo report {tmp_path / 'o'}")
    command = shlex.split(line.split("the default criterion: ")[1])
    assert command[:2] == ["virheo", "design"] and command[-2:] == ["--done", "30x20"]
    assert main(command[1:] + ["--workers", "0", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["criterion"] == "information"


def test_estimate_ends_with_an_estimate_when_the_proposal_has_no_normal(capsys, tmp_path, folder, fake):
    """A runny yield-stress start in a 30 x 20 mm box: the stage estimates give no plane-Poiseuille flow there, so
    section 6 has no normal to be perpendicular to.  The proposal is an optional step: the run keeps its estimate,
    prints one note per stage saying what was skipped and why, and points at the simulated criterion."""
    import shlex

    out = tmp_path / "o"
    assert main(["estimate", str(folder), "--out", str(out), "--preset", "footage", "--generations", "1",
                 "--start", "0.01,0.5,10", "--workers", "0", "--quiet"]) == 0
    stdout, stderr = capsys.readouterr()
    result = json.loads((out / "result.json").read_text())
    assert result["estimate"]["eta"] > 0 and result["next_setup"] is None
    notes = [ln for ln in stderr.strip().splitlines() if "locale" not in ln]  # Taichi's import under pytest
    assert notes == [f"virheo estimate: note: {n}" for n in result["notes"]] and len(notes) == len(result["stages"])
    for k, line in enumerate(notes, start=1):
        assert line.startswith(f"virheo estimate: note: next-setup proposal after stage {k} skipped: no "
                               "plane-Poiseuille flow in 30x20 at this estimate: its normal is undefined")
    assert stdout.startswith("estimate: eta = ")
    line = next(ln for ln in stdout.splitlines() if ln.startswith("next setup: "))
    command = shlex.split(line.split("the simulator's own criterion: ")[1])
    assert command[:2] == ["virheo", "design"] and command[-2:] == ["--done", "30x20"]
    material = command[command.index("--material") + 1]
    # the same material through `virheo design`: no candidate box makes it flow, so both Theta criteria refuse in
    # one line; a material that flows in other boxes gets an answer from those, the 29 x 20 mm box left out
    for criterion in ("perpendicularity", "eig"):
        line = one_error_line(capsys, ["design", "--material", material, "--done", "30x20", "--criterion", criterion])
        assert line.startswith("virheo design: error: no ")
    for criterion in ("perpendicularity", "eig"):
        assert main(["design", "--material", "0.1,0.5,1", "--done", "29x20", "--done", "60x60", "--criterion", criterion,
                     "--json"]) == 0
        answer = json.loads(capsys.readouterr().out)
        assert answer["notes"] == ["no plane-Poiseuille flow in 29x20 at this estimate: its normal is undefined"]
        assert answer["valid_candidates"] > 0
    assert main(["design", "--material", "0.1,0.5,1", "--done", "29x20", "--criterion", "eig"]) == 0
    assert "  left out: no plane-Poiseuille flow in 29x20" in capsys.readouterr().out


def test_estimate_on_shared_thin_box_footage_ends_with_an_estimate_and_a_note(capsys, tmp_path, fake, shared_data):
    """The shared 29 x 20 mm footage of thousand island dressing through the CLI's own code path (the fake forward
    model simulates): a runny yield-stress start leaves the stage estimates without plane-Poiseuille flow in 29x20,
    and the run still ends with its estimate and one note per skipped proposal."""
    folder = shared_data / "real_world" / "ref_Island_2.0_2.9_2"
    out = tmp_path / "island"
    assert main(["estimate", str(folder), "--out", str(out), "--preset", "footage", "--generations", "1",
                 "--start", "0.01,0.5,10", "--workers", "0", "--quiet"]) == 0
    stdout, stderr = capsys.readouterr()
    result = json.loads((out / "result.json").read_text())
    assert stdout.startswith("estimate: eta = ") and result["setups"] == ["29x20"]
    notes = [ln for ln in stderr.splitlines() if ln.startswith("virheo estimate: note: ")]
    assert len(notes) == len(result["notes"]) >= 1
    assert "no plane-Poiseuille flow in 29x20 at this estimate: its normal is undefined" in notes[0]
