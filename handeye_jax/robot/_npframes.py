"""The registered models' frames in NumPy alone, for checking a result file without JAX.

What each model's ``camera_mount()``, ``tablet_pose()`` and ``t_hand_pen()`` give
(:mod:`handeye_jax.models`, the definition), written again with NumPy so that the robot PC can
tell whether a result's ``frames`` section is what its parameters give. The tests hold these
to the JAX models, for every registered model, within 1e-12 over the models' search ranges.
A model defined elsewhere has no entry here: its frames are checked on the JAX side.
:func:`chain_of` gives the hand-command chain its numbers from fitted frames.
Lengths in mm, angles in degrees.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING

import numpy as np

from ._npchain import Chain, sincos_deg

if TYPE_CHECKING:
    from ._frames import Frames

#: The stage-2 correction's parameters (``AffinePair.param_names``), as the result stores them.
AFFINE_PARAMS = ("X1", "Y1", "theta1", "Sx1", "Sy1", "X2", "Y2", "theta2", "Sx2", "Sy2")

Mount = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def rot_z(angle_deg: float) -> np.ndarray:
    s, c = sincos_deg(angle_deg)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rot_zyx(gamma_deg: float, beta_deg: float, alpha_deg: float) -> np.ndarray:
    """``Rz(γ)·Ry(β)·Rx(α)`` (angles in degrees), as :func:`handeye_jax.geometry.rot_zyx`."""
    (sg, sb, sa), (cg, cb, ca) = sincos_deg(np.array([gamma_deg, beta_deg, alpha_deg]))
    return np.array([
        [cg * cb, cg * sb * sa - sg * ca, cg * sb * ca + sg * sa],
        [sg * cb, sg * sb * sa + cg * ca, sg * sb * ca - cg * sa],
        [-sb, cb * sa, cb * ca],
    ])  # fmt: skip


def _xy(x: float, y: float) -> np.ndarray:
    """A translation whose z no model determines (NaN, as the frames mark it)."""
    return np.array([x, y, np.nan])


def _htm(p: Mapping[str, float]) -> Mount:
    return (rot_zyx(p["gamma_c"], p["beta_c"] + 180.0, p["alpha_c"] + 180.0), _xy(p["xc"], p["yc"]),
            rot_zyx(p["gamma_t"], p["beta_t"], p["alpha_t"] + 180.0), _xy(p["xt"], p["yt"]),
            _xy(p["xp"], p["yp"]))  # fmt: skip


def _dh(p: Mapping[str, float]) -> Mount:
    s, c = sincos_deg(p["theta_t1"])
    D = np.array([[c, -s, 0.0], [-s, -c, 0.0], [0.0, 0.0, -1.0]])  # eq. (16)'s rotation block
    return (rot_z(90.0 + p["theta_c1"]) @ rot_zyx(90.0 + p["gamma_c"], p["beta_c"], p["alpha_c"]),
            _xy(p["a_c1"], 0.0), D @ rot_zyx(p["gamma_t"], p["beta_t"], p["alpha_t"]),
            _xy(p["a_t1"], 0.0), _xy(p["xp"], p["yp"]))  # fmt: skip


#: Each registered model's parameter names (in the JAX model's order) and its frames.
MODELS: dict[str, tuple[tuple[str, ...], Callable[[Mapping[str, float]], Mount]]] = {
    "htm": (("xc", "yc", "alpha_c", "beta_c", "gamma_c", "xt", "yt", "alpha_t", "beta_t",
             "gamma_t", "xp", "yp"), _htm),
    "dh": (("theta_c1", "a_c1", "alpha_c", "beta_c", "gamma_c", "theta_t1", "a_t1", "alpha_t",
            "beta_t", "gamma_t", "xp", "yp"), _dh),
}  # fmt: skip


def mount_pose_pen(model: str, params: Mapping[str, float]) -> Mount | None:
    """``(R_hand_camera, t_hand_camera_mm, R_base_tablet, t_base_tablet_mm, t_hand_pen_mm)``
    of model ``model`` at ``params`` (the z of each translation NaN: undetermined), or
    ``None`` for a model without a NumPy twin here."""
    if model not in MODELS:
        return None
    return MODELS[model][1](params)


def chain_of(frames: Frames) -> Chain:
    """The numbers the NumPy hand-command chain reads (:class:`~._npchain.Chain`), from fitted
    frames: of the camera's and the pen's translations, their x and y (their z may be
    undetermined, NaN; the chain never reads it)."""
    return Chain(frames.camera_px, frames.R_hand_camera, frames.t_hand_camera_mm[:2].copy(),
                 frames.t_hand_pen_mm[:2].copy(), frames.A1.as_tuple(), frames.A2.as_tuple(),
                 frames.centres_mm)  # fmt: skip
