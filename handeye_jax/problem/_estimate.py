"""A closed-form first estimate of the rig from the data alone (NumPy, no search ranges).

Two linear steps, then a rigid fit:

1. **The touches.** Each touch says that the touched point, ``A·q + t`` in base x-y (``q``
   the landmark plus the touch error, mm on the tablet; ``A`` the x-y rows of the tablet's
   first two axes; ``t`` its origin), equals the hand plus the turned pen offset,
   ``h + M(φ)·p`` with ``M(φ) = [[−cos φ, sin φ], [sin φ, cos φ]]`` (eq. 7). That is linear
   in ``A``, ``t`` and ``p``: least squares. Touches at two or more hand angles separate the
   pen from the tablet; at one they do not, and the pen is taken as 0 (its offset then sits
   in ``t``).
2. **The tablet's tilt.** ``A`` is the top of two orthonormal columns, so ``I − AᵀA = z·zᵀ``
   with ``z`` the columns' third components: its largest eigenpair gives ``z`` up to its
   sign, the tablet mirrored through its own plane (the sign twin). Tilts show only to second
   order in ``A``, so a small tilt is known poorly.
3. **The camera mount.** Each view's landmark, in base coordinates from 1–2 (its height up
   to the tablet's unknown ``z_t``, which every row shares), is taken into the hand frame of
   its capture pose; the camera-frame points the picture and depth give are fitted to those
   by a rotation and a translation (Kabsch): ``R_hand_camera``, ``t_hand_camera``. One
   capture cannot tell the two signs of the tablet's tilt apart (a plane's mirror image is a
   turned copy of it: both fit exactly, with camera mounts the shift/tilt trade-off apart);
   captures at several hand angles can, and the better fit comes first (else the camera
   nearer the hand's axis, as mounts are usually designed).

A model turns each candidate into its parameters with ``from_frames``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from jaxtyping import Float

from .._jax import in_float64
from ..data import Observations
from ..models import AbstractModel

#: A second candidate whose views fit worse than this factor times the first's (RMS) is
#: ruled out by the data: the tablet tilt's sign is then determined.
SIGN_RULED_OUT = 1.25
#: Hand angles closer than this, deg, count as one when asking whether the touches separate
#: the pen from the tablet.
SAME_ANGLE_DEG = 1.0


@dataclass(frozen=True)
class RigEstimate:
    """One closed-form candidate of the rig: the frames, and how well the views fit them.

    Attributes:
        R_hand_camera, t_hand_camera_mm: the camera in the hand frame (the translation's z is
            the camera's height less the tablet's, which the data do not separate).
        R_base_tablet, t_base_tablet_mm: the tablet in the base frame (z = 0: unknown).
        t_hand_pen_mm: the pen tip in the hand frame at φ = 0 (z = 0: unknown).
        view_rms_mm: RMS distance of the views' camera-frame points from the landmarks the
            frames put there, mm (3-D, the tablet's height taken as the views say).
    """

    R_hand_camera: np.ndarray
    t_hand_camera_mm: np.ndarray
    R_base_tablet: np.ndarray
    t_base_tablet_mm: np.ndarray
    t_hand_pen_mm: np.ndarray
    view_rms_mm: float

    def params(self, model_cls: type[AbstractModel]) -> dict[str, float]:
        """The model's parameters for these frames (``NotImplementedError`` for a model
        without ``from_frames``)."""
        return model_cls.from_frames(self.R_hand_camera, self.t_hand_camera_mm,
                                     self.R_base_tablet, self.t_base_tablet_mm,
                                     self.t_hand_pen_mm)  # fmt: skip


@dataclass(frozen=True)
class ClosedFormEstimate:
    """The closed-form estimate of :func:`closed_form_estimate`.

    Attributes:
        candidates: the rig for each sign of the tablet's tilt, the better view fit first
            (when the views cannot tell them apart, the camera nearer the hand's axis).
        touch_rms_mm: RMS length of the touches' residuals in step 1, mm.
        touches: the distinct touches used.
        pen_determined: the touches were made at two or more hand angles, so the pen offset
            is separate from the tablet's position (else it is 0 and sits in the tablet's).
        tilt_deg: the tablet's tilt from the horizontal, deg (to second order: poorly known
            when small).
        sign_determined: the views tell the tilt's sign (several captures at other hand
            angles); else both candidates fit them alike.
    """

    candidates: tuple[RigEstimate, ...]
    touch_rms_mm: float
    touches: int
    pen_determined: bool
    tilt_deg: float
    sign_determined: bool


def pen_turn(phi_deg: Float[np.ndarray, " n"]) -> Float[np.ndarray, "n 2 2"]:
    """``M(φ)``: the x-y block of ``Ry(−180)·Rz(φ)``, which turns the pen offset (eq. 7)."""
    r = np.deg2rad(np.asarray(phi_deg, dtype=float))
    s, c = np.sin(r), np.cos(r)
    return np.stack([np.stack([-c, s], -1), np.stack([s, c], -1)], -2)


def R_base_hand(phi_deg: Float[np.ndarray, " n"]) -> Float[np.ndarray, "n 3 3"]:
    """``Ry(−180)·Rz(φ)``: the hand pointing down, turned by φ (eq. 1)."""
    r = np.deg2rad(np.asarray(phi_deg, dtype=float))
    s, c = np.sin(r), np.cos(r)
    zero, one = np.zeros_like(c), np.ones_like(c)
    return np.stack([np.stack([-c, s, zero], -1), np.stack([s, c, zero], -1),
                     np.stack([zero, zero, -one], -1)], -2)  # fmt: skip


def kabsch(
    p: Float[np.ndarray, "n 3"], q: Float[np.ndarray, "n 3"]
) -> tuple[np.ndarray, np.ndarray, float]:
    """``(R, t, rms)`` of the rigid motion that best maps points ``p`` onto ``q`` (least
    squares, a proper rotation), and the RMS distance left, in the points' unit."""
    pm, qm = p.mean(axis=0), q.mean(axis=0)
    U, _, Vt = np.linalg.svd((p - pm).T @ (q - qm))
    d = np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0
    R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    t = qm - R @ pm
    rms = float(np.sqrt(np.mean(np.sum((p @ R.T + t - q) ** 2, axis=1))))
    return R, t, rms


def _touch_rows(obs: Observations) -> np.ndarray:
    """One row per distinct touch (a touch seen from k captures gives k rows)."""
    if obs.touch_index is None:
        return np.arange(obs.n_landmarks)
    return np.unique(np.asarray(obs.touch_index), return_index=True)[1]


def _touches(obs: Observations) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, int, bool]:
    """Step 1: ``(A, t, p, rms_mm, touches, pen_determined)`` by linear least squares."""
    rows = _touch_rows(obs)
    q = np.asarray(obs.tablet_mm)[rows] + np.asarray(obs.touch_error_mm)[rows]
    h = np.asarray(obs.hand_xy_mm)[rows]
    phi = np.asarray(obs.phi_deg())[rows]
    M = pen_turn(phi)
    k = len(rows)
    angles = np.round(np.asarray(phi) / SAME_ANGLE_DEG)
    pen = len(np.unique(np.mod(angles, 360.0 / SAME_ANGLE_DEG))) >= 2
    X = np.zeros((2 * k, 8))
    X[0::2, 0:2], X[0::2, 4], X[0::2, 6:8] = q, 1.0, -M[:, 0, :]
    X[1::2, 2:4], X[1::2, 5], X[1::2, 6:8] = q, 1.0, -M[:, 1, :]
    if not pen:
        X = X[:, :6]
    if np.linalg.matrix_rank(X) < X.shape[1]:
        raise ValueError(f"the {k} touches do not determine the tablet's pose (too few, or "
                         "their landmarks in a line)")  # fmt: skip
    sol, *_ = np.linalg.lstsq(X, h.reshape(-1), rcond=None)
    res = (X @ sol - h.reshape(-1)).reshape(-1, 2)
    rms = float(np.sqrt(np.mean(np.sum(res**2, axis=1))))
    p = sol[6:8] if pen else np.zeros(2)
    return sol[:4].reshape(2, 2), sol[4:6], p, rms, k, pen


def _tablet_axes(A: np.ndarray, sign: float) -> np.ndarray:
    """Step 2: the tablet's rotation whose first two columns have ``A`` as their x-y rows
    (nearest, orthonormalised), its tilt of the given sign."""
    w, V = np.linalg.eigh(0.5 * ((np.eye(2) - A.T @ A) + (np.eye(2) - A.T @ A).T))
    z = np.sqrt(max(float(w[-1]), 0.0)) * V[:, -1]
    U, _, Vt = np.linalg.svd(np.vstack([A, sign * z[None]]), full_matrices=False)
    B = U @ Vt
    return np.column_stack([B[:, 0], B[:, 1], np.cross(B[:, 0], B[:, 1])])


def _capture_poses(obs: Observations) -> tuple[np.ndarray, np.ndarray]:
    """Each row's capture position, mm ``(n, 3)``, and hand turn φc, deg ``(n,)``."""
    n, rig = obs.n_landmarks, obs.rig
    if obs.capture_position_mm is None:
        return (np.tile(np.asarray(rig.capture_position_mm, dtype=float), (n, 1)),
                np.full(n, float(rig.capture_phi_deg())))  # fmt: skip
    return np.asarray(obs.capture_position_mm, float), np.asarray(obs.capture_phi_deg(), float)


def _off_axis(R_hand_camera: np.ndarray) -> float:
    """The angle between the camera's optical axis and the hand's z axis, rad."""
    return float(np.arccos(np.clip(abs(R_hand_camera[2, 2]), 0.0, 1.0)))


@in_float64
def closed_form_estimate(obs: Observations) -> ClosedFormEstimate:
    """The rig from the data alone, in closed form (see the module): no search ranges.

    Args:
        obs: the observations (any captures and convention; the pen must be touched at two
            or more hand angles for its offset to be estimated).

    Raises:
        ValueError: the touches do not determine the tablet's pose, or the views are fewer
            than three or in a line.
    """
    A, t, p, touch_rms, k, pen = _touches(obs)
    rig = obs.rig
    p_camera = np.asarray(rig.p_camera(obs.image_px, obs.depth_mm), dtype=float)
    centred = p_camera - p_camera.mean(axis=0)
    if len(p_camera) < 3 or np.linalg.svd(centred, compute_uv=False)[1] < 1e-6:
        raise ValueError("the views do not determine the camera mount (fewer than three "
                         "landmarks seen, or all in a line)")  # fmt: skip
    positions, phis = _capture_poses(obs)
    R_bh = R_base_hand(phis)
    tablet_mm = np.asarray(obs.tablet_mm, dtype=float)
    candidates = []
    for sign in (1.0, -1.0):
        R_bt = _tablet_axes(A, sign)
        x_base = tablet_mm @ R_bt[:, :2].T + np.array([t[0], t[1], 0.0])
        # Each landmark in the hand frame of its capture: R_bhᵀ·(x − position).
        x_hand = np.einsum("nji,nj->ni", R_bh, x_base - positions)
        R_hc, t_hc, rms = kabsch(p_camera, x_hand)
        candidates.append(RigEstimate(R_hc, t_hc, R_bt, np.array([t[0], t[1], 0.0]),
                                      np.array([p[0], p[1], 0.0]), rms))  # fmt: skip
    candidates.sort(key=lambda c: c.view_rms_mm)
    best, other = candidates[0].view_rms_mm, candidates[1].view_rms_mm
    determined = other > SIGN_RULED_OUT * best + 1e-9
    if not determined:
        # Both fit alike, so their order by fit is rounding's: the camera nearer the hand's
        # axis (how mounts are designed) comes first, the same on every machine.
        candidates.sort(key=lambda c: _off_axis(c.R_hand_camera))
    tilt = float(np.degrees(np.arccos(np.clip(abs(candidates[0].R_base_tablet[2, 2]), 0, 1))))
    return ClosedFormEstimate(tuple(candidates), touch_rms, k, pen, tilt, determined)
