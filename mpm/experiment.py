"""Experiment folders: ``settings.xml``, ``camera_params.xml`` and ``config_01.png .. config_08.png``.

Reading follows the reference implementation's conventions:
- the setup (W along the flow, H) comes from the ``<cuboid max="W H D+0.15">``, which the reference MPM
  uses; ``<setup W H>`` and the folder name ``ref_<Material>_<H>_<W>_<k>`` are cross-checked and a
  disagreement is a warning (one shared folder has a swapped ``<setup>``);
- the depth D is read from the static wall boxes (never assumed to be 4 cm: 3.99 and 4.15 occur);
- the density is ``<setup RHO>`` in g/cm^3 (the cuboid's density attribute is ignored by the reference);
- ``initial_material`` is CGS (eta in dyn s^n/cm^2, sigmaY in dyn/cm^2) and is converted to SI;
- the camera XML is read leniently (one shared file lacks its opening tag).
Everything returned is SI (metres, kg/m^3, Pa) except the setup, which is in millimetres (``*_mm``).
"""
from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mpm import camera as _camera
from mpm.camera import Camera
from mpm.loss import load_reference
from mpm.params import DEFAULT_DENSITY_KG_M3, DEFAULT_DEPTH_MM, FPS, N_FRAMES, WORKING_SIZE
from mpm.ranges import check_density
FRAME_TIMES_S = tuple(k / FPS for k in range(1, N_FRAMES + 1))  # frame k <-> config_k at t = k/24 s
WALL_OVERLAP_CM = 0.15  # the reference cuboid reaches 0.15 cm into the back, floor and far walls
_FRAME_NAME = re.compile(r"^config_(\d+)\.png$", re.I)
_FOLDER_NAME = re.compile(r"^ref_.+_(\d+(?:\.\d+)?)_(\d+(?:\.\d+)?)_(\d+)$")  # ref_<material>_<H cm>_<W cm>_<k>


@dataclass
class Experiment:
    """One dam-break recording. Setup in mm, everything else SI; frames are bool masks (True = material)."""

    name: str
    path: Path | None  # None: emulated footage (similarity.emulation)
    width_mm: float
    height_mm: float
    depth_mm: float
    density: float  # kg/m^3
    camera: Camera
    frames: np.ndarray  # (8, 540, 960) bool at the working size
    initial_material: dict | None = None  # {"eta": Pa s^n, "n": -, "sigma_y": Pa}
    setup_index: int | None = None  # k of ref_<...>_<k> when the folder name carries it
    warnings: list[str] = field(default_factory=list)

    @property
    def frame_times_s(self) -> tuple[float, ...]:
        return FRAME_TIMES_S[: len(self.frames)]

    @property
    def image_size(self) -> tuple[int, int]:
        return (int(self.frames.shape[2]), int(self.frames.shape[1]))


# ------------------------------------------------------------------------------------- XML helpers
_TAG = r"<\s*{}\b([^<>]*?)/?\s*>"
_ATTR = re.compile(r"([A-Za-z_][\w.-]*)\s*=\s*\"([^\"]*)\"")


def _elements(path: Path, notes: list[str]) -> dict[str, list[dict]]:
    """Attribute dicts of the settings elements, parsed strictly, or recovered with a note."""
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise ValueError(f"cannot read {path}: {exc.strerror or exc}") from None
    tags = ("setup", "initial_material", "cuboid", "static_box")
    try:
        root = ET.fromstring(text)
        return {t: [dict(e.attrib) for e in root.iter(t)] for t in tags}
    except ET.ParseError as exc:
        found = {t: [dict(_ATTR.findall(m)) for m in re.findall(_TAG.format(t), text, re.S)] for t in tags}
        if not found["cuboid"] and not found["setup"]:
            raise ValueError(f"{path}: unreadable XML ({str(exc).splitlines()[0]}) and no <setup> or <cuboid> "
                             f"element could be recovered") from None
        notes.append(f"{path.name} is not well-formed XML ({str(exc).splitlines()[0]}); recovered its elements")
        return found


def _floats(attrs: dict, key: str, count: int, where: str) -> tuple[float, ...] | None:
    if key not in attrs:
        return None
    try:
        values = tuple(float(v) for v in attrs[key].replace(",", " ").split())
    except ValueError:
        raise ValueError(f"{where}: {key}=\"{attrs[key]}\" is not numeric") from None
    if len(values) != count or not all(map(math.isfinite, values)):
        raise ValueError(f"{where}: {key} needs {count} finite numbers, got \"{attrs[key]}\"")
    return values


def _setup_from_xml(el: dict[str, list[dict]], where: str, name: str, notes: list[str]):
    """(W cm, H cm, D cm, RHO g/cm^3) from the parsed settings, with cross-checks appended to notes."""
    setup = el["setup"][0] if el["setup"] else {}
    cub = el["cuboid"][0] if el["cuboid"] else {}
    cmax = _floats(cub, "max", 3, f"{where} <cuboid>")
    s_w = _floats(setup, "W", 1, f"{where} <setup>")
    s_h = _floats(setup, "H", 1, f"{where} <setup>")
    m = _FOLDER_NAME.search(name)
    n_hw = (float(m.group(1)), float(m.group(2))) if m else None

    if cmax is not None:
        width, height = cmax[0], cmax[1]
        source = "the cuboid"
    elif s_w is not None and s_h is not None:
        width, height = s_w[0], s_h[0]
        source = "<setup>"
        notes.append(f"settings.xml has no <cuboid>; setup W={width:g} H={height:g} cm taken from <setup>")
    elif n_hw is not None:
        height, width = n_hw
        source = "the folder name"
        notes.append(f"settings.xml has neither <cuboid> nor <setup> W/H; setup taken from the folder name")
    else:
        raise ValueError(f"{where}: no setup: neither <cuboid max> nor <setup W H> found")

    def close(a, b):
        return abs(a - b) < 0.051

    if source == "the cuboid" and s_w is not None and s_h is not None and not (close(s_w[0], width) and
                                                                                close(s_h[0], height)):
        swapped = close(s_w[0], height) and close(s_h[0], width)
        notes.append(f"settings.xml <setup W=\"{s_w[0]:g}\" H=\"{s_h[0]:g}\"> "
                     f"{'is swapped against' if swapped else 'disagrees with'} the cuboid "
                     f"(W={width:g}, H={height:g} cm); using the cuboid")
    if n_hw is not None and not (close(n_hw[0], height) and close(n_hw[1], width)):
        notes.append(f"folder name says H={n_hw[0]:g} W={n_hw[1]:g} cm but {source} says "
                     f"W={width:g} H={height:g} cm; using {source}")

    # depth: the back wall box [-1, 0] x [0, ..] x [0, D] (or the near side wall starting at z = D)
    depth = None
    for box in el["static_box"]:
        bmin = _floats(box, "min", 3, f"{where} <static_box>")
        bmax = _floats(box, "max", 3, f"{where} <static_box>")
        if bmin is None or bmax is None:
            continue
        if bmax[0] <= 1e-6 and bmin[1] >= -1e-6 and abs(bmin[2]) < 1e-6 and bmax[2] > 0:
            depth = bmax[2]  # back wall
            break
    if depth is None:
        for box in el["static_box"]:
            bmin = _floats(box, "min", 3, f"{where} <static_box>")
            bmax = _floats(box, "max", 3, f"{where} <static_box>")
            if bmin is not None and bmax is not None and bmin[1] >= -1e-6 and bmin[2] > 0.5:
                depth = bmin[2]  # near side wall
                break
    if depth is None and cmax is not None:
        depth = cmax[2] - WALL_OVERLAP_CM
        notes.append(f"no wall boxes in settings.xml; depth {depth:g} cm taken from the cuboid")
    if depth is None:
        depth = 4.0
        notes.append("no wall boxes or cuboid in settings.xml; depth assumed 4 cm")

    rho = _floats(setup, "RHO", 1, f"{where} <setup>")
    if rho is None:
        rho = _floats(cub, "density", 1, f"{where} <cuboid>")
        if rho is None:
            raise ValueError(f"{where}: no density: <setup RHO> is missing")
        notes.append(f"settings.xml has no <setup RHO>; density {rho[0]:g} g/cm^3 taken from the cuboid")
    return width, height, depth, rho[0]


def _initial_material(el: dict[str, list[dict]], where: str) -> dict | None:
    if not el["initial_material"]:
        return None
    attrs = el["initial_material"][0]
    vals = {}
    for key in ("eta", "n", "sigmaY"):
        v = _floats(attrs, key, 1, f"{where} <initial_material>")
        if v is None:
            raise ValueError(f"{where}: <initial_material> lacks {key}")
        vals[key] = v[0]
    if vals["eta"] <= 0 or not 0 < vals["n"] <= 2 or vals["sigmaY"] < 0:
        raise ValueError(f"{where}: unphysical <initial_material> eta={vals['eta']:g} n={vals['n']:g} "
                         f"sigmaY={vals['sigmaY']:g}")
    # CGS -> SI: 1 dyn/cm^2 = 0.1 Pa
    return {"eta": 0.1 * vals["eta"], "n": vals["n"], "sigma_y": 0.1 * vals["sigmaY"]}


def frame_paths(folder) -> list[Path]:
    """config_01.png .. config_08.png of ``folder``; missing or extra frames raise ValueError."""
    folder = Path(folder)
    found = {}
    for p in folder.iterdir():
        m = _FRAME_NAME.match(p.name)
        if m:
            found[int(m.group(1))] = p
    expected = set(range(1, N_FRAMES + 1))
    missing = sorted(expected - set(found))
    extra = sorted(set(found) - expected)
    if missing:
        raise ValueError(f"{folder.name}: {len(found)} frames found, missing "
                         f"{', '.join(f'config_{k:02d}.png' for k in missing)} (need config_01..{N_FRAMES:02d})")
    if extra:
        raise ValueError(f"{folder.name}: unexpected extra frames "
                         f"{', '.join(found[k].name for k in extra)} (need exactly config_01..{N_FRAMES:02d})")
    return [found[k] for k in range(1, N_FRAMES + 1)]


def _required_file(path: Path, name: str) -> Path:
    if path.is_dir():
        raise ValueError(f"{name}: {path.name} is a folder, not a file")
    if not path.is_file():
        raise FileNotFoundError(f"{name}: {path.name} not found")
    return path


def load(path, *, frames: bool = True) -> Experiment:
    """Read and validate an experiment folder; problems raise one-line ValueError/FileNotFoundError.

    Recoverable oddities (a repaired XML, a swapped ``<setup>``, ...) are kept in ``Experiment.warnings``.
    ``frames=False`` skips the images (frames is then an empty (0, 540, 960) array).
    """
    folder = Path(path)
    if not folder.exists():
        raise FileNotFoundError(f"experiment folder not found: {folder}")
    if not folder.is_dir():
        raise ValueError(f"{folder} is a file, not an experiment folder")
    name = folder.resolve().name
    notes: list[str] = []
    settings = _required_file(folder / "settings.xml", name)
    el = _elements(settings, notes)
    width_cm, height_cm, depth_cm, rho = _setup_from_xml(el, f"{name}/settings.xml", name, notes)
    for label, v in (("width", width_cm), ("height", height_cm), ("depth", depth_cm)):
        if not 0.5 <= v <= 30.0:
            raise ValueError(f"{name}: implausible {label} {v:g} cm in settings.xml")
    check_density(1000.0 * rho, f"{name}: the density in settings.xml,")
    initial = _initial_material(el, f"{name}/settings.xml")

    cam_path = _required_file(folder / "camera_params.xml", name)
    camera, cam_notes = _camera.read_xml(cam_path)
    notes.extend(cam_notes)

    m = _FOLDER_NAME.search(name)
    masks = np.zeros((0, WORKING_SIZE[1], WORKING_SIZE[0]), dtype=bool)
    if frames:
        masks = np.stack([load_reference(p) for p in frame_paths(folder)])
        inverted = [k for k, mask in enumerate(masks, start=1) if mask.mean() > 0.5]
        if inverted:
            notes.append(f"frames {frame_list(inverted)} are more than half material: inverted colours? "
                         f"(material must be black on white)")
    win_w, win_h = camera.window_size
    if abs(win_w * WORKING_SIZE[1] - win_h * WORKING_SIZE[0]) > 0.01 * win_w * WORKING_SIZE[1]:
        notes.append(f"camera window_size {win_w}x{win_h} does not have the frames' aspect ratio "
                     f"{WORKING_SIZE[0]}:{WORKING_SIZE[1]}")
    return Experiment(name=name, path=folder, width_mm=round(10.0 * width_cm, 6), height_mm=round(10.0 * height_cm, 6),
                      depth_mm=round(10.0 * depth_cm, 6), density=1000.0 * rho, camera=camera, frames=masks,
                      initial_material=initial, setup_index=int(m.group(3)) if m else None, warnings=notes)


def frame_list(frames) -> str:
    """1-based frame numbers as text with runs collapsed: [1, 2, 3, 6] -> '1-3, 6'."""
    frames = sorted(int(k) for k in frames)
    runs: list[list[int]] = []
    for k in frames:
        if runs and k == runs[-1][1] + 1:
            runs[-1][1] = k
        else:
            runs.append([k, k])
    return ", ".join(f"{a}" if a == b else f"{a}-{b}" for a, b in runs)


def footage_problems(frames) -> list[str]:
    """Why the footage holds no evidence about the material, one line per reason (empty: usable).

    Footage is no evidence when frames show no material, when the material never moves (all frames
    identical), or when it leaves the image (touches its left or right edge where frame 1 does not).
    """
    masks = np.asarray(frames, dtype=bool)
    if len(masks) == 0:
        return []
    problems = []
    empty = [k for k, m in enumerate(masks, start=1) if not m.any()]
    if empty:
        plural = len(empty) > 1
        problems.append(f"frame{'s' * plural} {frame_list(empty)} of {len(masks)} show{'' if plural else 's'} no material")
    elif len(masks) > 1 and all(np.array_equal(masks[0], m) for m in masks[1:]):
        problems.append(f"the material never moves: frames 1-{len(masks)} are identical")
    else:
        edges0 = (masks[0][:, 0].any(), masks[0][:, -1].any())
        out = [k for k, m in enumerate(masks, start=1)
               if (m[:, 0].any() and not edges0[0]) or (m[:, -1].any() and not edges0[1])]
        if out:
            problems.append(f"the material leaves the image in frame{'s' * (len(out) > 1)} {frame_list(out)} "
                            f"(it reaches the image's edge)")
    return problems


def check_footage(exp: "Experiment") -> None:
    """Raise ValueError when the footage of ``exp`` holds no evidence (see :func:`footage_problems`)."""
    problems = footage_problems(exp.frames)
    if problems:
        raise ValueError(f"{exp.name}: {problems[0]}: nothing to estimate from (check the silhouettes)")


def iter_shared() -> list[Path]:
    """The shared real-world experiment folders (``ref_*`` under the shared data), sorted by name."""
    from mpm.datasets import real_world_dir

    return sorted(p for p in real_world_dir().iterdir() if p.is_dir() and (p / "settings.xml").is_file())


# -------------------------------------------------------------------------------------------- writing
def _png(mask: np.ndarray, path: Path) -> None:
    from PIL import Image

    gray = np.where(mask, 0, 255).astype(np.uint8)
    Image.fromarray(np.repeat(gray[..., None], 3, axis=2), mode="RGB").save(path)


def settings_xml(width_mm: float, height_mm: float, depth_mm: float, density: float,
                 initial_material: dict | None = None) -> str:
    """``settings.xml`` text in the reference layout (cm, g/cm^3, CGS material)."""
    w, h, d, rho = width_mm / 10.0, height_mm / 10.0, depth_mm / 10.0, density / 1000.0
    o = WALL_OVERLAP_CM
    lines = ['<?xml version="1.0"?>', "<Optimizer>", f'  <setup RHO="{rho:g}" H="{h:g}" W="{w:g}"/>']
    if initial_material is not None:
        lines.append(f'  <initial_material eta="{10.0 * initial_material["eta"]:.10g}" '
                     f'n="{initial_material["n"]:.10g}" sigmaY="{10.0 * initial_material["sigma_y"]:.10g}"/>')
    lines += [
        f'  <cuboid min="{-o:f} {-o:f} {-o:f}" max="{w:f} {h:f} {d + o:f}" density="{rho:g}" '
        f'cell_samples_per_dim="2" vel="0.0 0.0 0.0" omega="0.0 0.0 0.0"/>',
        '  <static_box min="-100.000000 -1.000000 -100.000000" max="100.000000 0.000000 100.000000" '
        'boundary_behavior="sticking"/>',
        f'  <static_box min="-1.000000 0.000000 0.000000" max="0.000000 20.000000 {d:f}" boundary_behavior="sticking"/>',
        f'  <static_box min="-1.000000 0.000000 -0.300000" max="{w:f} 20.000000 0.000000" boundary_behavior="sticking"/>',
        f'  <static_box min="-1.000000 0.000000 {d:f}" max="{w:f} 20.000000 {d + 0.3:f}" boundary_behavior="sticking"/>',
        "</Optimizer>",
    ]
    return "\n".join(lines) + "\n"


def write(path, frames, *, width_mm: float, height_mm: float, camera: Camera, density: float = DEFAULT_DENSITY_KG_M3,
          depth_mm: float = DEFAULT_DEPTH_MM, initial_material: dict | None = None) -> Path:
    """Write an experiment folder that :func:`load` reads back: settings.xml, camera_params.xml and
    config_01..08.png at 1920x1080 (black material on white) from 8 bool masks at 960x540 or 1920x1080.
    """
    masks = np.asarray(frames)
    if masks.ndim != 3 or len(masks) != N_FRAMES:
        raise ValueError(f"need {N_FRAMES} masks (8, height, width), got shape {masks.shape}")
    masks = masks.astype(bool)
    width, height = WORKING_SIZE
    if masks.shape[1:] == (height, width):
        masks = masks.repeat(2, axis=1).repeat(2, axis=2)
    elif masks.shape[1:] != (2 * height, 2 * width):
        raise ValueError(f"masks must be {width}x{height} or {2 * width}x{2 * height}, got "
                         f"{masks.shape[2]}x{masks.shape[1]}")
    folder = Path(path)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "settings.xml").write_text(settings_xml(width_mm, height_mm, depth_mm, density, initial_material))
    (folder / "camera_params.xml").write_text(camera.to_xml())
    for k, mask in enumerate(masks, start=1):
        _png(mask, folder / f"config_{k:02d}.png")
    return folder


# ----------------------------------------------------------------------------------- setup vs footage
SWAP_MARGIN = 0.05  # the W/H-swapped box fitting frame 1 better than this flags the stated setup
MIN_CUBOID_IOU = 0.6  # below this the stated setup (or camera) does not match frame 1


def cuboid_mask(exp: Experiment, *, swap: bool = False) -> np.ndarray:
    """The projected initial cuboid [0, W] x [0, H] x [0, D] (W and H exchanged when ``swap``)."""
    from mpm.silhouette import box_mask

    w, h = (exp.height_mm, exp.width_mm) if swap else (exp.width_mm, exp.height_mm)
    return box_mask(exp.camera, w / 1000.0, h / 1000.0, exp.depth_mm / 1000.0, exp.image_size)


def cuboid_fit(exp: Experiment) -> tuple[float, float]:
    """IoU of frame 1 with the projected initial cuboid, as stated and with W and H swapped."""
    from mpm.loss import iou

    if len(exp.frames) == 0:
        raise ValueError(f"{exp.name}: no frames loaded")
    return iou(cuboid_mask(exp), exp.frames[0]), iou(cuboid_mask(exp, swap=True), exp.frames[0])


def setup_warnings(exp: Experiment) -> list[str]:
    """One-line warnings when the stated setup fits frame 1 badly or clearly worse than W/H swapped."""
    fit, swapped = cuboid_fit(exp)
    notes = []
    if swapped > fit + SWAP_MARGIN:
        notes.append(f"the stated setup W={exp.width_mm:g} H={exp.height_mm:g} mm fits frame 1 clearly worse "
                     f"(IoU {fit:.3f}) than with W and H swapped (IoU {swapped:.3f}): are W and H swapped?")
    elif fit < MIN_CUBOID_IOU:
        notes.append(f"the projected initial cuboid fits frame 1 poorly (IoU {fit:.3f} < {MIN_CUBOID_IOU}): "
                     f"check the setup and the camera")
    return notes
