"""The synthetic twin's rig truth: everything about the rig, known exactly.

A :class:`TwinTruth` holds an HTM-model-consistent rig: intrinsics and image size, the camera
mount (six DoF: the HTM model's five plus its height ``zc``), the pen offset, the tablet pose
(six DoF: the model's five plus its height), the capture pose, the tablet's ppi and scale, the
display and landmark layout, and the controller's hand-angle convention. It is drawn from the
documented :data:`RANGES` by a seed (:func:`draw_truth`) or read from ``truth.json``
(:func:`load_truth`; :meth:`TwinTruth.to_json` writes it back unchanged).

Units: mm, deg, px (image px for the camera, tablet px for the display).
"""

from __future__ import annotations

import functools
import json
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import jax.numpy as jnp
import numpy as np
from jaxtyping import Float

from .. import geometry as geo
from .._core import (
    CHANGES,
    MAX_DEG,
    MAX_DOT_PX,
    MAX_IMAGE_PIXELS,
    MAX_LANDMARKS,
    MAX_MM,
    MAX_PX,
    Reader,
    describe,
    load_json,
)
from .._jax import in_float64
from ..data import Camera, check_tablet_px, distort_px, snake_grid_px, undistort_px
from ..models import HTMModel, Rig
from ._synthetic import Scene, camera_view

FORMAT = "handeye-jax.twin-truth/1"

# Seeded draws are uniform in these ranges (mm, deg, px). The model's parameters stay well
# inside HTMModel's default search ranges (Table 5), so a calibration can find them.
RANGES: dict[str, tuple[float, float]] = {
    "fx": (600.0, 640.0),  # image px; fy = fx (square pixels)
    "cx_offset": (-8.0, 8.0),  # principal point minus the image centre, image px
    "cy_offset": (-8.0, 8.0),
    "xc": (-8.0, 8.0), "yc": (28.0, 42.0), "zc_mm": (-10.0, 10.0),
    "alpha_c": (-3.0, 3.0), "beta_c": (-3.0, 3.0), "gamma_c": (-5.0, 5.0),
    "xt": (150.0, 195.0), "yt": (10.0, 60.0), "tablet_height_mm": (110.0, 130.0),
    "alpha_t": (-4.0, 4.0), "beta_t": (-4.0, 4.0), "gamma_t": (-8.0, 8.0),
    "xp": (-5.0, 5.0), "yp": (-30.0, -15.0),
    "ppi": (250.0, 290.0),
    "depth_mm": (160.0, 180.0),  # camera height above the tablet at capture
    "capture_jitter_mm": (-10.0, 10.0),  # capture x, y off the landmark centre
}  # fmt: skip
HAND_ANGLE_CONVENTIONS = ((90.0, -1), (90.0, 1), (0.0, 1), (0.0, -1))  # (zero deg, sign)
# Landmarks (and held-out targets) must lie this far inside the picture, image px.
MARGIN_PX = 24.0
#: Largest lens blur σ in a truth file, image px: the PSF patch of each dot is 10 σ wide.
MAX_LENS_BLUR_PX = 20.0
#: Largest magnitude of a distortion coefficient in a truth file.
MAX_DISTORTION = 1.0
#: A RealSense-like colour lens: coefficients of the size a D400-series colour camera reports
#: (plumb_bob k1 k2 p1 p2 k3); they move the corner of a 640 × 480 picture by about 4.5 px.
REALSENSE_LIKE = (-0.0555, 0.0665, -0.0004, 0.0007, -0.0213)


@dataclass(frozen=True, eq=False)
class TwinTruth:
    """The rig of a synthetic twin, exactly.

    Attributes:
        image_size_px: picture ``(width, height)``, image px.
        camera_px: intrinsics ``fx, fy, cx, cy``, image px.
        lens_blur_px: the lens's point-spread function, a Gaussian of this σ, image px. Always
            present (a real lens is never perfectly sharp); noise presets add defocus on top.
        model: the HTM model's parameters (``xc … yp``; mm, deg).
        camera_z_mm: the camera's offset along the hand's z axis, ``zc``, mm.
        tablet_height_mm: height of the display surface in the base frame, mm.
        capture_position_mm: hand position when the picture is taken, mm, base frame.
        ppi, scale: the display's pixel density and scale; one tablet px is
            ``25.4 / ppi * scale`` mm (eq. 9).
        display_px: the display's ``(width, height)``, tablet px; its corner is the tablet
            frame's origin.
        dot_px: side of each drawn landmark dot, tablet px (the paper draws one-pixel dots).
        hand_angle_zero_deg, hand_angle_sign: ``φ = zero + sign·θh``.
        landmarks_tablet_px: where the landmarks are drawn, tablet px, in touch order.
        landmarks_hand_angle_deg: the hand angle θh of each touch, deg.
        seed: the seed it was drawn with (``None`` when written by hand).
        capture_hand_angle_deg: the hand angle θc at the capture, deg; ``None``: where φ = 0
            (eq. 1). The camera turns with the hand: ``R_base_hand = Ry(-180)·Rz(φc)``.
        pen_z_mm: the pen tip's offset along the hand's z axis, ``zp``, mm (the hand's height
            at a touch is the touched point's plus this).
        distortion: the lens's Brown–Conrady (``plumb_bob``) ``(k1, k2, p1, p2, k3)``, or
            ``None`` (a pinhole). Pictures, depth images and held-out targets are distorted
            with it; the dataset's ``[camera]`` carries it.
    """

    image_size_px: tuple[int, int]
    camera_px: dict[str, float]
    lens_blur_px: float
    model: dict[str, float]
    camera_z_mm: float
    tablet_height_mm: float
    capture_position_mm: tuple[float, float, float]
    ppi: float
    scale: float
    display_px: tuple[float, float]
    dot_px: float
    hand_angle_zero_deg: float
    hand_angle_sign: int
    landmarks_tablet_px: np.ndarray = field(repr=False)
    landmarks_hand_angle_deg: np.ndarray = field(repr=False)
    seed: int | None = None
    capture_hand_angle_deg: float | None = None
    pen_z_mm: float = 0.0
    distortion: tuple[float, float, float, float, float] | None = None

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, TwinTruth):
            return NotImplemented
        return self.to_dict() == other.to_dict()

    __hash__ = None  # arrays inside: not hashable

    @property
    def mm_per_tablet_px(self) -> float:
        return geo.mm_per_tablet_px(self.ppi, self.scale)

    def scene(self, pen_z_mm: float | None = None) -> Scene:
        """What the data depend on besides :meth:`htm` and :meth:`rig` (``pen_z_mm``: record
        the hand's heights, a pen tip that far along the hand's z axis, mm)."""
        return Scene(self.ppi, self.scale, self.tablet_height_mm, self.camera_z_mm, pen_z_mm)

    @in_float64
    def rig(self) -> Rig:
        """What the calibration knows: intrinsics, capture position, angle convention."""
        c = self.camera_px
        return Rig(
            c["fx"], c["fy"], c["cx"], c["cy"], np.asarray(self.capture_position_mm),
            self.hand_angle_zero_deg, self.hand_angle_sign, self.capture_hand_angle_deg,
        )  # fmt: skip

    def at_capture(self, position_mm: Any, hand_angle_deg: float) -> TwinTruth:
        """The same rig with the picture taken from another hand pose (mm, deg)."""
        return replace(self, capture_position_mm=tuple(float(x) for x in position_mm),
                       capture_hand_angle_deg=float(hand_angle_deg))  # fmt: skip

    @property
    def capture_angle_deg(self) -> float:
        """The hand angle θc at the capture, deg (where φ = 0 unless given)."""
        if self.capture_hand_angle_deg is not None:
            return float(self.capture_hand_angle_deg)
        return float(-self.hand_angle_zero_deg * self.hand_angle_sign) + 0.0

    @in_float64
    def true_command(
        self, p_base_mm: Float[np.ndarray, "k 3"], hand_angle_deg: Float[np.ndarray, " k"]
    ) -> Float[np.ndarray, "k 3"]:
        """The hand position ``(x, y, z)``, mm, that puts the pen tip on base-frame points at
        hand angles θh, deg."""
        p = jnp.asarray(p_base_mm, dtype=float)
        off = self.htm().pen_offset(self.rig().phi_deg(jnp.asarray(hand_angle_deg, dtype=float)))
        return np.asarray(jnp.concatenate([p[:, :2] - off[:, :2], p[:, 2:] + self.pen_z_mm], 1))

    @in_float64
    def surface_points(
        self, tablet_px: Float[np.ndarray, "k 2"], above_mm: float = 0.0
    ) -> Float[np.ndarray, "k 3"]:
        """Display points (tablet px) in the base frame, mm, lifted ``above_mm`` straight up
        (the top of an object standing there)."""
        p = self.htm().tablet_to_base(jnp.asarray(tablet_px, float) * self.mm_per_tablet_px)
        return np.asarray(p.at[:, 2].add(self.tablet_height_mm + above_mm))

    @in_float64
    def htm(self) -> HTMModel:
        """The true stage-1 model."""
        return HTMModel.from_dict(self.model)

    @in_float64
    def camera_points(self, tablet_px: Float[np.ndarray, "n 2"]) -> Float[np.ndarray, "n 3"]:
        """Display points, tablet px ``(n, 2)``, in the camera frame at capture, mm ``(n, 3)``."""
        return self._view(tablet_px)[0]

    @functools.cached_property
    def _chain(self) -> tuple[HTMModel, Rig]:
        # Built once per truth: a rendered picture projects points a few hundred times, and
        # each build converts twenty numbers to arrays, one operation each.
        return self.htm(), self.rig()

    def _view(self, tablet_px):
        return camera_view(*self._chain,
                           np.asarray(tablet_px, float) * self.mm_per_tablet_px,
                           self.tablet_height_mm, self.camera_z_mm)  # fmt: skip

    @in_float64
    def project(
        self, tablet_px: Float[np.ndarray, "n 2"]
    ) -> tuple[Float[np.ndarray, "n 2"], Float[np.ndarray, " n"]]:
        """Where display points appear in the picture: ``(image_px (n, 2), depth_mm (n,))``,
        through the lens's distortion."""
        _, uv, z = self._view(tablet_px)
        return distort_px(uv, self.camera_tuple_px, self.distortion), z

    @property
    def camera_tuple_px(self) -> tuple[float, float, float, float]:
        """``(fx, fy, cx, cy)``, image px."""
        c = self.camera_px
        return (c["fx"], c["fy"], c["cx"], c["cy"])

    def undistort(self, image_px: Float[np.ndarray, "n 2"]) -> Float[np.ndarray, "n 2"]:
        """Picture points as the pinhole of the same intrinsics would see them, px."""
        return undistort_px(np.asarray(image_px, float).reshape(-1, 2), self.camera_tuple_px,
                            self.distortion)  # fmt: skip

    def camera(self) -> Camera:
        """The dataset's ``[camera]``: intrinsics and distortion."""
        return Camera(*self.camera_tuple_px, self.distortion)

    def sees(self, tablet_px: Float[np.ndarray, "n 2"]) -> bool:
        """Whether every display point (tablet px) is in the picture, :data:`MARGIN_PX` in."""
        return _in_view(self, np.asarray(tablet_px, dtype=float))

    def landmark_area_px(self) -> tuple[np.ndarray, np.ndarray]:
        """The landmarks' bounding box on the display, ``(lower, upper)`` corners, tablet px."""
        return self.landmarks_tablet_px.min(axis=0), self.landmarks_tablet_px.max(axis=0)

    # -- file ------------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["landmarks_tablet_px"] = self.landmarks_tablet_px.tolist()
        d["landmarks_hand_angle_deg"] = self.landmarks_hand_angle_deg.tolist()
        for k in ("image_size_px", "capture_position_mm", "display_px"):
            d[k] = list(d[k])
        # Written only when set: a truth of one capture at φ = 0 reads as before.
        if d["capture_hand_angle_deg"] is None:
            del d["capture_hand_angle_deg"]
        if d["pen_z_mm"] == 0.0:
            del d["pen_z_mm"]
        if d["distortion"] is None:
            del d["distortion"]
        else:
            d["distortion"] = list(d["distortion"])
        return {"format": FORMAT, **d}

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2, allow_nan=False) + "\n"


def _in_view(truth: TwinTruth, tablet_px: np.ndarray) -> bool:
    uv, z = truth.project(tablet_px)
    w, h = truth.image_size_px
    inside = (uv >= MARGIN_PX).all() and (uv[:, 0] <= w - 1 - MARGIN_PX).all()
    return bool(inside and (uv[:, 1] <= h - 1 - MARGIN_PX).all() and (z > 0).all())


def draw_truth(
    seed: int,
    *,
    image_size_px: tuple[int, int] = (640, 480),
    landmarks_tablet_px: np.ndarray | None = None,
    display_px: tuple[float, float] = (1280.0, 800.0),
    lens_blur_px: float = 0.5,
    dot_px: float = 1.0,
    scale: float = 2.0,
    fixed: dict[str, float] | None = None,
) -> TwinTruth:
    """A rig truth drawn uniformly from :data:`RANGES` by ``seed`` (bit-for-bit repeatable).

    The capture pose is put above the landmarks' centre (off by ``capture_jitter_mm``) at a
    camera height of ``depth_mm`` above the tablet; draws that leave a landmark within
    :data:`MARGIN_PX` of the picture's edge are redrawn from the same stream.

    Args:
        seed: the seed of the draw.
        image_size_px: picture ``(width, height)``, image px.
        landmarks_tablet_px: the landmark layout, tablet px; the paper's 3×3 snake by default.
            The hand angles are the paper's, ``22.5·m`` deg.
        display_px: the display size, tablet px.
        lens_blur_px: σ of the lens's Gaussian point-spread function, image px.
        dot_px: side of each landmark dot, tablet px.
        scale: the display scale (eq. 9).
        fixed: values for some of :data:`RANGES`' names instead of draws (still drawn, so the
            other values do not change), e.g. ``{"gamma_t": 30.0}``.
    """
    fixed = dict(fixed or {})
    unknown = sorted(set(fixed) - set(RANGES))
    if unknown:
        raise ValueError(f"unknown names in fixed: {unknown}; known: {sorted(RANGES)}")
    rng = np.random.default_rng(seed)
    layout = snake_grid_px() if landmarks_tablet_px is None else np.asarray(landmarks_tablet_px)
    angles = 22.5 * np.arange(len(layout))
    w, h = image_size_px
    for _ in range(1000):
        u = {k: float(rng.uniform(lo, hi)) for k, (lo, hi) in RANGES.items()}
        u.update(fixed)
        zero, sign = HAND_ANGLE_CONVENTIONS[int(rng.integers(len(HAND_ANGLE_CONVENTIONS)))]
        model = {k: u[k] for k in HTMModel.param_names}
        camera = {"fx": u["fx"], "fy": u["fx"], "cx": (w - 1) / 2 + u["cx_offset"],
                  "cy": (h - 1) / 2 + u["cy_offset"]}  # fmt: skip
        truth = TwinTruth(
            image_size_px=(int(w), int(h)), camera_px=camera, lens_blur_px=float(lens_blur_px),
            model=model, camera_z_mm=u["zc_mm"], tablet_height_mm=u["tablet_height_mm"],
            capture_position_mm=(0.0, 0.0, 0.0), ppi=u["ppi"], scale=float(scale),
            display_px=(float(display_px[0]), float(display_px[1])), dot_px=float(dot_px),
            hand_angle_zero_deg=zero, hand_angle_sign=sign,
            landmarks_tablet_px=np.array(layout, dtype=float), landmarks_hand_angle_deg=angles,
            seed=int(seed),
        )  # fmt: skip
        truth = _capture_above(truth, u["capture_jitter_mm"], float(rng.uniform(-10.0, 10.0)),
                               u["depth_mm"])  # fmt: skip
        if _in_view(truth, truth.landmarks_tablet_px):
            return truth
    raise ValueError("could not draw a rig that sees every landmark; check the layout and size")


def _capture_above(truth: TwinTruth, jitter_x_mm: float, jitter_y_mm: float, depth_mm: float):
    """``truth`` with the capture pose above the landmarks' centre (off by the jitter, mm), the
    camera ``depth_mm`` above the tablet."""
    # Put the camera's optical centre above the landmarks' centre, at the drawn height.
    truth = replace(truth, capture_position_mm=(0.0, 0.0, 0.0))
    centre_px = np.mean(truth.landmark_area_px(), axis=0)[None]
    # In the camera frame with the hand at the origin; rotated into the base frame, it is
    # the hand position that puts the camera right above the centre.
    p_camera = truth.camera_points(centre_px)[0]
    centre_base = np.asarray(_R_base_camera(truth)) @ p_camera
    xy = centre_base[:2] + [jitter_x_mm, jitter_y_mm]
    z = truth.tablet_height_mm + depth_mm + truth.camera_z_mm
    return replace(truth, capture_position_mm=(float(xy[0]), float(xy[1]), float(z)))


#: A changed parameter stays this fraction of its search range (HTMModel's, Table 5) inside
#: the range: a calibration of the changed rig can still find it, off the range's bounds.
CHANGE_MARGIN = 0.1


def change_truth(truth: TwinTruth, part: str, seed: int) -> TwinTruth:
    """The same rig after one part changed: a new pen offset, a moved tablet or a remounted
    camera, drawn by ``seed`` within :data:`CHANGES` (bit-for-bit repeatable).

    Only the model's parameters of ``part``'s group (``HTMModel.groups``) change, each kept
    :data:`CHANGE_MARGIN` of its search range inside it. After a tablet or camera change the
    capture pose is put above the landmarks again, as :func:`draw_truth` puts it (a new
    ``capture_jitter_mm`` and ``depth_mm`` from :data:`RANGES`); after a pen change it stays
    (the camera's view did not change). Draws that leave a landmark within :data:`MARGIN_PX`
    of the picture's edge are redrawn from the same stream. Everything else (intrinsics,
    heights, display, layout, hand-angle convention, ``seed``) is ``truth``'s.

    Args:
        truth: the rig before the change.
        part: ``"pen"``, ``"tablet"`` or ``"camera"``.
        seed: the seed of the change's draw.

    Raises:
        ValueError: an unknown ``part``, or no draw keeps every landmark in the picture.
    """
    if part not in CHANGES:
        raise ValueError(f"unknown part {part!r}; known: {', '.join(CHANGES)}")
    ranges = CHANGES[part]
    rng = np.random.default_rng(seed)
    old = truth.model
    names = HTMModel.groups[part]
    lo, hi = HTMModel.search_bounds()
    box = {
        n: (lo[i] + CHANGE_MARGIN * (hi[i] - lo[i]), hi[i] - CHANGE_MARGIN * (hi[i] - lo[i]))
        for i, n in enumerate(HTMModel.param_names)
        if n in names
    }

    def moved(x: str, y: str, length: tuple[float, float]) -> dict[str, float]:
        d, a = rng.uniform(*length), rng.uniform(0.0, 2.0 * np.pi)
        return {x: old[x] + d * float(np.cos(a)), y: old[y] + d * float(np.sin(a))}

    def turned(name: str, angle: tuple[float, float]) -> float:
        return old[name] + float(rng.choice((-1.0, 1.0)) * rng.uniform(*angle))

    for _ in range(1000):
        if part == "pen":
            new = moved("xp", "yp", ranges["tip_move_mm"])
        elif part == "tablet":
            new = moved("xt", "yt", ranges["move_mm"])
            new["gamma_t"] = turned("gamma_t", ranges["turn_deg"])
            new |= {n: float(rng.uniform(*RANGES[n])) for n in ("alpha_t", "beta_t")}
        else:
            new = moved("xc", "yc", ranges["move_mm"])
            new |= {n: turned(n, ranges["turn_deg"]) for n in ("alpha_c", "beta_c", "gamma_c")}
        changed = replace(truth, model={**old, **new})
        if part != "pen":
            jitter = rng.uniform(*RANGES["capture_jitter_mm"], 2)
            depth = float(rng.uniform(*RANGES["depth_mm"]))
            changed = _capture_above(changed, float(jitter[0]), float(jitter[1]), depth)
        inside = all(box[n][0] <= v <= box[n][1] for n, v in new.items())
        if inside and _in_view(changed, changed.landmarks_tablet_px):
            return changed
    raise ValueError(f"could not change the {part} so that the camera sees every landmark")


@in_float64
def _R_base_camera(truth: TwinTruth):
    R_bh, _ = truth.rig().T_base_hand_capture()
    R_hc, _ = truth.htm().camera_mount()
    return R_bh @ R_hc


def load_truth(path: str | Path) -> TwinTruth:
    """Read and validate a ``truth.json``; raises :class:`InputError` naming the field."""
    path = Path(path)
    r = Reader(path)
    doc = load_json(path)
    if not isinstance(doc, dict):
        r.fail("", "must be a JSON object")
    if doc.get("format") != FORMAT:
        r.fail("format", f"expected {FORMAT!r} (got {describe(doc.get('format'))})")
    keys = ("format", *TwinTruth.__dataclass_fields__)
    r.table(doc, "", keys, optional=("seed", "capture_hand_angle_deg", "pen_z_mm", "distortion"))
    size, camera = _picture(r, doc)
    m = r.table(doc["model"], "model", HTMModel.param_names)
    model = {k: r.number(m[k], f"model.{k}", limit=MAX_MM) for k in HTMModel.param_names}
    tab, angles = _landmarks(r, doc)
    sign = r.number(doc["hand_angle_sign"], "hand_angle_sign")
    if sign not in (1.0, -1.0):
        r.fail("hand_angle_sign", f"must be 1 or -1 (got {sign})")
    ppi = r.number(doc["ppi"], "ppi", True, 1e5, minimum=1)
    scale = r.number(doc["scale"], "scale", True, 100, minimum=0.01)
    check_tablet_px(ppi, scale, path, "scale")
    seed = doc.get("seed")
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int)):
        r.fail("seed", f"must be an integer or null (got {describe(seed)})")
    truth = TwinTruth(
        image_size_px=size, camera_px=camera,
        lens_blur_px=r.number(doc["lens_blur_px"], "lens_blur_px", positive=True,
                              limit=MAX_LENS_BLUR_PX),
        model=model,
        camera_z_mm=r.number(doc["camera_z_mm"], "camera_z_mm", limit=MAX_MM),
        tablet_height_mm=r.number(doc["tablet_height_mm"], "tablet_height_mm", limit=MAX_MM),
        capture_position_mm=tuple(
            r.vector(doc["capture_position_mm"], "capture_position_mm", 3, MAX_MM)
        ),
        ppi=ppi, scale=scale,
        display_px=tuple(r.vector(doc["display_px"], "display_px", 2, MAX_PX)),
        dot_px=r.number(doc["dot_px"], "dot_px", positive=True, limit=MAX_DOT_PX),
        hand_angle_zero_deg=r.number(doc["hand_angle_zero_deg"], "hand_angle_zero_deg",
                                     limit=MAX_DEG),
        hand_angle_sign=int(sign), landmarks_tablet_px=np.array(tab),
        landmarks_hand_angle_deg=np.array(angles), seed=seed,
        capture_hand_angle_deg=None if doc.get("capture_hand_angle_deg") is None else
        r.number(doc["capture_hand_angle_deg"], "capture_hand_angle_deg", limit=MAX_DEG),
        pen_z_mm=r.number(doc.get("pen_z_mm", 0.0), "pen_z_mm", limit=MAX_MM),
        distortion=None if doc.get("distortion") is None else
        tuple(r.vector(doc["distortion"], "distortion", 5, MAX_DISTORTION)),
    )  # fmt: skip
    if not _in_view(truth, truth.landmarks_tablet_px):
        r.fail("", f"some landmark is not in the picture (or within {MARGIN_PX:g} px of its edge)")
    return truth


def _picture(r: Reader, doc: dict) -> tuple[tuple[int, int], dict[str, float]]:
    """A truth's picture size (px) and intrinsics (px), checked."""
    size = r.vector(doc["image_size_px"], "image_size_px", 2, 1e5)
    if any(s < 8 or s != int(s) for s in size):
        r.fail("image_size_px", f"must be two whole numbers >= 8 (got {size})")
    if size[0] * size[1] > MAX_IMAGE_PIXELS:
        r.fail("image_size_px", f"{size[0]:g} x {size[1]:g} px is more than "
               f"{MAX_IMAGE_PIXELS:,} px (4096 x 4096), the most detect reads")  # fmt: skip
    cam = r.table(doc["camera_px"], "camera_px", ("fx", "fy", "cx", "cy"))
    focal = {"fx": 1.0, "fy": 1.0}  # px; cx and cy may be anything on the sensor's scale
    camera = {
        k: r.number(cam[k], f"camera_px.{k}", k in focal, MAX_PX, focal.get(k), "px") for k in cam
    }
    return (int(size[0]), int(size[1])), camera


def _landmarks(r: Reader, doc: dict) -> tuple[list, list[float]]:
    """A truth's landmark layout (tablet px) and touch hand angles (deg), checked."""
    layout = doc["landmarks_tablet_px"]
    if not isinstance(layout, list) or not 4 <= len(layout) <= MAX_LANDMARKS:
        r.fail("landmarks_tablet_px", f"must be 4 to {MAX_LANDMARKS:,} [x, y] (got "
               f"{describe(layout)})")  # fmt: skip
    tab = [r.vector(p, f"landmarks_tablet_px[{i}]", 2, MAX_PX) for i, p in enumerate(layout)]
    angles = doc["landmarks_hand_angle_deg"]
    if not isinstance(angles, list) or len(angles) != len(tab):
        r.fail("landmarks_hand_angle_deg", f"must be a list of {len(tab)} numbers")
    angles = [
        r.number(a, f"landmarks_hand_angle_deg[{i}]", limit=MAX_DEG) for i, a in enumerate(angles)
    ]
    return tab, angles
