"""Camera: XML reading, the reference implementation's projection convention, and the fit on real footage."""
import math
import pickle
import warnings

import numpy as np
import pytest

from mpm import experiment
from mpm.camera import Camera, CameraXMLWarning, read_xml
from mpm.loss import iou, load_reference
from mpm.silhouette import box_mask

XML = ('<?xml version="1.0"?>\n<setup3D>\n<camera eyepos="7.45150626 13.58546276 25.92631598"  '
       'quat="0.96584289 -0.25912607 0.00104166 -0.00032933" window_size="960 540" fov="36.17541"/>\n</setup3D>\n')


def test_value_semantics():
    cam = Camera.default()
    assert hash(cam) == hash(Camera.default())
    assert pickle.loads(pickle.dumps(cam)) == cam
    assert Camera.from_dict(cam.to_dict()) == cam
    assert {cam: 1}[Camera.from_dict(cam.to_dict())] == 1
    with pytest.raises(Exception):
        cam.fov_deg = 10.0  # frozen


def test_projection_closed_form():
    # identity rotation: camera at z = 1 m looking along -z; f = (H/2) / tan(fov/2)
    cam = Camera(eyepos_m=(0.0, 0.0, 1.0), quat=(1.0, 0.0, 0.0, 0.0), fov_deg=60.0)
    f = 270.0 / math.tan(math.radians(30.0))
    uv = cam.project([[0.0, 0.0, 0.0], [0.1, 0.2, 0.0], [0.1, 0.2, -1.0]], (960, 540))
    np.testing.assert_allclose(uv[0], [480.0, 270.0])
    np.testing.assert_allclose(uv[1], [480.0 + 0.1 * f, 270.0 - 0.2 * f])  # x right, y down
    np.testing.assert_allclose(uv[2], [480.0 + 0.05 * f, 270.0 - 0.1 * f])  # twice as far: half the offset
    # points behind the eye do not project
    assert np.isnan(cam.project([[0.0, 0.0, 2.0]], (960, 540))).all()


def test_projection_scales_with_image_size():
    cam = Camera.default()
    pts = np.random.default_rng(1).uniform([0, 0, 0], [0.07, 0.07, 0.04], size=(50, 3))
    np.testing.assert_allclose(cam.project(pts, (1920, 1080)), 2.0 * cam.project(pts, (960, 540)), rtol=1e-12)


def test_pitch_looks_down():
    cam = Camera.default()  # pitched -30 deg about +x: the view axis points down and away from +z
    forward = cam.rotation @ np.array([0.0, 0.0, -1.0])
    assert forward[1] < 0 and forward[2] < 0
    assert math.degrees(math.asin(-forward[1])) == pytest.approx(30.0)
    np.testing.assert_allclose(cam.rotation @ cam.rotation.T, np.eye(3), atol=1e-12)


def test_xml_roundtrip_and_units(tmp_path):
    cam = Camera.default()
    path = tmp_path / "camera_params.xml"
    path.write_text(cam.to_xml())
    back = Camera.from_xml(path)
    np.testing.assert_allclose(back.eyepos_m, cam.eyepos_m, atol=1e-9)
    np.testing.assert_allclose(back.quat, cam.quat, atol=1e-8)
    path.write_text(XML)
    c = Camera.from_xml(path)
    np.testing.assert_allclose(c.eyepos_m, [0.0745150626, 0.1358546276, 0.2592631598])  # cm -> m
    assert c.window_size == (960, 540) and c.fov_deg == pytest.approx(36.17541)


def test_missing_opening_tag_is_recovered_with_a_warning(tmp_path):
    good, bad = tmp_path / "good.xml", tmp_path / "bad.xml"
    good.write_text(XML)
    bad.write_text(XML.replace("<setup3D>\n", ""))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ref = Camera.from_xml(good)
    with pytest.warns(CameraXMLWarning, match="opening <setup3D>"):
        cam = Camera.from_xml(bad)
    assert cam == ref
    assert len(read_xml(bad)[1]) == 1 and read_xml(good)[1] == []


@pytest.mark.parametrize("text", ["<setup3D></setup3D>", "not xml at all <<<", "",
                                  '<setup3D><camera eyepos="1 2" quat="1 0 0 0"/></setup3D>',
                                  '<setup3D><camera eyepos="1 2 3" quat="9 0 0 0"/></setup3D>'])
def test_unrecoverable_camera_is_one_line_error(tmp_path, text):
    path = tmp_path / "camera_params.xml"
    path.write_text(text)
    with pytest.raises(ValueError) as info:
        Camera.from_xml(path)
    assert "\n" not in str(info.value)


def test_shared_cameras_fit_frame_one(shared_data):
    """Projected initial cuboid vs config_01: IoU >= 0.7 everywhere; lower with W and H swapped when |W-H| >= 10 mm."""
    folders = experiment.iter_shared()
    assert len(folders) >= 14
    distinct = 0  # experiments whose W and H differ enough for the swapped box to fit worse
    for folder in folders:
        exp = experiment.load(folder, frames=False)
        frame1 = load_reference(folder / "config_01.png")
        w, h, d = exp.width_mm / 1000, exp.height_mm / 1000, exp.depth_mm / 1000
        fit = iou(box_mask(exp.camera, w, h, d), frame1)
        swapped = iou(box_mask(exp.camera, h, w, d), frame1)
        assert 0.7 <= fit <= 0.95, (folder.name, fit)
        if abs(exp.width_mm - exp.height_mm) >= 10:
            distinct += 1
            assert swapped < fit - 0.05, (folder.name, fit, swapped)
        # the world origin lands near PNG pixel (300-625, 448-475), z = 4 cm ~115 px lower
        o, z = exp.camera.project([[0, 0, 0], [0, 0, 0.04]], (1920, 1080))
        assert 290 <= o[0] <= 635 and 440 <= o[1] <= 480, (folder.name, o)
        assert 100 <= z[1] - o[1] <= 130
    assert distinct >= 5
