"""The fitted calibration as named frames and plain numbers: :class:`Frames` (NumPy only).

This is what a robot needs to act on a calibration: the camera and pen on the hand, the tablet
in the base, the intrinsics, the hand-angle convention, the capture pose and the stage-2
correction. It is written into every result file (section ``frames``) and by
``handeye-jax export --format json|yaml`` as the document :meth:`Frames.to_dict` gives.

Frame names follow the rest of the toolkit: ``R_a_b`` rotates vectors expressed in frame ``b``
into frame ``a``, ``t_a_b`` is the origin of ``b`` in ``a``, so ``p_a = R_a_b·p_b + t_a_b``.
Components the data does not determine (:attr:`Frames.undetermined`) are NaN here and ``null``
in files, never a silent 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .._core import MAX_DEG, MAX_MM, MAX_PX, InputError
from ..data import DISTORTION_COEFFICIENTS, DISTORTION_MODEL

FORMAT = "handeye-jax.frames/1"
UNITS = {"length": "mm", "angle": "deg", "image": "px"}

#: What each frame is; written into every frames document.
AXES = {
    "base": "the robot base frame, in which the controller takes hand positions",
    "hand": "the flange, turning with the sixth axis; z along the tool axis (pointing down at "
    "every pose the toolkit uses). At hand angle θh, R_base_hand = Ry(180)·Rz(φ) with "
    "φ = zero_deg + sign·θh (hand_angle), so at φ = 0: x = −x_base, y = y_base, z = −z_base",
    "camera_optical": "OpenCV's (and ROS's) optical frame: x right and y down in the picture, "
    "z forward along the optical axis, as the back-projection of eq. (4) uses it",
    "tablet": "origin at the display's top-left corner (tablet px (0, 0)), x right and y down "
    "on the screen, z into the screen",
    "pen_tip": "the pen tip point, the tool centre point; its axes are the hand's",
}
#: The translations a frames document holds, and their names in ``undetermined``.
TRANSLATIONS = ("t_hand_camera_mm", "t_base_tablet_mm", "t_hand_pen_mm")
AXIS_NAMES = ("x", "y", "z")
#: Why a component is not determined, for the components the toolkit's models leave open.
REASONS = {
    "t_hand_camera_mm.z": "the hand points down at the capture and at every touch, so a shift "
    "along the tool axis never moves x or y, the only coordinates the fit compares (section 3.5)",
    "t_hand_pen_mm.z": "the hand points down at every touch, so the pen's length along the tool "
    "axis never moves x or y, the only coordinates the fit compares (section 3.5)",
    "t_base_tablet_mm.z": "the fit compares x and y only (section 3.5): the tablet's height "
    "never enters it",
}
STAGE2_RULE = (
    "stage 2, eq. (25): hand_xy = A2(A1(x_bi) − x'); A(p) = R(theta_deg)·diag(Sx, Sy)·"
    "(p − centre) + centre + (X_mm, Y_mm), A1 about centres_mm[0], A2 about centres_mm[1]. "
    "Stage 1, eq. (8): hand_xy = x_bi − x'. x_bi: the image point in the base frame; x': the "
    "pen tip in the base frame relative to the hand, R_base_hand(θh)·t_hand_pen_mm"
)
HAND_ANGLE_RULE = "φ = zero_deg + sign·θh; R_base_hand(θh) = Ry(180)·Rz(φ)"
DEPLOY_NOTE = (
    "the stage the calibration chose to deploy by its evidence (leave-one-out): 1, eq. (8), "
    "the frames alone; 2, eq. (25), the frames with stage2's A1 and A2. Hand commands use it "
    "unless told otherwise"
)
CAPTURE_NOTE = (
    "the hand pose when the (first) picture was taken: position in the base frame, and the "
    "hand angle θc; R_base_hand = Ry(180)·Rz(zero_deg + sign·θc) there, and the camera turns "
    "with the hand. The default capture pose of a hand command"
)
HEIGHT_RULE = (
    "hand_z = z_b + pen_minus_camera_mm, z_b the z of T_base_hand(capture)·T_hand_camera·p_c "
    "with t_hand_camera z taken as 0: only z_pen − z_camera is determined (from the hand's "
    "heights at the touches), not each"
)
GIVEN_NOTE = (
    "not determined by the calibration data: given by the user (export --camera-z-mm or "
    "--pen-z-mm), or following from the one given and heights.pen_minus_camera_mm"
)
DISTORTION_RULE = (
    "plumb_bob (Brown–Conrady, OpenCV's distCoeffs order): a measured image point is first "
    "undistorted to the pixel a pinhole camera with camera_px would record "
    "(cv2.undistortPoints with P = K), then back-projected"
)
#: Largest magnitude of a distortion coefficient read from a file.
MAX_DISTORTION = 100.0
#: Largest file :func:`read_json` reads: a result with its data is well under 1 MB.
MAX_FILE_BYTES = 64 * 1024 * 1024
#: How far from orthonormal a rotation read from a file may be.
ROTATION_TOL = 1e-9
AFFINE_KEYS = ("X_mm", "Y_mm", "theta_deg", "Sx", "Sy")


@dataclass(frozen=True)
class Affine:
    """A planar affine map of eq. (24): scale, turn about a centre, shift.

    Attributes:
        X_mm, Y_mm: the shift, mm.
        theta_deg: the turn about the centre, deg.
        Sx, Sy: scale factors along x and y, > 0.
    """

    X_mm: float = 0.0
    Y_mm: float = 0.0
    theta_deg: float = 0.0
    Sx: float = 1.0
    Sy: float = 1.0

    def as_tuple(self) -> tuple[float, float, float, float, float]:
        return (self.X_mm, self.Y_mm, self.theta_deg, self.Sx, self.Sy)


def _array(x: Any, shape: tuple[int, ...]) -> np.ndarray:
    a = np.array(x, dtype=np.float64)
    if a.shape != shape:
        raise ValueError(f"expected shape {shape}, got {a.shape}")
    a.flags.writeable = False
    return a


@dataclass(frozen=True, eq=False)
class Frames:
    """A fitted calibration as plain numbers (float64; mm, deg, px).

    Attributes:
        R_hand_camera, t_hand_camera_mm: the camera's optical frame in the hand frame.
        R_base_tablet, t_base_tablet_mm: the tablet frame in the base frame.
        t_hand_pen_mm: the pen tip in the hand frame (the tool centre point).
        fx_px, fy_px, cx_px, cy_px: the camera intrinsics, px.
        hand_angle_zero_deg, hand_angle_sign: the controller's convention,
            ``φ = zero + sign·θh`` turns the hand about its own z.
        capture_position_mm: the hand position at the calibration's capture, mm, base frame.
        capture_hand_angle_deg: the hand angle θh at the capture, deg.
        A1, A2: the stage-2 correction (eq. 24); identity maps for a stage-1-only calibration.
        centres_mm: the centres A1 and A2 turn about (rows), mm.
        undetermined: components the data did not determine, e.g. ``"t_hand_pen_mm.z"``;
            they are NaN in the arrays above.
        model: the name of the model that was fitted (``"htm"``, ``"dh"``), for the record.
        pen_minus_camera_z_mm: ``z_p − z_c``, the pen tip's minus the camera's offset along
            the hand's z, mm: what commanding a height needs (:data:`HEIGHT_RULE`); ``None``
            when the touches recorded no hand height.
        deploy_stage: the stage the calibration chose to deploy (1: eq. 8; 2: eq. 25 with
            A1, A2), which hand commands use by default; 2 in files that do not say (written
            before the choice was recorded, when stage 2 was the default).
        distortion: the lens's Brown–Conrady (``plumb_bob``) ``(k1, k2, p1, p2, k3)``, or
            ``None``; image points are undistorted with it before the chain.
        given: components the data leaves undetermined whose values were given by the user
            (a measured camera height, :func:`~handeye_jax.robot.with_heights`), or follow from
            one given and ``z_p − z_c``.

    """

    R_hand_camera: np.ndarray
    t_hand_camera_mm: np.ndarray
    R_base_tablet: np.ndarray
    t_base_tablet_mm: np.ndarray
    t_hand_pen_mm: np.ndarray
    fx_px: float
    fy_px: float
    cx_px: float
    cy_px: float
    hand_angle_zero_deg: float
    hand_angle_sign: int
    capture_position_mm: np.ndarray
    capture_hand_angle_deg: float
    A1: Affine = field(default_factory=Affine)
    A2: Affine = field(default_factory=Affine)
    centres_mm: np.ndarray = field(default_factory=lambda: np.zeros((2, 2)))
    undetermined: tuple[str, ...] = ()
    model: str = ""
    pen_minus_camera_z_mm: float | None = None
    deploy_stage: int = 2
    distortion: tuple[float, float, float, float, float] | None = None
    given: tuple[str, ...] = ()


    def __post_init__(self):
        shapes = {"R_hand_camera": (3, 3), "R_base_tablet": (3, 3), "capture_position_mm": (3,),
                  "centres_mm": (2, 2), **dict.fromkeys(TRANSLATIONS, (3,))}  # fmt: skip
        for name, shape in shapes.items():
            object.__setattr__(self, name, _array(getattr(self, name), shape))
        if self.hand_angle_sign not in (1, -1):
            raise ValueError(f"hand_angle_sign must be 1 or -1, got {self.hand_angle_sign}")
        if self.deploy_stage not in (1, 2):
            raise ValueError(f"deploy_stage must be 1 or 2, got {self.deploy_stage}")
        object.__setattr__(self, "deploy_stage", int(self.deploy_stage))
        object.__setattr__(self, "hand_angle_sign", int(self.hand_angle_sign))
        object.__setattr__(self, "undetermined", tuple(self.undetermined))
        object.__setattr__(self, "given", tuple(self.given))
        known = {f"{t}.{a}" for t in TRANSLATIONS for a in AXIS_NAMES}
        for name in self.given:
            if name not in known or name in self.undetermined:
                raise ValueError(f"given: {name!r} must be a known component with a value")
        for name in self.undetermined:
            if name not in known:
                raise ValueError(f"unknown component {name!r}; known: {sorted(known)}")
        for t in TRANSLATIONS:
            for i, a in enumerate(AXIS_NAMES):
                nan = math.isnan(getattr(self, t)[i])
                if nan != (f"{t}.{a}" in self.undetermined):
                    state = "NaN but not listed" if nan else "listed but not NaN"
                    raise ValueError(f"{t}.{a} is {state} in undetermined")
        numbers = [self.R_hand_camera, self.R_base_tablet, self.capture_position_mm,
                   self.centres_mm, self.A1.as_tuple(), self.A2.as_tuple(),
                   (self.fx_px, self.fy_px, self.cx_px, self.cy_px, self.hand_angle_zero_deg,
                    self.capture_hand_angle_deg)]  # fmt: skip
        if not all(np.isfinite(n).all() for n in numbers):
            raise ValueError("every number but the undetermined components must be finite")
        if self.pen_minus_camera_z_mm is not None:
            object.__setattr__(self, "pen_minus_camera_z_mm", float(self.pen_minus_camera_z_mm))
            if not math.isfinite(self.pen_minus_camera_z_mm):
                raise ValueError("pen_minus_camera_z_mm must be finite or None (undetermined)")
        if self.distortion is not None:
            d = tuple(float(c) for c in self.distortion)
            if len(d) != 5 or not all(math.isfinite(c) for c in d):
                raise ValueError("distortion must be five finite numbers (k1, k2, p1, p2, k3)")
            object.__setattr__(self, "distortion", d)

    @property
    def has_height(self) -> bool:
        """Whether the calibration determines the hand's height for a command."""
        return self.pen_minus_camera_z_mm is not None

    def phi_deg(self, hand_angle_deg: Any) -> np.ndarray:
        """The hand's turn about its own z, ``φ = zero + sign·θh``, deg, for hand angles θh."""
        return self.hand_angle_zero_deg + self.hand_angle_sign * np.asarray(hand_angle_deg, float)

    @property
    def camera_px(self) -> tuple[float, float, float, float]:
        """``(fx, fy, cx, cy)`` in px."""
        return (self.fx_px, self.fy_px, self.cx_px, self.cy_px)

    # -- the document ------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """The frames document (JSON- and YAML-ready): numbers, units, axes, conventions.

        An undetermined component is ``None`` (``null``) with ``determined: false`` beside it,
        and is listed with its reason under ``undetermined``.
        """

        def vector(name: str) -> dict[str, Any]:
            v = getattr(self, name)
            return {
                "mm": [None if math.isnan(x) else float(x) for x in v],
                "determined": [not math.isnan(x) for x in v],
            }

        def matrix(R: np.ndarray) -> list[list[float]]:
            return [[float(x) for x in row] for row in R]

        doc = {
            "format": FORMAT,
            "model": self.model,
            "units": dict(UNITS),
            "axes": dict(AXES),
            "convention": "T_a_b maps points from frame b to frame a: p_a = R·p_b + t; t is b's "
            "origin in a. R is row-major.",
            "T_hand_camera": {
                "maps": "camera_optical → hand",
                "R": matrix(self.R_hand_camera),
                "t": vector("t_hand_camera_mm"),
            },
            "T_base_tablet": {
                "maps": "tablet → base",
                "R": matrix(self.R_base_tablet),
                "t": vector("t_base_tablet_mm"),
            },
            "pen_tip": {
                "maps": "the pen tip (tool centre point) in the hand frame",
                "t_hand_pen": vector("t_hand_pen_mm"),
            },
            "camera_px": {"fx": self.fx_px, "fy": self.fy_px, "cx": self.cx_px, "cy": self.cy_px},
            "hand_angle": {
                "zero_deg": self.hand_angle_zero_deg,
                "sign": self.hand_angle_sign,
                "rule": HAND_ANGLE_RULE,
            },
            "capture": {
                "hand_position_mm": [float(x) for x in self.capture_position_mm],
                "hand_angle_deg": self.capture_hand_angle_deg,
                "note": CAPTURE_NOTE,
            },
            "stage2": {
                "A1": dict(zip(AFFINE_KEYS, map(float, self.A1.as_tuple()), strict=True)),
                "A2": dict(zip(AFFINE_KEYS, map(float, self.A2.as_tuple()), strict=True)),
                "centres_mm": matrix(self.centres_mm),
                "rule": STAGE2_RULE,
            },
            "undetermined": [
                {"component": c, "reason": REASONS.get(c, "not determined by the data")}
                for c in self.undetermined
            ],
            "deploy_stage": self.deploy_stage,
            "deploy_note": DEPLOY_NOTE,
        }
        if self.has_height:
            doc["heights"] = {"pen_minus_camera_mm": self.pen_minus_camera_z_mm,
                              "rule": HEIGHT_RULE}  # fmt: skip
        if self.given:
            doc["given"] = [{"component": c, "note": GIVEN_NOTE} for c in self.given]
        if self.distortion is not None:
            doc["distortion"] = {"model": DISTORTION_MODEL,
                                 **dict(zip(DISTORTION_COEFFICIENTS, self.distortion, strict=True)),
                                 "rule": DISTORTION_RULE}  # fmt: skip
        return doc

    @classmethod
    def from_dict(cls, doc: Any, path: str | Path | None = None, where: str = "") -> Frames:
        """Read and check a frames document; :class:`InputError` names ``path`` and the field.

        Args:
            doc: the parsed document (as :meth:`to_dict` gives it).
            path: the file it came from, for messages.
            where: where the document sits in the file, e.g. ``"frames"`` in a result.
        """
        r = _Check(path)
        d = r.table(doc, where, ("format", "model", "units", "T_hand_camera", "T_base_tablet",
                                 "pen_tip", "camera_px", "hand_angle", "capture", "stage2",
                                 "undetermined"),
                     ("axes", "convention", "heights", "deploy_stage", "deploy_note", "stage",
                      "stage_note", "distortion", "given"))  # fmt: skip
        at = lambda key: f"{where}.{key}" if where else key  # noqa: E731
        if d["format"] != FORMAT:
            r.fail(at("format"), f"expected {FORMAT!r} (got {d['format']!r:.60})")
        if not isinstance(d["model"], str):
            r.fail(at("model"), "must be a string")
        units = r.table(d["units"], at("units"), tuple(UNITS))
        for k, unit in UNITS.items():
            if units[k] != unit:
                r.fail(at(f"units.{k}"), f"must be {unit!r} (got {units[k]!r:.40})")
        undetermined, T_hc, T_bt, values = _read_translations(r, d, at)
        cam = r.table(d["camera_px"], at("camera_px"), ("fx", "fy", "cx", "cy"))
        for k in ("fx", "fy"):
            r.number(cam[k], at(f"camera_px.{k}"), MAX_PX, minimum=1.0)
        angle = r.table(d["hand_angle"], at("hand_angle"), ("zero_deg", "sign"), ("rule",))
        sign = r.number(angle["sign"], at("hand_angle.sign"))
        if sign not in (1.0, -1.0):
            r.fail(at("hand_angle.sign"), f"must be 1 or -1 (got {angle['sign']})")
        cap = r.table(d["capture"], at("capture"), ("hand_position_mm", "hand_angle_deg"),
                      ("note",))  # fmt: skip
        s2 = r.table(d["stage2"], at("stage2"), ("A1", "A2", "centres_mm"), ("rule",))
        affines = [_read_affine(r, s2[k], at(f"stage2.{k}")) for k in ("A1", "A2")]
        deploy, height, distortion, given = _read_extras(r, d, at)
        return cls(
            R_hand_camera=r.rotation(T_hc["R"], at("T_hand_camera.R")),
            t_hand_camera_mm=values["t_hand_camera_mm"],
            R_base_tablet=r.rotation(T_bt["R"], at("T_base_tablet.R")),
            t_base_tablet_mm=values["t_base_tablet_mm"],
            t_hand_pen_mm=values["t_hand_pen_mm"],
            fx_px=float(cam["fx"]),
            fy_px=float(cam["fy"]),
            cx_px=r.number(cam["cx"], at("camera_px.cx"), MAX_PX),
            cy_px=r.number(cam["cy"], at("camera_px.cy"), MAX_PX),
            hand_angle_zero_deg=r.number(angle["zero_deg"], at("hand_angle.zero_deg"), MAX_DEG),
            hand_angle_sign=int(sign),
            capture_position_mm=r.vector(cap["hand_position_mm"], at("capture.hand_position_mm"),
                                         3, MAX_MM),  # fmt: skip
            capture_hand_angle_deg=r.number(cap["hand_angle_deg"], at("capture.hand_angle_deg"),
                                            MAX_DEG),  # fmt: skip
            A1=affines[0],
            A2=affines[1],
            centres_mm=[r.vector(c, at(f"stage2.centres_mm[{i}]"), 2, MAX_MM)
                        for i, c in enumerate(r.sized_list(s2["centres_mm"],
                                                           at("stage2.centres_mm"), 2))],
            undetermined=tuple(undetermined),
            model=d["model"],
            pen_minus_camera_z_mm=height,
            deploy_stage=int(deploy),
            distortion=distortion,
            given=given,
        )  # fmt: skip


def _read_extras(r: _Check, d: dict, at) -> tuple[float, float | None, tuple | None, tuple]:
    """A frames document's optional parts, checked: the stage to deploy, the heights' rule
    (``z_pen − z_camera``, mm), the lens distortion and the components the user gave."""
    deploy = 2
    # An export's "stage" (the stage it carries) is its default; else the calibration's.
    for key in ("deploy_stage", "stage"):
        if key in d:
            deploy = r.number(d[key], at(key))
            if deploy not in (1.0, 2.0):
                r.fail(at(key), f"must be 1 or 2 (got {d[key]!r:.40})")
    height = None
    if "heights" in d:
        hd = r.table(d["heights"], at("heights"), ("pen_minus_camera_mm",), ("rule",))
        height = r.number(hd["pen_minus_camera_mm"], at("heights.pen_minus_camera_mm"),
                          MAX_MM)  # fmt: skip
    distortion = None
    if "distortion" in d:
        dd = r.table(d["distortion"], at("distortion"), ("model", *DISTORTION_COEFFICIENTS),
                     ("rule",))  # fmt: skip
        if dd["model"] != DISTORTION_MODEL:
            r.fail(at("distortion.model"), f"must be {DISTORTION_MODEL!r} (got "
                   f"{dd['model']!r:.40})")  # fmt: skip
        distortion = tuple(r.number(dd[k], at(f"distortion.{k}"), MAX_DISTORTION)
                           for k in DISTORTION_COEFFICIENTS)  # fmt: skip
    given = tuple(r.table(g, at(f"given[{i}]"), ("component",), ("note",))["component"]
                  for i, g in enumerate(r.table_list(d.get("given", []), at("given"))))  # fmt: skip
    return deploy, height, distortion, given


def _read_translations(r: _Check, d: dict, at) -> tuple[list[str], dict, dict, dict]:
    """The undetermined components, the two transforms' tables and the three translations
    (mm, NaN where undetermined) of a frames document, checked."""
    listed = r.table_list(d["undetermined"], at("undetermined"))
    undetermined = []
    for i, e in enumerate(listed):
        e = r.table(e, at(f"undetermined[{i}]"), ("component", "reason"))
        undetermined.append(e["component"])
    T_hc = r.table(d["T_hand_camera"], at("T_hand_camera"), ("R", "t"), ("maps",))
    T_bt = r.table(d["T_base_tablet"], at("T_base_tablet"), ("R", "t"), ("maps",))
    pen = r.table(d["pen_tip"], at("pen_tip"), ("t_hand_pen",), ("maps",))
    translations = {
        "t_hand_camera_mm": (T_hc["t"], at("T_hand_camera.t")),
        "t_base_tablet_mm": (T_bt["t"], at("T_base_tablet.t")),
        "t_hand_pen_mm": (pen["t_hand_pen"], at("pen_tip.t_hand_pen")),
    }
    values = {name: r.translation(t, w, name, undetermined)
              for name, (t, w) in translations.items()}  # fmt: skip
    extra = sorted(set(undetermined) - {f"{t}.{a}" for t in TRANSLATIONS for a in AXIS_NAMES})
    if extra:
        r.fail(at("undetermined"), f"unknown component {extra[0]!r:.60}")
    return undetermined, T_hc, T_bt, values


def _read_affine(r: _Check, doc: Any, where: str) -> Affine:
    """One of stage 2's maps (mm, deg, scale factors > 0), checked."""
    a = r.table(doc, where, AFFINE_KEYS)
    for key in AFFINE_KEYS:
        if key.startswith("S"):
            r.number(a[key], f"{where}.{key}", 1e3, positive=True)
        else:
            r.number(a[key], f"{where}.{key}", MAX_DEG if key == "theta_deg" else MAX_MM)
    return Affine(*(float(a[key]) for key in AFFINE_KEYS))


def _describe(x: Any) -> str:
    if x is None:
        return "null"
    if isinstance(x, bool):
        return f"boolean {str(x).lower()}"
    if isinstance(x, int | float):
        return f"number {x}"
    if isinstance(x, str):
        return f"string {x!r:.40}"
    if isinstance(x, list):
        return f"an array of {len(x)}"
    if isinstance(x, dict):
        return "an object"
    return f"a {type(x).__name__}"


class _Check:
    """Typed fields out of a parsed document, with one-line errors naming file and field."""

    def __init__(self, path: str | Path | None):
        self.path = path

    def fail(self, where: str, message: str):
        raise InputError(self.path, where, message)

    def table(self, x: Any, where: str, keys: tuple[str, ...], optional: tuple[str, ...] = ()):
        if not isinstance(x, dict):
            self.fail(where, f"must be an object (got {_describe(x)})")
        for k in x:
            if k not in keys and k not in optional:
                self.fail(f"{where}.{k}" if where else str(k), "unknown key")
        for k in keys:
            if k not in x:
                self.fail(f"{where}.{k}" if where else k, "missing")
        return x

    def table_list(self, x: Any, where: str) -> list:
        if not isinstance(x, list):
            self.fail(where, f"must be an array (got {_describe(x)})")
        return x

    def sized_list(self, x: Any, where: str, n: int) -> list:
        if not isinstance(x, list) or len(x) != n:
            self.fail(where, f"must be an array of {n} (got {_describe(x)})")
        return x

    def number(
        self,
        x: Any,
        where: str,
        limit: float | None = None,
        positive: bool = False,
        minimum: float | None = None,
    ) -> float:
        if isinstance(x, bool) or not isinstance(x, int | float):
            self.fail(where, f"must be a number (got {_describe(x)})")
        try:
            v = float(x)
        except OverflowError:
            self.fail(where, "must be finite (got an integer beyond float64)")
        if not math.isfinite(v):
            self.fail(where, f"must be finite (got {x})")
        if positive and v <= 0:
            self.fail(where, f"must be > 0 (got {x})")
        if minimum is not None and v < minimum:
            self.fail(where, f"must be at least {minimum:g} (got {x})")
        if limit is not None and abs(v) > limit:
            self.fail(where, f"must be at most {limit:g} in magnitude (got {x})")
        return v

    def vector(self, x: Any, where: str, n: int, limit: float) -> list[float]:
        x = self.sized_list(x, where, n)
        return [self.number(v, f"{where}[{i}]", limit) for i, v in enumerate(x)]

    def rotation(self, x: Any, where: str) -> np.ndarray:
        rows = self.sized_list(x, where, 3)
        R = np.array([self.vector(row, f"{where}[{i}]", 3, 2.0) for i, row in enumerate(rows)])
        err = float(np.abs(R.T @ R - np.eye(3)).max())
        if err > ROTATION_TOL or np.linalg.det(R) < 0:
            what = f"off by {err:.3g}" if err > ROTATION_TOL else "a reflection (det < 0)"
            self.fail(where, f"must be a rotation matrix (orthonormal, det +1): {what}")
        return R

    def translation(self, x: Any, where: str, name: str, undetermined: list[str]) -> np.ndarray:
        t = self.table(x, where, ("mm", "determined"))
        mm = self.sized_list(t["mm"], f"{where}.mm", 3)
        det = self.sized_list(t["determined"], f"{where}.determined", 3)
        out = np.empty(3)
        for i, axis in enumerate(AXIS_NAMES):
            w = f"{where}.mm[{i}]"
            if not isinstance(det[i], bool):
                self.fail(f"{where}.determined[{i}]", f"must be true or false (got "
                          f"{_describe(det[i])})")  # fmt: skip
            listed = f"{name}.{axis}" in undetermined
            if det[i] == listed:
                not_ = "" if listed else "not "
                self.fail(f"{where}.determined[{i}]", f"is {str(det[i]).lower()} but "
                          f"{name}.{axis} is {not_}listed in undetermined")  # fmt: skip
            if det[i]:
                out[i] = self.number(mm[i], w, MAX_MM)
            elif mm[i] is not None:
                self.fail(w, f"must be null: the component is not determined (got "
                          f"{_describe(mm[i])})")  # fmt: skip
            else:
                out[i] = np.nan
        return out
