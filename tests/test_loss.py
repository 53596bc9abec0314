"""Reference preprocessing of captured frames and the video loss of eq. 3."""
import numpy as np
import pytest
from PIL import Image

from mpm.loss import frame_loss, frame_losses, iou, load_reference, video_loss


def white(w=1920, h=1080):
    return np.full((h, w, 3), 255, dtype=np.uint8)


def test_two_by_two_mean_and_threshold():
    img = white()
    # block (row 0, col c) gets c black pixels out of 4: means 255, 191.25, 127.5, 63.75, 0
    for c in range(5):
        for j in range(c):
            img[j // 2, 2 * c + j % 2] = 0
    m = load_reference(img)
    assert m.shape == (540, 960)
    assert m[0, :5].tolist() == [False, False, True, True, True]  # > 130 is background
    assert m.sum() == 3


def test_gray_threshold_130_is_material():
    img = np.full((540, 960, 3), 255, dtype=np.uint8)  # already at the working size
    img[0, 0], img[0, 1] = 130, 131
    img[0, 2] = (255, 0, 0)  # gray 0.299 * 255 = 76: material (a few coloured pixels are allowed)
    m = load_reference(img)
    assert m[0, :3].tolist() == [True, False, True] and m.sum() == 2


def test_path_bool_and_rgba_inputs(tmp_path):
    img = white()
    img[100:300, 400:800] = 0
    rgba = np.concatenate([img, np.full(img.shape[:2] + (1,), 7, np.uint8)], axis=2)
    Image.fromarray(rgba, "RGBA").save(tmp_path / "a.png")
    Image.fromarray(img[..., 0], "L").save(tmp_path / "b.png")
    expected = np.zeros((540, 960), bool)
    expected[50:150, 200:400] = True
    for src in (img, tmp_path / "a.png", str(tmp_path / "b.png"), img[..., 0] == 0, expected):
        assert np.array_equal(load_reference(src), expected)


@pytest.mark.parametrize("shape", [(500, 1000, 3), (1080, 1921, 3), (540, 961)])
def test_wrong_size_is_one_line_error(shape):
    with pytest.raises(ValueError, match="expected 1920x1080") as info:
        load_reference(np.full(shape, 255, np.uint8))
    assert "\n" not in str(info.value)


def test_photograph_is_rejected(tmp_path):
    rng = np.random.default_rng(0)
    photo = rng.integers(0, 256, size=(1080, 1920, 3), dtype=np.uint8)
    Image.fromarray(photo).save(tmp_path / "photo.png")
    with pytest.raises(ValueError, match="not a binary silhouette") as info:
        load_reference(tmp_path / "photo.png")
    assert "\n" not in str(info.value)
    # a smooth grey-level photograph is rejected as well
    grad = np.tile(np.linspace(0, 255, 1920, dtype=np.uint8), (1080, 1))
    with pytest.raises(ValueError, match="not a binary silhouette"):
        load_reference(grad)


def test_unreadable_and_missing_files(tmp_path):
    (tmp_path / "x.png").write_bytes(b"not a png")
    with pytest.raises(ValueError):
        load_reference(tmp_path / "x.png")
    with pytest.raises(FileNotFoundError):
        load_reference(tmp_path / "missing.png")


def test_loss_properties():
    rng = np.random.default_rng(1)
    a = rng.random((8, 54, 96)) < 0.3
    b = rng.random((8, 54, 96)) < 0.3
    assert frame_loss(a[0], a[0]) == 0.0
    assert frame_loss(a[0], ~a[0]) == 1.0
    assert frame_loss(a[0], b[0]) == frame_loss(b[0], a[0])
    # binary masks: mean squared difference (eq. 3) = fraction of differing pixels
    mse = np.mean((a.astype(float) - b.astype(float)) ** 2)
    assert video_loss(a, b) == pytest.approx(mse)
    assert video_loss(a, b) == pytest.approx(np.mean([frame_loss(x, y) for x, y in zip(a, b)]))
    assert frame_losses(a, b).shape == (8,)
    one = np.zeros((54, 96), bool)
    one[0, 0] = True
    assert frame_loss(one, np.zeros_like(one)) == pytest.approx(1 / (54 * 96))
    with pytest.raises(ValueError):
        frame_loss(a[0], a[0, :10])
    with pytest.raises(ValueError):
        video_loss(a, b[:7])


def test_iou():
    a = np.zeros((10, 10), bool)
    b = np.zeros((10, 10), bool)
    a[:5], b[:, :5] = True, True
    assert iou(a, a) == 1.0 and iou(a, ~a) == 0.0
    assert iou(a, b) == pytest.approx(25 / 75)
    assert iou(np.zeros_like(a), np.zeros_like(a)) == 1.0


def test_shared_frames(shared_data):
    folder = shared_data / "real_world" / "ref_JapaneseThickenedWorcestershireSauce_2.0_3.0_2"
    frames = np.stack([load_reference(folder / f"config_{k:02d}.png") for k in range(1, 9)])
    fractions = frames.mean(axis=(1, 2))
    assert np.all((fractions > 0.017) & (fractions < 0.22))  # material is 1.7-22 % of the image
    assert np.all(np.diff(fractions) > 0)  # the puddle spreads
    losses = frame_losses(frames[:-1], frames[1:])
    assert np.all((losses > 0) & (losses < 0.02))
    assert video_loss(frames, frames) == 0.0
    # the half-size frame is exactly the reference's 2x2 mean: recompute in float and compare
    rgb = np.asarray(Image.open(folder / "config_05.png").convert("RGB"), dtype=float)
    mean = rgb.reshape(540, 2, 960, 2, 3).mean(axis=(1, 3)) @ np.array([0.299, 0.587, 0.114])
    assert np.count_nonzero(frames[4] != (mean <= 130)) <= 5  # only rounding ties may differ
