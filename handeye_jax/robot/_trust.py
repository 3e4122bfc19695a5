"""Whether a result is what its own parameters and data say: checks in NumPy alone.

A result's ``content_sha256`` tells a file as it was written from one edited since, but whoever
edits a file can recompute it. So every command that reads a result (``predict`` without JAX,
the others through :func:`~handeye_jax.load_result`) checks what an edit cannot keep
consistent short of fitting again, and ``predict`` and ``export`` refuse the same files:

* the ``frames`` are what the parameters give (``stage1.params`` through the model's NumPy
  twin, :mod:`._npframes`; ``stage2.params``, ``rig``, ``centres_mm``, ``heights``);
* the ``rig`` is the one of the ``data`` it was fitted on: intrinsics, hand-angle convention
  and first capture;
* the residuals the fit recorded (``stage1`` and ``stage2.residuals_mm``) are what the
  parameters give at the data's landmarks, replayed with the NumPy chain (:mod:`._npchain`);
* the hand commands at its own landmarks lie within the rig's reach (:class:`Reach`).

A failure is an :class:`~handeye_jax.InputError` naming the file and the field.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from .._core import MAX_DEG, MAX_MM, MAX_PX, InputError, Reader
from ..data import undistort_px
from . import _npchain
from ._frames import TRANSLATIONS, Affine, Frames
from ._npframes import AFFINE_PARAMS, MODELS, chain_of, mount_pose_pen

#: How far beyond the hand positions a calibration recorded (its captures and touches) a hand
#: command may lie, mm: a camera's view from those poses at a rig's working depths, with room
#: to spare; a command beyond is a wrong point or a wrong result, not a target.
REACH_MARGIN_MM = 500.0
#: How closely the recorded residuals must match the replayed ones, mm (float64 gives 1e-10).
RESIDUAL_TOL_MM = 1e-6
#: How closely the frames must match those the parameters give (relative to max(1, |value|)),
#: as :func:`~handeye_jax.calibration.load_frames` checks them with JAX.
FRAMES_TOL = 1e-9
UNDETERMINED = tuple(f"{t}.z" for t in TRANSLATIONS)
EDITED = "the file was edited after the fit"


@dataclass(frozen=True)
class Reach:
    """Where a hand command may go: the box of the hand positions a calibration recorded,
    widened by ``margin_mm`` on every side (mm, base frame).

    Attributes:
        lo_mm, hi_mm: the recorded positions' smallest and largest x, y, z, mm (z NaN when
            none was recorded: then z is not checked).
        margin_mm: how far beyond them a command may lie, mm.
    """

    lo_mm: np.ndarray
    hi_mm: np.ndarray
    margin_mm: float = REACH_MARGIN_MM

    @classmethod
    def around(cls, positions_mm: Any, margin_mm: float = REACH_MARGIN_MM) -> Reach:
        """The reach around hand positions ``(k, 3)`` (or ``(k, 2)``), mm; NaN: unknown."""
        p = np.asarray(positions_mm, dtype=np.float64).reshape(-1, np.shape(positions_mm)[-1])
        p = np.column_stack([p, np.full((len(p), 3 - p.shape[1]), np.nan)])
        known = np.isfinite(p)
        lo = np.where(known, p, np.inf).min(axis=0)
        hi = np.where(known, p, -np.inf).max(axis=0)
        none = ~known.any(axis=0)
        lo[none], hi[none] = np.nan, np.nan
        return cls(lo, hi, margin_mm)

    @classmethod
    def of_frames(cls, frames: Frames) -> Reach:
        """The reach a frames document alone gives: around its capture and the tablet's
        origin (the most it records of where the hand was)."""
        return cls.around([frames.capture_position_mm, frames.t_base_tablet_mm])

    def including(self, positions_mm: Any) -> Reach:
        """This reach grown to hold more hand positions (e.g. the captures of points)."""
        if positions_mm is None:
            return self
        more = Reach.around(positions_mm, self.margin_mm)
        lo, hi = np.fmin(self.lo_mm, more.lo_mm), np.fmax(self.hi_mm, more.hi_mm)
        return Reach(lo, hi, self.margin_mm)

    def excess_mm(self, commands_mm: Any) -> np.ndarray:
        """How far each hand command ``(n, 2)`` or ``(n, 3)`` lies outside the reach, mm
        (0 inside); a coordinate without recorded positions is not checked."""
        c = np.asarray(commands_mm, dtype=np.float64)
        k = c.shape[1]
        lo, hi = self.lo_mm[:k] - self.margin_mm, self.hi_mm[:k] + self.margin_mm
        out = np.fmax(np.fmax(lo - c, c - hi), 0.0)  # fmax: a NaN bound checks nothing
        out[~np.isfinite(c)] = np.inf
        return np.sqrt((out**2).sum(axis=1))

    def describe(self) -> str:
        """E.g. ``x 150 to 903 mm, y -580 to 514 mm: the hand positions the calibration
        recorded ± 500 mm``."""
        parts = [f"{a} {lo - self.margin_mm:.0f} to {hi + self.margin_mm:.0f} mm"
                 for a, lo, hi in zip("xyz", self.lo_mm, self.hi_mm, strict=True)
                 if math.isfinite(lo)]  # fmt: skip
        return (f"{', '.join(parts)}: the hand positions the calibration recorded ± "
                f"{self.margin_mm:.0f} mm")  # fmt: skip


def check_reach(
    path: str | Path, commands_mm: np.ndarray, reach: Reach, result: str | Path
) -> None:
    """Refuse hand commands beyond ``reach`` (:class:`Reach`): an
    :class:`InputError` naming the points file ``path`` and the first such point's line."""
    far = reach.excess_mm(commands_mm)
    i = int(np.argmax(far)) if len(far) else 0
    if len(far) and far[i] > 0:
        command = ", ".join(f"{c:.1f}" for c in commands_mm[i])
        raise InputError(path, f"line {i + 2}", f"its hand command ({command}) mm lies "
                         f"{far[i]:.0f} mm outside the rig's reach ({reach.describe()}): check "
                         f"the point's values, or the result {str(result)!r}")  # fmt: skip


class Checked(NamedTuple):
    """A result that passed :func:`check_result_document`: its frames and its rig's reach."""

    frames: Frames
    reach: Reach


def check_result_document(
    doc: dict[str, Any],
    path: str | Path | None,
    frames_of_parameters: Callable[[], Frames] | None = None,
) -> Checked:
    """Check a parsed result document (see the module's docstring); raises
    :class:`InputError` naming ``path`` and the field that disagrees.

    Args:
        doc: the parsed ``handeye-jax.result/1`` document.
        path: its file, for messages.
        frames_of_parameters: the frames the parameters give, for a model without a NumPy
            twin (:mod:`._npframes`); without it, such a model's frames are taken as stored.
    """
    c = _Doc(path)
    computed = _frames_of_parameters(c, doc)
    if computed is None and frames_of_parameters is not None:
        computed = frames_of_parameters()
    stored = Frames.from_dict(doc["frames"], path, "frames") if "frames" in doc else None
    if stored is not None and computed is not None:
        _compare_frames(c, stored, computed)
    frames = computed if computed is not None else stored
    if stored is not None and computed is not None:  # the stage to deploy: the file's choice
        frames = replace(frames, deploy_stage=stored.deploy_stage)
    if frames is None:
        c.fail("model", f"{doc.get('model')!r:.40} has no NumPy twin and the file no frames")
    data = doc.get("data")
    if not isinstance(data, dict):  # an older result, or one made without its data
        if stored is not None:
            frames = replace(frames, distortion=stored.distortion)
        return Checked(frames, Reach.of_frames(frames))
    rows = _rows(c, data)
    if stored is not None and stored.distortion != rows.distortion:
        c.fail("frames.distortion", f"is {stored.distortion} but the data's camera has "
               f"{rows.distortion}: {EDITED}")  # fmt: skip
    frames = replace(frames, distortion=rows.distortion)
    _compare_rig(c, doc, rows)
    reach = Reach.around(rows.positions_mm)
    for key, (e1, e2, command) in (_replay(frames, rows) if rows.n else {}).items():
        _compare_residuals(c, doc, key, e1, e2, rows.n)
        far = reach.excess_mm(command)
        m = int(np.argmax(far))
        if far[m] > 0:
            c.fail(f"{key}.residuals_mm[{m}]", f"the hand command at the data's row {m} lies "
                   f"{far[m]:.0f} mm outside the rig's reach ({reach.describe()}): not a "
                   "calibration of this rig")  # fmt: skip
    return Checked(frames, reach)


class _Doc(Reader):
    """A reader of the fields the checks use, naming them as the file does."""

    def get(self, table: Any, key: str, where: str) -> Any:
        if not isinstance(table, dict):
            self.fail(where, "must be an object")
        if key not in table:
            self.fail(f"{where}.{key}" if where else key, "missing")
        return table[key]

    def column(self, items: Any, key: str | None, where: str, shape: tuple[int, ...],
               limit: float = MAX_MM) -> np.ndarray:  # fmt: skip
        """``items[i][key]`` (or ``items[i]``) as one float array ``(len(items), *shape)``."""
        if not isinstance(items, list):
            self.fail(where, "must be an array")
        try:
            a = np.array([it[key] if key is not None else it for it in items], dtype=np.float64)
            if a.shape == (len(items), *shape) and (np.abs(a) <= limit).all():
                return a
        except (TypeError, ValueError, KeyError, IndexError, OverflowError):
            pass
        for i, it in enumerate(items):  # find the first bad one, to name it
            w = f"{where}[{i}]"
            value = self.get(it, key, w) if key is not None else it
            w = f"{w}.{key}" if key is not None else w
            if shape:
                self.vector(value, w, shape[0], limit)
            else:
                self.number(value, w, limit=limit)
        self.fail(where, f"must hold arrays of {shape} numbers")  # pragma: no cover


def _frames_of_parameters(c: _Doc, doc: dict[str, Any]) -> Frames | None:
    """The frames the document's parameters give, or ``None`` for a model without a twin."""
    model = c.get(doc, "model", "")
    if not isinstance(model, str) or model not in MODELS:
        return None
    names = MODELS[model][0]
    p1 = c.get(c.get(doc, "stage1", ""), "params", "stage1")
    p2 = c.get(c.get(doc, "stage2", ""), "params", "stage2")
    params = {n: c.number(c.get(p1, n, "stage1.params"), f"stage1.params.{n}") for n in names}
    affine = {n: c.number(c.get(p2, n, "stage2.params"), f"stage2.params.{n}")
              for n in AFFINE_PARAMS}  # fmt: skip
    rig = c.get(doc, "rig", "")
    cam = c.get(rig, "camera_px", "rig")
    fx, fy, cx, cy = (c.number(c.get(cam, k, "rig.camera_px"), f"rig.camera_px.{k}", limit=MAX_PX)
                      for k in ("fx", "fy", "cx", "cy"))  # fmt: skip
    angle = c.get(rig, "hand_angle", "rig")
    zero = c.number(c.get(angle, "zero_deg", "rig.hand_angle"), "rig.hand_angle.zero_deg")
    sign = c.number(c.get(angle, "sign", "rig.hand_angle"), "rig.hand_angle.sign")
    if sign not in (1.0, -1.0):
        c.fail("rig.hand_angle.sign", f"must be 1 or -1 (got {sign})")
    capture = c.vector(c.get(rig, "capture_hand_position_mm", "rig"),
                       "rig.capture_hand_position_mm", 3, MAX_MM)  # fmt: skip
    cap_angle = rig.get("capture_hand_angle_deg")
    cap_angle = (-zero * sign if cap_angle is None
                 else c.number(cap_angle, "rig.capture_hand_angle_deg", limit=MAX_DEG))  # fmt: skip
    centres = c.column(c.get(doc, "centres_mm", ""), None, "centres_mm", (2,))
    if len(centres) != 2:
        c.fail("centres_mm", "must be a list of two [x, y] points")
    heights = doc.get("heights")
    z = None
    if isinstance(heights, dict) and "pen_minus_camera_mm" in heights:
        z = c.number(heights["pen_minus_camera_mm"], "heights.pen_minus_camera_mm", limit=MAX_MM)
    R_hc, t_hc, R_bt, t_bt, t_hp = mount_pose_pen(model, params)
    A1, A2 = (Affine(*(affine[f"{k}{i}"] for k in ("X", "Y", "theta", "Sx", "Sy")))
              for i in (1, 2))  # fmt: skip
    try:
        return Frames(
            R_hand_camera=R_hc, t_hand_camera_mm=t_hc, R_base_tablet=R_bt, t_base_tablet_mm=t_bt,
            t_hand_pen_mm=t_hp, fx_px=fx, fy_px=fy, cx_px=cx, cy_px=cy, hand_angle_zero_deg=zero,
            hand_angle_sign=int(sign), capture_position_mm=capture,
            capture_hand_angle_deg=cap_angle, A1=A1, A2=A2, centres_mm=centres,
            undetermined=UNDETERMINED, model=model, pen_minus_camera_z_mm=z,
        )  # fmt: skip
    except ValueError as e:  # e.g. an angle so large its sine is not finite
        c.fail("stage1.params", f"do not give frames: {e}")


#: Each number of a frames document: (its name there, what it is in :class:`Frames`).
_FRAME_FIELDS: tuple[tuple[str, Callable[[Frames], Any]], ...] = (
    ("T_hand_camera.R", lambda f: f.R_hand_camera),
    ("T_hand_camera.t.mm", lambda f: f.t_hand_camera_mm),
    ("T_base_tablet.R", lambda f: f.R_base_tablet),
    ("T_base_tablet.t.mm", lambda f: f.t_base_tablet_mm),
    ("pen_tip.t_hand_pen.mm", lambda f: f.t_hand_pen_mm),
    ("camera_px", lambda f: f.camera_px),
    ("hand_angle", lambda f: (f.hand_angle_zero_deg, f.hand_angle_sign)),
    ("capture.hand_position_mm", lambda f: f.capture_position_mm),
    ("capture.hand_angle_deg", lambda f: f.capture_hand_angle_deg),
    ("stage2.A1", lambda f: f.A1.as_tuple()),
    ("stage2.A2", lambda f: f.A2.as_tuple()),
    ("stage2.centres_mm", lambda f: f.centres_mm),
    ("heights.pen_minus_camera_mm",
     lambda f: math.nan if f.pen_minus_camera_z_mm is None else f.pen_minus_camera_z_mm),
)  # fmt: skip


def _numbers(x: Any) -> str:
    a = np.ravel(np.asarray(x, dtype=np.float64))
    text = ", ".join("null" if math.isnan(v) else f"{v:.10g}" for v in a)
    return text if a.size == 1 else f"[{text}]"


def _agree(a: np.ndarray, b: np.ndarray) -> bool:
    """Same NaNs, and the other numbers within FRAMES_TOL (relative to max(1, |b|))."""
    nan_a, nan_b = np.isnan(a), np.isnan(b)
    if not np.array_equal(nan_a, nan_b):
        return False
    a, b = a[~nan_b], b[~nan_b]
    return bool((np.abs(a - b) <= FRAMES_TOL * np.maximum(1.0, np.abs(b))).all())


def _vector(f: Frames) -> np.ndarray:
    return np.concatenate([np.ravel(np.asarray(get(f), dtype=np.float64))
                           for _, get in _FRAME_FIELDS])  # fmt: skip


def _compare_frames(c: _Doc, stored: Frames, computed: Frames) -> None:
    if set(stored.undetermined) != set(computed.undetermined):
        c.fail("frames.undetermined", f"must list {', '.join(computed.undetermined)}, as the "
               "parameters leave them")  # fmt: skip
    if _agree(_vector(stored), _vector(computed)):  # one comparison; the fields only to name one
        return
    for name, get in _FRAME_FIELDS:
        a = np.asarray(get(stored), dtype=np.float64)
        b = np.asarray(get(computed), dtype=np.float64)
        if not _agree(a, b):
            c.fail("frames", f"disagrees with the parameters (stage1.params, stage2.params, rig, "
                   f"centres_mm): its {name} is {_numbers(a)}, they give {_numbers(b)}: "
                   f"{EDITED}; delete the frames section to use the parameters")  # fmt: skip


@dataclass(frozen=True)
class _Rows:
    """A result's data as the fit saw it (``Dataset.observations``): one row per landmark
    (version 1), or per view of a touched landmark and touch of it (version 2)."""

    n: int
    image_px: np.ndarray
    depth_mm: np.ndarray
    capture_mm: np.ndarray
    capture_phi_deg: np.ndarray
    tablet_mm: np.ndarray
    hand_xy_mm: np.ndarray
    phi_deg: np.ndarray
    touch_error_mm: np.ndarray
    #: the camera, hand-angle convention and first capture the data record.
    camera_px: tuple[float, float, float, float]
    zero_deg: float
    sign: float
    first_capture_mm: np.ndarray
    first_capture_phi_deg: float
    #: every hand position recorded (captures; touches, z NaN where not recorded).
    positions_mm: np.ndarray
    #: the camera's lens distortion (plumb_bob k1 k2 p1 p2 k3), or None; image_px above are
    #: undistorted with it, as the fit's observations are.
    distortion: tuple[float, ...] | None = None


class _DataRig(NamedTuple):
    """The camera, tablet scale and hand-angle convention a result's data record."""

    camera_px: tuple[float, float, float, float]
    mm_per_tablet_px: float
    zero_deg: float
    sign: float
    distortion: tuple[float, ...] | None

    def phi_deg(self, hand_angle_deg: Any) -> Any:
        return self.zero_deg + self.sign * hand_angle_deg


def _data_rig(c: _Doc, data: dict[str, Any]) -> _DataRig:
    cam = c.get(data, "camera", "data")
    camera = tuple(c.number(c.get(cam, k, "data.camera"), f"data.camera.{k}", limit=MAX_PX)
                   for k in ("fx", "fy", "cx", "cy"))  # fmt: skip
    lens = cam.get("distortion") if isinstance(cam, dict) else None
    lens = None if lens is None else tuple(c.vector(lens, "data.camera.distortion", 5, 100.0))
    tab = c.get(data, "tablet", "data")
    ppi = c.number(c.get(tab, "ppi", "data.tablet"), "data.tablet.ppi", positive=True)
    mm_px = 25.4 / ppi * c.number(c.get(tab, "scale", "data.tablet"), "data.tablet.scale")
    angle = c.get(data, "hand_angle", "data")
    zero = c.number(c.get(angle, "zero", "data.hand_angle"), "data.hand_angle.zero")
    sign = c.number(c.get(angle, "sign", "data.hand_angle"), "data.hand_angle.sign")
    return _DataRig(camera, mm_px, zero, sign, lens)


def _rows(c: _Doc, data: dict[str, Any]) -> _Rows:
    """The rows of a result's data (version 1 or 2), each field checked as it is read."""
    rig = _data_rig(c, data)
    landmarks = c.get(data, "landmarks", "data")
    tablet_px = c.column(landmarks, "tablet_px", "data.landmarks", (2,), MAX_PX)
    if "captures" not in data:
        rows = _rows_v1(c, data, rig, landmarks, tablet_px)
    else:
        rows = _rows_v2(c, data, rig, len(landmarks), tablet_px)
    if rig.distortion is None:
        return rows
    # the fit's observations are undistorted
    image = undistort_px(rows.image_px, rig.camera_px, rig.distortion)
    if not np.isfinite(image).all():
        c.fail("data.camera.distortion", "cannot undistort the data's image points")
    return replace(rows, image_px=image, distortion=rig.distortion)


def _rows_v1(c: _Doc, data: dict[str, Any], rig: _DataRig, landmarks: Any,
             tablet_px: np.ndarray) -> _Rows:  # fmt: skip
    """Version 1: one capture at φ = 0 seeing every landmark, each touched once in order."""
    cap = c.vector(c.get(c.get(data, "capture", "data"), "hand_position", "data.capture"),
                   "data.capture.hand_position", 3, MAX_MM)  # fmt: skip
    n = len(landmarks)
    capture = np.tile(cap, (n, 1))
    arrays = {k: c.column(landmarks, k, "data.landmarks", s, lim) for k, s, lim in (
        ("image_px", (2,), MAX_PX), ("depth", (), MAX_MM), ("hand_xy", (2,), MAX_MM),
        ("hand_angle", (), MAX_DEG), ("touch_error_px", (2,), MAX_PX))}  # fmt: skip
    mm_px = rig.mm_per_tablet_px
    return _Rows(
        n=n, image_px=arrays["image_px"], depth_mm=arrays["depth"], capture_mm=capture,
        capture_phi_deg=np.zeros(n), tablet_mm=tablet_px * mm_px, hand_xy_mm=arrays["hand_xy"],
        phi_deg=rig.phi_deg(arrays["hand_angle"]), touch_error_mm=arrays["touch_error_px"] * mm_px,
        camera_px=rig.camera_px, zero_deg=rig.zero_deg, sign=rig.sign,
        first_capture_mm=np.asarray(cap), first_capture_phi_deg=0.0,
        positions_mm=np.vstack([capture[:1],
                                np.column_stack([arrays["hand_xy"], np.full(n, np.nan)])]),
    )  # fmt: skip


def _rows_v2(c: _Doc, data: dict[str, Any], rig: _DataRig, n_landmarks: int,
             tablet_px: np.ndarray) -> _Rows:  # fmt: skip
    """Version 2: one row per view of a touched landmark and touch of it, capture by capture
    (as ``Dataset.observations`` orders them)."""
    touches = c.get(data, "touches", "data")
    touched = _indices(c, c.column(touches, "landmark", "data.touches", ()), "data.touches",
                       "landmark", n_landmarks)  # fmt: skip
    hand_xy = c.column(touches, "hand_xy", "data.touches", (2,))
    hand_angle = c.column(touches, "hand_angle", "data.touches", (), MAX_DEG)
    touch_error = c.column(touches, "touch_error_px", "data.touches", (2,), MAX_PX)
    hand_z = np.array([t.get("hand_z", np.nan) if isinstance(t.get("hand_z"), int | float)
                       else np.nan for t in touches], dtype=np.float64)  # fmt: skip
    captures = c.get(data, "captures", "data")
    if not isinstance(captures, list) or not captures:
        c.fail("data.captures", "must be a non-empty array")
    views = [_views(c, i, cap, rig, touched.tolist(), n_landmarks)
             for i, cap in enumerate(captures)]  # fmt: skip
    t = np.asarray([k for v in views for k in v.touch], dtype=np.int64)
    n = len(t)
    positions = np.asarray([v.position_mm for v in views])
    mm_px = rig.mm_per_tablet_px
    return _Rows(
        n=n, image_px=np.reshape([x for v in views for x in v.image_px], (n, 2)),
        depth_mm=np.asarray([x for v in views for x in v.depth_mm], float),
        capture_mm=np.reshape([v.position_mm for v in views for _ in v.touch], (n, 3)),
        capture_phi_deg=np.asarray([v.phi_deg for v in views for _ in v.touch], float),
        tablet_mm=tablet_px[touched[t]] * mm_px, hand_xy_mm=hand_xy[t],
        phi_deg=rig.phi_deg(hand_angle[t]), touch_error_mm=touch_error[t] * mm_px,
        camera_px=rig.camera_px, zero_deg=rig.zero_deg, sign=rig.sign,
        first_capture_mm=positions[0],
        first_capture_phi_deg=rig.phi_deg(float(captures[0]["hand_angle"])),
        positions_mm=np.vstack([positions, np.column_stack([hand_xy, hand_z])]),
    )  # fmt: skip


class _Views(NamedTuple):
    """One capture's rows: for each touch of a landmark it sees, the touch's number and the
    landmark's picture point (px) and depth (mm); and the capture's pose (mm, φ deg)."""

    touch: list[int]
    image_px: list[np.ndarray]
    depth_mm: list[float]
    position_mm: np.ndarray
    phi_deg: float


def _views(c: _Doc, i: int, cap: Any, rig: _DataRig, touched: list[int], n: int) -> _Views:
    cw = f"data.captures[{i}]"
    position = c.vector(c.get(cap, "hand_position", cw), f"{cw}.hand_position", 3, MAX_MM)
    phi = rig.phi_deg(c.number(c.get(cap, "hand_angle", cw), f"{cw}.hand_angle", limit=MAX_DEG))
    seen = _indices(c, c.column(c.get(cap, "landmarks", cw), None, f"{cw}.landmarks", ()),
                    f"{cw}.landmarks", "", n)  # fmt: skip
    uv = c.column(c.get(cap, "image_px", cw), None, f"{cw}.image_px", (2,), MAX_PX)
    d = c.column(c.get(cap, "depth", cw), None, f"{cw}.depth", ())
    if not len(seen) == len(uv) == len(d):
        c.fail(f"{cw}.image_px", "must have one entry per landmark seen")
    where = {int(m): k for k, m in enumerate(seen)}
    rows = [(t, where[m]) for t, m in enumerate(touched) if m in where]
    return _Views([t for t, _ in rows], [uv[k] for _, k in rows], [d[k] for _, k in rows],
                  position, phi)  # fmt: skip


def _indices(c: _Doc, x: np.ndarray, where: str, key: str, n: int) -> np.ndarray:
    """Landmark numbers: whole numbers 0 to n - 1."""
    bad = np.flatnonzero((x != np.floor(x)) | (x < 0) | (x >= n))
    if bad.size:
        c.fail(f"{where}[{bad[0]}]{'.' + key if key else ''}", f"must be a landmark's number, 0 "
               f"to {n - 1} (got {x[bad[0]]:g})")  # fmt: skip
    return x.astype(np.int64)


def _compare_rig(c: _Doc, doc: dict[str, Any], rows: _Rows) -> None:
    """The rig a result was fitted with must be its data's (the fit takes it from there)."""
    rig = c.get(doc, "rig", "")
    cam, angle = c.get(rig, "camera_px", "rig"), c.get(rig, "hand_angle", "rig")
    cap_angle = rig.get("capture_hand_angle_deg")
    cap_angle = None if cap_angle is None else c.number(cap_angle, "rig.capture_hand_angle_deg")
    zero = c.number(c.get(angle, "zero_deg", "rig.hand_angle"), "rig.hand_angle.zero_deg")
    sign = c.number(c.get(angle, "sign", "rig.hand_angle"), "rig.hand_angle.sign")
    capture = c.vector(c.get(rig, "capture_hand_position_mm", "rig"),
                       "rig.capture_hand_position_mm", 3)  # fmt: skip
    pairs = [(f"rig.camera_px.{k}", c.number(c.get(cam, k, "rig.camera_px"), f"rig.camera_px.{k}"),
              f"data.camera.{k}", v, "px")
             for k, v in zip(("fx", "fy", "cx", "cy"), rows.camera_px, strict=True)]  # fmt: skip
    pairs += [
        ("rig.hand_angle.zero_deg", zero, "data.hand_angle.zero", rows.zero_deg, "deg"),
        ("rig.hand_angle.sign", sign, "data.hand_angle.sign", rows.sign, ""),
        ("rig.capture_hand_angle_deg", 0.0 if cap_angle is None else zero + sign * cap_angle,
         "the first capture's hand angle", rows.first_capture_phi_deg, "deg (as φ)"),
    ]  # fmt: skip
    pairs += [(f"rig.capture_hand_position_mm[{i}]", capture[i],
               "the first capture's hand_position", rows.first_capture_mm[i], "mm")
              for i in range(3)]  # fmt: skip
    for field, a, where, b, unit in pairs:
        if not abs(float(a) - float(b)) <= FRAMES_TOL * max(1.0, abs(float(b))):
            c.fail(field, f"is {float(a):.10g} {unit} but the data it was fitted on say "
                   f"{float(b):.10g} {unit} ({where}): {EDITED}")  # fmt: skip


def _replay(f: Frames, rows: _Rows) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Each stage's error vectors (image vs tablet, hand) and hand commands at the data's
    rows, as the fit computes them (``_objective.stage1_errors``, ``stage2_errors``), mm."""
    chain = chain_of(f)
    x_bi = _npchain.image_to_base_xy(chain, rows.image_px, rows.depth_mm, rows.capture_mm,
                                     rows.capture_phi_deg)  # fmt: skip
    R = f.R_base_tablet[:2, :2]
    x_bt = rows.tablet_mm @ R.T + f.t_base_tablet_mm[:2]
    target = rows.hand_xy_mm - rows.touch_error_mm @ R.T
    offset = _npchain.pen_offset_xy(chain.t_hand_pen_mm, rows.phi_deg)
    a1 = _npchain.affine_about(x_bi, chain.centres_mm[0], chain.A1)
    command2 = _npchain.affine_about(a1 - offset, chain.centres_mm[1], chain.A2)
    command1 = x_bi - offset
    return {"stage1": (x_bi - x_bt, command1 - target, command1),
            "stage2": (a1 - x_bt, command2 - target, command2)}  # fmt: skip


def _compare_residuals(c: _Doc, doc: dict[str, Any], key: str, e1: np.ndarray, e2: np.ndarray,
                       n: int) -> None:  # fmt: skip
    stage = c.get(doc, key, "")
    if not isinstance(stage, dict):
        c.fail(key, "must be an object")
    residuals = stage.get("residuals_mm") or []
    if not residuals:  # a result made without them (the library's own constructions)
        return
    if not isinstance(residuals, list) or len(residuals) != n:
        c.fail(f"{key}.residuals_mm", f"must be an array of {n} entries, one per row of the "
               "data")  # fmt: skip
    where = f"{key}.residuals_mm"
    for name, got in (("image_vs_tablet_xy_mm", e1), ("hand_xy_mm", e2)):
        recorded = c.column(residuals, name, where, (2,), math.inf)
        off = np.abs(recorded - got).max(axis=1)
        m = int(np.argmax(off))
        if not off[m] <= RESIDUAL_TOL_MM:
            c.fail(f"{where}[{m}].{name}", f"is {_numbers(recorded[m])} mm but the parameters "
                   f"give {_numbers(got[m])} mm on the result's data: {EDITED}")  # fmt: skip
