"""Experiment folders: the shared data's quirks, a write/load round trip, and malformed folders."""
import shutil

import numpy as np
import pytest
from PIL import Image

from mpm import experiment
from mpm.camera import Camera
from mpm.silhouette import box_mask

WORCESTER_2 = "ref_JapaneseThickenedWorcestershireSauce_2.0_3.0_2"


def masks(n=8, width_mm=30.0, height_mm=20.0):
    """n frames of a growing box silhouette at 960x540."""
    cam = Camera.default()
    return np.stack([box_mask(cam, (width_mm + 2 * k) / 1000, height_mm / 1000, 0.04) for k in range(n)])


@pytest.fixture()
def folder(tmp_path):
    return experiment.write(tmp_path / "ref_Emulated_2.0_3.0_1", masks(), width_mm=30, height_mm=20,
                            camera=Camera.default(), density=1175.0, depth_mm=41.5,
                            initial_material={"eta": 3.45, "n": 0.74, "sigma_y": 6.26})


def test_roundtrip(folder):
    exp = experiment.load(folder)
    assert (exp.width_mm, exp.height_mm, exp.depth_mm, exp.density) == (30.0, 20.0, 41.5, 1175.0)
    assert exp.setup_index == 1 and exp.warnings == []
    assert exp.initial_material == pytest.approx({"eta": 3.45, "n": 0.74, "sigma_y": 6.26})
    assert exp.frames.shape == (8, 540, 960) and exp.frames.dtype == bool
    assert np.array_equal(exp.frames, masks())
    np.testing.assert_allclose(exp.camera.eyepos_m, Camera.default().eyepos_m, atol=1e-9)
    assert exp.frame_times_s[0] == pytest.approx(1 / 24) and exp.frame_times_s[-1] == pytest.approx(1 / 3)
    with Image.open(folder / "config_01.png") as im:
        assert im.size == (1920, 1080) and im.mode == "RGB"
    fit, swapped = experiment.cuboid_fit(exp)
    assert fit > 0.9 > swapped and experiment.setup_warnings(exp) == []


def test_shared_quirks(shared_data):
    by_name = {p.name: experiment.load(p, frames=False) for p in experiment.iter_shared()}
    assert len(by_name) >= 14
    # depths read from the wall boxes, never assumed
    assert by_name["ref_Cobb_4.7_5.5_1"].depth_mm == pytest.approx(39.9)
    assert by_name["ref_MoisturizingMilk_5.9_2.9_1"].depth_mm == pytest.approx(41.5)
    assert by_name["ref_Carbonara_3.7_6.4_1"].depth_mm == pytest.approx(40.0)
    # W is the flow direction; the folder name is H first
    assert (by_name["ref_Carbonara_3.7_6.4_1"].width_mm, by_name["ref_Carbonara_3.7_6.4_1"].height_mm) == (64, 37)
    # density: <setup RHO> in g/cm^3 -> kg/m^3, not the cuboid's density="1.0"
    assert by_name[WORCESTER_2].density == pytest.approx(1200.0)
    assert by_name["ref_Carbonara_2.0_2.5_2"].density == pytest.approx(1025.0)
    # CGS initial_material -> SI
    m = by_name["ref_Carbonara_2.0_2.5_2"].initial_material
    assert m == pytest.approx({"eta": 9.816273704, "n": 0.7050882349, "sigma_y": 12.88674845})
    assert by_name["ref_Carbonara_3.7_6.4_1"].initial_material is None
    # the camera file without its opening tag is recovered, with a warning
    assert any("setup3D" in w for w in by_name[WORCESTER_2].warnings)
    assert sum(bool(e.warnings) for e in by_name.values()) == 1
    # the manifest agrees on setups and densities
    from mpm.datasets import manifest

    for row in manifest():
        e = by_name[row["folder"]]
        assert e.width_mm == pytest.approx(10 * float(row["width_cm"]))
        assert e.height_mm == pytest.approx(10 * float(row["height_cm"]))
        assert e.density == pytest.approx(1000 * float(row["density_g_per_cm3"]))


def test_swapped_setup_element_is_resolved_by_the_cuboid(folder):
    text = (folder / "settings.xml").read_text()
    (folder / "settings.xml").write_text(text.replace('H="2" W="3"', 'H="3" W="2"'))
    exp = experiment.load(folder, frames=False)
    assert (exp.width_mm, exp.height_mm) == (30.0, 20.0)
    assert len(exp.warnings) == 1 and "swapped" in exp.warnings[0]


def test_folder_name_disagreeing_is_a_warning(folder, tmp_path):
    other = tmp_path / "ref_Thing_3.0_2.0_2"
    shutil.copytree(folder, other)
    exp = experiment.load(other, frames=False)
    assert exp.width_mm == 30.0 and any("folder name" in w for w in exp.warnings)


def one_line_error(path, match, exc=ValueError):
    with pytest.raises(exc, match=match) as info:
        experiment.load(path)
    assert "\n" not in str(info.value)


def test_bad_folders(folder, tmp_path):
    one_line_error(tmp_path / "nowhere", "not found", FileNotFoundError)
    (folder / "config_08.png").rename(folder / "config_09.png")
    one_line_error(folder, "missing config_08")
    (folder / "config_09.png").rename(folder / "config_08.png")
    shutil.copy(folder / "config_08.png", folder / "config_00.png")
    one_line_error(folder, "extra frames config_00")
    (folder / "config_00.png").unlink()
    Image.new("RGB", (1000, 500), "white").save(folder / "config_03.png")
    one_line_error(folder, "1000x500")
    noise = np.random.default_rng(0).integers(0, 256, (1080, 1920, 3), dtype=np.uint8)
    Image.fromarray(noise).save(folder / "config_03.png")
    one_line_error(folder, "not a binary silhouette")


def test_bad_xml(folder):
    good_cam = (folder / "camera_params.xml").read_text()
    (folder / "camera_params.xml").write_text("<setup3D><lens f='3'/></setup3D>")
    one_line_error(folder, "no <camera> element")
    (folder / "camera_params.xml").write_text(good_cam)
    (folder / "settings.xml").write_text("<<< garbage")
    one_line_error(folder, "unreadable XML")
    (folder / "settings.xml").unlink()
    one_line_error(folder, "settings.xml not found", FileNotFoundError)


def test_write_rejects_bad_masks(tmp_path):
    with pytest.raises(ValueError, match=r"need 8 masks .* got shape \(7, 540, 960\)"):
        experiment.write(tmp_path / "x", masks(7), width_mm=30, height_mm=20, camera=Camera.default())
    with pytest.raises(ValueError, match="masks must be 960x540 or 1920x1080, got 1000x500"):
        experiment.write(tmp_path / "x", np.zeros((8, 500, 1000), bool), width_mm=30, height_mm=20,
                         camera=Camera.default())


def test_inverted_frames_are_suspicious(folder):
    for k in (1, 2):
        p = folder / f"config_{k:02d}.png"
        Image.fromarray(255 - np.asarray(Image.open(p))).save(p)
    exp = experiment.load(folder)
    assert [w for w in exp.warnings if "inverted" in w] == [
        "frames 1-2 are more than half material: inverted colours? (material must be black on white)"]


def test_footage_without_evidence():
    moving = masks()
    assert experiment.footage_problems(moving) == []
    empty = moving.copy()
    empty[[2, 3, 4, 7]] = False
    assert experiment.footage_problems(empty) == ["frames 3-5, 8 of 8 show no material"]
    empty[:] = False
    empty[0, 100, 100] = True
    assert experiment.footage_problems(empty) == ["frames 2-8 of 8 show no material"]
    assert experiment.footage_problems(np.stack([moving[0]] * 8)) == [
        "the material never moves: frames 1-8 are identical"]
    escaping = moving.copy()
    escaping[5:, 300:310, 700:] = True
    assert experiment.footage_problems(escaping) == [
        "the material leaves the image in frames 6-8 (it reaches the image's edge)"]
    assert experiment.frame_list([1, 2, 3, 6, 8, 9]) == "1-3, 6, 8-9"


def test_paths_of_the_wrong_kind(folder, tmp_path):
    (folder / "settings.xml").unlink()
    (folder / "settings.xml").mkdir()
    one_line_error(folder, "settings.xml is a folder, not a file")
    f = tmp_path / "plain.txt"
    f.write_text("x")
    one_line_error(f, "is a file, not an experiment folder")


def test_implausible_density(folder):
    text = (folder / "settings.xml").read_text()
    (folder / "settings.xml").write_text(text.replace('RHO="1.175"', 'RHO="0.05"'))
    one_line_error(folder, r"the density in settings.xml, 50 kg/m\^3 lies outside the accepted range 300..5000")
