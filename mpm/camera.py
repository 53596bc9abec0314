"""Calibrated pinhole camera of an experiment (``camera_params.xml``) and world-to-pixel projection.

Convention (the reference implementation's): the stored quaternion (w, x, y, z) rotates camera axes into the
Y-up simulation frame; the camera looks along its local -Z, local +Y is up, local +X is right; ``fov`` is
the VERTICAL field of view in degrees. A world point X maps to camera coordinates X_c = R^T (X - e) and
to continuous pixel coordinates

    u = W_img/2 + f * X_c,x / (-X_c,z),   v = H_img/2 - f * X_c,y / (-X_c,z),   f = (H_img/2) / tan(fov/2)

with u measured from the left edge and v from the TOP edge; pixel (col, row) = (floor(u), floor(v)), and a
pixel counts as covered when its centre (col + 0.5, row + 0.5) is. World points are in metres in the
reference frame: origin at the bottom back corner of the specimen on the far side wall, x along the flow
(width W), y up, z towards the camera. The XML stores ``eyepos`` in cm; a :class:`Camera` holds metres.
"""
from __future__ import annotations

import math
import re
import warnings
import xml.etree.ElementTree as ET
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from mpm.params import WORKING_SIZE

NEAR_M = 1e-3  # points closer than this in front of the eye do not project (returned as NaN)


class CameraXMLWarning(UserWarning):
    """A camera_params.xml that had to be repaired while reading (e.g. a missing opening tag)."""


# the render window the camera XML describes, where it does not say (its intrinsics are in these pixels); not
# the working image size of the silhouettes (mpm.params.WORKING_SIZE), though today both are 960 x 540
XML_WINDOW_SIZE = (960, 540)

@dataclass(frozen=True)
class Camera:
    eyepos_m: tuple[float, float, float]
    quat: tuple[float, float, float, float]  # (w, x, y, z), unit, simulation (OpenGL) convention
    fov_deg: float = 36.17541  # vertical
    window_size: tuple[int, int] = XML_WINDOW_SIZE  # (width, height) of the render window in the XML

    def __post_init__(self):
        eye = tuple(float(v) for v in self.eyepos_m)
        q = tuple(float(v) for v in self.quat)
        win = tuple(int(v) for v in self.window_size)
        if len(eye) != 3 or not all(map(math.isfinite, eye)):
            raise ValueError(f"camera eyepos must be 3 finite numbers, got {self.eyepos_m!r}")
        if len(q) != 4 or not all(map(math.isfinite, q)):
            raise ValueError(f"camera quat must be 4 finite numbers (w x y z), got {self.quat!r}")
        norm = math.sqrt(sum(v * v for v in q))
        if not 0.9 < norm < 1.1:
            raise ValueError(f"camera quat is not a unit quaternion (|q| = {norm:.4g})")
        if not 1.0 < float(self.fov_deg) < 179.0:
            raise ValueError(f"camera fov must be in (1, 179) degrees, got {self.fov_deg!r}")
        if len(win) != 2 or min(win) <= 0:
            raise ValueError(f"camera window_size must be two positive integers, got {self.window_size!r}")
        object.__setattr__(self, "eyepos_m", eye)
        object.__setattr__(self, "quat", tuple(v / norm for v in q))
        object.__setattr__(self, "fov_deg", float(self.fov_deg))
        object.__setattr__(self, "window_size", win)

    # ----------------------------------------------------------------------------------- construction
    @classmethod
    def default(cls) -> "Camera":
        """A plausible camera for emulated experiments: in front of and above the box, pitched 30 deg down."""
        pitch = math.radians(-30.0)  # rotation about +x
        return cls(eyepos_m=(0.09, 0.135, 0.27), quat=(math.cos(pitch / 2), math.sin(pitch / 2), 0.0, 0.0),
                   fov_deg=36.17541, window_size=XML_WINDOW_SIZE)

    @classmethod
    def from_xml(cls, path) -> "Camera":
        """Read ``camera_params.xml`` leniently; repairs are reported with :class:`CameraXMLWarning`."""
        camera, notes = read_xml(path)
        for note in notes:
            warnings.warn(note, CameraXMLWarning, stacklevel=2)
        return camera

    def to_dict(self) -> dict:
        d = asdict(self)
        d["eyepos_m"], d["quat"], d["window_size"] = list(self.eyepos_m), list(self.quat), list(self.window_size)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "Camera":
        try:
            return cls(eyepos_m=tuple(d["eyepos_m"]), quat=tuple(d["quat"]), fov_deg=d.get("fov_deg", 36.17541),
                       window_size=tuple(d.get("window_size", XML_WINDOW_SIZE)))
        except (KeyError, TypeError) as exc:
            raise ValueError(f"not a camera dictionary: {exc}") from None

    def to_xml(self) -> str:
        """The ``camera_params.xml`` text (eyepos in cm) that :meth:`from_xml` reads back."""
        eye = " ".join(f"{100.0 * v:.8f}" for v in self.eyepos_m)
        quat = " ".join(f"{v:.8f}" for v in self.quat)
        return (f'<?xml version="1.0"?>\n<setup3D>\n<camera eyepos="{eye}" quat="{quat}" '
                f'window_size="{self.window_size[0]} {self.window_size[1]}" fov="{self.fov_deg:.5f}"/>\n</setup3D>\n')

    # ------------------------------------------------------------------------------------- geometry
    @property
    def rotation(self) -> np.ndarray:
        """R(q): columns are the camera's local x (right), y (up), z (backwards) axes in world coordinates."""
        w, x, y, z = self.quat
        return np.array([
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ])

    def focal_px(self, image_height: int) -> float:
        """Focal length in pixels for an image ``image_height`` rows high (fov is vertical)."""
        return 0.5 * image_height / math.tan(math.radians(self.fov_deg) / 2)

    def to_camera(self, points_m) -> np.ndarray:
        """World points (N, 3) in metres -> camera coordinates X_c = R^T (X - e); the view axis is -Z_c."""
        d = np.asarray(points_m, dtype=np.float64).reshape(-1, 3) - np.asarray(self.eyepos_m)
        r = self.rotation
        # written out rather than d @ r: a BLAS call on a busy machine can stall far longer than this takes
        return np.stack([d[:, 0] * r[0, j] + d[:, 1] * r[1, j] + d[:, 2] * r[2, j] for j in range(3)], axis=1)

    def depth(self, points_m) -> np.ndarray:
        """Distance of each point in front of the eye along the view axis (metres)."""
        return -self.to_camera(points_m)[:, 2]

    def project(self, points_m, image_size=WORKING_SIZE) -> np.ndarray:
        """(N, 2) continuous pixel coordinates (u right, v down, origin at the top-left image edge).

        Points not in front of the camera come back as NaN.
        """
        return self.project_with_depth(points_m, image_size)[0]

    def project_with_depth(self, points_m, image_size=WORKING_SIZE) -> tuple[np.ndarray, np.ndarray]:
        """(:meth:`project`, :meth:`depth`) in one pass."""
        width, height = image_size_of(image_size)
        pc = self.to_camera(points_m)
        d = -pc[:, 2]
        f = self.focal_px(height)
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = np.stack([0.5 * width + f * pc[:, 0] / d, 0.5 * height - f * pc[:, 1] / d], axis=1)
        uv[~(d >= NEAR_M)] = np.nan
        return uv, d


def image_size_of(image_size) -> tuple[int, int]:
    """Validated (width, height) in pixels; one-line ValueError otherwise."""
    try:
        width, height = (int(v) for v in image_size)
    except (TypeError, ValueError):
        raise ValueError(f"image_size must be (width, height), got {image_size!r}") from None
    if width <= 0 or height <= 0:
        raise ValueError(f"image_size must be positive, got {image_size!r}")
    return width, height


# ---------------------------------------------------------------------------------------- XML reading
_ELEMENT = re.compile(r"<\s*camera\b([^<>]*?)/?\s*>", re.S)
_ATTR = re.compile(r"([A-Za-z_][\w.-]*)\s*=\s*\"([^\"]*)\"")


def _numbers(attrs: dict, key: str, count: int, where: str) -> tuple[float, ...]:
    if key not in attrs:
        raise ValueError(f"{where}: <camera> has no {key} attribute")
    try:
        values = tuple(float(v) for v in attrs[key].replace(",", " ").split())
    except ValueError:
        raise ValueError(f"{where}: <camera {key}=\"{attrs[key]}\"> is not numeric") from None
    if len(values) != count:
        raise ValueError(f"{where}: <camera {key}> needs {count} numbers, got {len(values)}")
    return values


def read_xml(path) -> tuple[Camera, list[str]]:
    """Parse ``camera_params.xml``; returns the camera and a list of one-line notes about repairs made.

    The XML is parsed strictly first; when that fails (one shared file lacks its opening ``<setup3D>``
    tag) the ``<camera .../>`` element is recovered with a regular expression and a note is returned.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"camera file not found: {path}")
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise ValueError(f"cannot read {path}: {exc.strerror or exc}") from None
    notes: list[str] = []
    attrs = None
    try:
        root = ET.fromstring(text)
        el = root if root.tag == "camera" else root.find(".//camera")
        if el is not None:
            attrs = dict(el.attrib)
    except ET.ParseError as exc:
        found = _ELEMENT.findall(text)
        if found:
            attrs = dict(_ATTR.findall(found[0]))
            problem = ("missing its opening <setup3D> tag" if "</setup3D>" in text and "<setup3D" not in text
                       else f"not well-formed XML ({str(exc).splitlines()[0]})")
            notes.append(f"{path.name} is {problem}; recovered its <camera> element")
    if attrs is None:
        raise ValueError(f"{path}: no <camera> element could be recovered")
    where = str(path)
    eye_cm = _numbers(attrs, "eyepos", 3, where)
    quat = _numbers(attrs, "quat", 4, where)
    fov = _numbers(attrs, "fov", 1, where)[0] if "fov" in attrs else 36.17541
    win = _numbers(attrs, "window_size", 2, where) if "window_size" in attrs else XML_WINDOW_SIZE
    try:
        camera = Camera(eyepos_m=tuple(0.01 * v for v in eye_cm), quat=quat, fov_deg=fov,
                        window_size=(int(round(win[0])), int(round(win[1]))))
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None
    return camera, notes
