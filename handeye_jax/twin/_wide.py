"""Random wide rigs: twins drawn far from the paper's layout, for calibrations that must not
depend on search ranges.

:func:`draw_wide_truth` puts the tablet anywhere in a 600 × 600 mm area of the workspace, at
any yaw, tilted up to 5°; the camera up to ±100 mm off the flange axis, tilted up to ±20°
about each of two axes, at any roll about its optical axis; the pen tip up to ±80 mm off the
axis in x and y; the hand-angle convention one of four (:data:`WIDE_RANGES`). The DH model
holds the camera's offset on the hand's x axis and the tablet's origin on the base's x axis
(eqs. 12–16): a ``"dh"`` rig is drawn so (``yc = yt = 0``), its tablet's landmarks still
anywhere along that axis.

The picture is physically valid: the capture pose points the camera's optical axis at the
landmarks' centre from a drawn distance, with the hand turned so that the tablet's x axis
appears within :data:`UPRIGHT_DEG` of the picture's u axis (as an operator frames it, and as
the detector's ordering needs), and every landmark lies inside the picture's margin at a
positive depth (:meth:`TwinTruth.sees`). Further captures are aimed the same way
(:func:`aimed_position`).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .._core import WIDE_MODELS
from .._jax import in_float64
from ..data import snake_grid_px
from ._truth import HAND_ANGLE_CONVENTIONS, RANGES, TwinTruth

#: Uniform draws of a wide rig (mm, deg): where the landmarks' centre lies in the base frame,
#: the tablet's yaw and tilt, the camera's offset from the flange axis, its tilt about the
#: hand's x and y axes and its roll, the pen tip's offset, and the camera's distance from
#: the landmarks' centre along its optical axis at the capture.
WIDE_RANGES: dict[str, tuple[float, float]] = {
    "centre_x_mm": (100.0, 700.0), "centre_y_mm": (-300.0, 300.0),
    "tablet_yaw_deg": (-180.0, 180.0), "tablet_tilt_deg": (0.0, 5.0),
    "camera_offset_mm": (-100.0, 100.0), "camera_tilt_deg": (-20.0, 20.0),
    "camera_roll_deg": (-180.0, 180.0), "pen_offset_mm": (-80.0, 80.0),
    "distance_mm": (170.0, 210.0),
}  # fmt: skip
#: The tablet's x axis appears within this many degrees of the picture's u axis.
UPRIGHT_DEG = 15.0
#: Side of a wide rig's landmark dots, tablet px: the camera looks from up to ~290 mm.
WIDE_DOT_PX = 2.0


def _R_base_hand(phi_deg: float) -> np.ndarray:
    r = np.deg2rad(phi_deg)
    s, c = np.sin(r), np.cos(r)
    return np.array([[-c, s, 0.0], [s, c, 0.0], [0.0, 0.0, -1.0]])


@in_float64
def _mount(truth: TwinTruth) -> tuple[np.ndarray, np.ndarray]:
    """The camera in the hand frame, ``(R, t)`` with its height ``zc``."""
    R, t = (np.asarray(a, dtype=float) for a in truth.htm().camera_mount())
    return R, t + [0.0, 0.0, truth.camera_z_mm]


def _centre_mm(truth: TwinTruth) -> np.ndarray:
    return truth.surface_points(np.mean(truth.landmark_area_px(), axis=0)[None])[0]


def aimed_position(truth: TwinTruth, hand_angle_deg: float, distance_mm: float,
                   offset_mm: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:  # fmt: skip
    """The hand position, mm, at hand angle θ (deg) that puts the camera ``distance_mm``
    from the landmarks' centre along its optical axis, the hand then moved ``offset_mm`` in
    base x and y."""
    R_bh = _R_base_hand(truth.hand_angle_zero_deg + truth.hand_angle_sign * hand_angle_deg)
    R_hc, t_hc = _mount(truth)
    axis = (R_bh @ R_hc)[:, 2]
    origin = _centre_mm(truth) - distance_mm * axis
    return origin - R_bh @ t_hc + [offset_mm[0], offset_mm[1], 0.0]


def upright_angle(truth: TwinTruth, turn_deg: float = 0.0) -> float:
    """The hand angle θ, deg, at which the tablet's x axis appears turned ``turn_deg`` from
    the picture's u axis (to 0.1°)."""
    R_hc, _ = _mount(truth)
    with_tablet = np.asarray(truth.htm().tablet_pose()[0], dtype=float)[:, 0]
    phis = np.arange(0.0, 360.0, 0.1)
    seen = np.array([R_hc.T @ _R_base_hand(p).T @ with_tablet for p in phis])
    off = (np.degrees(np.arctan2(seen[:, 1], seen[:, 0])) - turn_deg + 180.0) % 360.0 - 180.0
    phi = float(phis[np.argmin(np.abs(off))])
    theta = (phi - truth.hand_angle_zero_deg) * truth.hand_angle_sign
    return float((theta + 180.0) % 360.0 - 180.0)


def _tablet(rng: np.random.Generator) -> dict[str, float]:
    """The tablet's yaw and tilt (HTM angles), deg."""
    tilt = rng.uniform(*WIDE_RANGES["tablet_tilt_deg"])
    direction = rng.uniform(0.0, 2.0 * np.pi)
    return {"alpha_t": float(tilt * np.cos(direction)), "beta_t": float(tilt * np.sin(direction)),
            "gamma_t": float(rng.uniform(*WIDE_RANGES["tablet_yaw_deg"]))}  # fmt: skip


def _camera_and_pen(rng: np.random.Generator, model: str) -> dict[str, float]:
    offset = WIDE_RANGES["camera_offset_mm"]
    out = {"xc": float(rng.uniform(*offset)), "yc": float(rng.uniform(*offset)),
           "alpha_c": float(rng.uniform(*WIDE_RANGES["camera_tilt_deg"])),
           "beta_c": float(rng.uniform(*WIDE_RANGES["camera_tilt_deg"])),
           "gamma_c": float(rng.uniform(*WIDE_RANGES["camera_roll_deg"])),
           "xp": float(rng.uniform(*WIDE_RANGES["pen_offset_mm"])),
           "yp": float(rng.uniform(*WIDE_RANGES["pen_offset_mm"]))}  # fmt: skip
    if model == "dh":  # the DH chain holds the camera on the hand's x axis
        out["yc"] = 0.0
    return out


def draw_wide_truth(
    seed: int,
    *,
    model: str = "htm",
    image_size_px: tuple[int, int] = (640, 480),
    display_px: tuple[float, float] = (1280.0, 800.0),
    lens_blur_px: float = 0.5,
    dot_px: float = WIDE_DOT_PX,
    scale: float = 2.0,
) -> TwinTruth:
    """A random wide rig (see the module), drawn by ``seed`` (bit-for-bit repeatable).

    Intrinsics, camera height on the hand, tablet height and ppi are drawn from
    :data:`~handeye_jax.twin.RANGES` as :func:`draw_truth` draws them; the landmarks are the
    paper's 3×3 snake, touched at hand angles ``22.5·m`` deg. Draws whose picture leaves a
    landmark outside the margin are redrawn from the same stream.

    Args:
        seed: the seed of the draw.
        model: ``"htm"`` (any rig) or ``"dh"`` (a rig the DH model holds exactly).
        image_size_px, display_px, lens_blur_px, dot_px, scale: as for :func:`draw_truth`.
    """
    if model not in WIDE_MODELS:
        raise ValueError(f"unknown model {model!r} for a wide rig; known: {', '.join(WIDE_MODELS)}")
    rng = np.random.default_rng(seed)
    layout = snake_grid_px()
    w, h = image_size_px
    for _ in range(1000):
        base = {k: float(rng.uniform(lo, hi)) for k, (lo, hi) in RANGES.items()}
        zero, sign = HAND_ANGLE_CONVENTIONS[int(rng.integers(len(HAND_ANGLE_CONVENTIONS)))]
        params = {**_tablet(rng), **_camera_and_pen(rng, model), "xt": 0.0, "yt": 0.0}
        camera = {"fx": base["fx"], "fy": base["fx"], "cx": (w - 1) / 2 + base["cx_offset"],
                  "cy": (h - 1) / 2 + base["cy_offset"]}  # fmt: skip
        truth = TwinTruth(
            image_size_px=(int(w), int(h)), camera_px=camera, lens_blur_px=float(lens_blur_px),
            model=params, camera_z_mm=base["zc_mm"], tablet_height_mm=base["tablet_height_mm"],
            capture_position_mm=(0.0, 0.0, 0.0), ppi=base["ppi"], scale=float(scale),
            display_px=(float(display_px[0]), float(display_px[1])), dot_px=float(dot_px),
            hand_angle_zero_deg=zero, hand_angle_sign=sign,
            landmarks_tablet_px=np.array(layout, dtype=float),
            landmarks_hand_angle_deg=22.5 * np.arange(len(layout)), seed=int(seed),
            capture_hand_angle_deg=0.0,
        )  # fmt: skip
        truth = _placed(truth, rng, model)
        angle = upright_angle(truth, float(rng.uniform(-UPRIGHT_DEG, UPRIGHT_DEG)))
        jitter = rng.uniform(-10.0, 10.0, 2)
        position = aimed_position(truth, angle, float(rng.uniform(*WIDE_RANGES["distance_mm"])),
                                  (float(jitter[0]), float(jitter[1])))  # fmt: skip
        truth = truth.at_capture(position, angle)
        if truth.sees(truth.landmarks_tablet_px):
            return truth
    raise ValueError("could not draw a wide rig whose picture holds every landmark")


def _placed(truth: TwinTruth, rng: np.random.Generator, model: str) -> TwinTruth:
    """``truth`` with the tablet moved so that the landmarks' centre lies at a drawn point of
    the area (for DH: the tablet's origin on the base x axis, the centre at a drawn x)."""
    centre = _centre_mm(truth)[:2]  # with the tablet's origin at the base's
    x = rng.uniform(*WIDE_RANGES["centre_x_mm"])
    y = rng.uniform(*WIDE_RANGES["centre_y_mm"])
    xt, yt = (x - centre[0], 0.0) if model == "dh" else (x - centre[0], y - centre[1])
    return replace(truth, model={**truth.model, "xt": float(xt), "yt": float(yt)})


def capture_distance_mm(truth: TwinTruth) -> float:
    """The landmarks' centre's depth in the truth's picture, mm."""
    return float(truth.project(np.mean(truth.landmark_area_px(), axis=0)[None])[1][0])
