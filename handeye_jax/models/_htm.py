"""The six-DoF homogeneous-transform model of eqs. (2) and (11); Table 5's search ranges."""

from __future__ import annotations

from typing import ClassVar

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .. import geometry as geo
from ._base import AbstractModel
from ._euler import wrap_deg, zyx_angles_deg


class HTMModel(AbstractModel):
    """Camera mount and tablet pose as six-DoF transforms (12 parameters).

    ``R_hand_camera = Rz(γc)·Ry(βc + 180)·Rx(αc + 180)``, ``t_hand_camera = (xc, yc, 0)``;
    ``R_base_tablet = Rz(γt)·Ry(βt)·Rx(αt + 180)``, ``t_base_tablet = (xt, yt, 0)``;
    pen tip ``(xp, yp, 0)``. Lengths in mm, angles in degrees. ``zc``, ``zt`` and ``zp`` never
    enter the objective, which compares x and y only (section 3.5).
    """

    xc: Float[Array, ""]
    yc: Float[Array, ""]
    alpha_c: Float[Array, ""]
    beta_c: Float[Array, ""]
    gamma_c: Float[Array, ""]
    xt: Float[Array, ""]
    yt: Float[Array, ""]
    alpha_t: Float[Array, ""]
    beta_t: Float[Array, ""]
    gamma_t: Float[Array, ""]
    xp: Float[Array, ""]
    yp: Float[Array, ""]

    name: ClassVar[str] = "htm"
    param_names: ClassVar[tuple[str, ...]] = (
        "xc", "yc", "alpha_c", "beta_c", "gamma_c",
        "xt", "yt", "alpha_t", "beta_t", "gamma_t",
        "xp", "yp",
    )  # fmt: skip
    # Flipping both tablet tilts mirrors the tablet through its own plane (Tables 7, 8).
    sign_twin: ClassVar[tuple[str, ...]] = ("alpha_t", "beta_t")
    groups: ClassVar[dict[str, tuple[str, ...]]] = {
        "camera": ("xc", "yc", "alpha_c", "beta_c", "gamma_c"),
        "tablet": ("xt", "yt", "alpha_t", "beta_t", "gamma_t"),
        "pen": ("xp", "yp"),
    }
    param_units: ClassVar[tuple[str, ...]] = (
        "mm", "mm", "deg", "deg", "deg", "mm", "mm", "deg", "deg", "deg", "mm", "mm",
    )  # fmt: skip
    # Table 5, with the xt/yt and xp/yp labels of Table 7 un-swapped (paper notes, item 2).
    default_ranges: ClassVar[dict[str, tuple[float, float]]] = {
        "xc": (-20.0, 20.0), "yc": (20.0, 50.0),
        "alpha_c": (-30.0, 30.0), "beta_c": (-30.0, 30.0), "gamma_c": (-30.0, 30.0),
        "xt": (100.0, 200.0), "yt": (0.0, 100.0),
        "alpha_t": (-30.0, 30.0), "beta_t": (-30.0, 30.0), "gamma_t": (-30.0, 30.0),
        "xp": (-20.0, 20.0), "yp": (-40.0, -10.0),
    }  # fmt: skip

    def camera_mount(self):
        R = geo.rot_zyx(self.gamma_c, self.beta_c + 180.0, self.alpha_c + 180.0)
        return R, jnp.stack([self.xc, self.yc, jnp.zeros_like(self.xc)])

    def tablet_pose(self):
        R = geo.rot_zyx(self.gamma_t, self.beta_t, self.alpha_t + 180.0)
        return R, jnp.stack([self.xt, self.yt, jnp.zeros_like(self.xt)])

    def t_hand_pen(self):
        return jnp.stack([self.xp, self.yp, jnp.zeros_like(self.xp)])

    @classmethod
    def from_frames(cls, R_hand_camera, t_hand_camera_mm, R_base_tablet, t_base_tablet_mm,
                    t_hand_pen_mm):  # fmt: skip
        # Rz(γ)·Ry(β + 180)·Rx(α + 180) = Rz(γ + 180)·Ry(−β)·Rx(α): the triple with the small
        # tilts of a camera that looks along the hand's axis.
        g, b, a = zyx_angles_deg(R_hand_camera)
        gt, bt, at = zyx_angles_deg(R_base_tablet)
        t_c, t_t, t_p = (np.asarray(t, dtype=float) for t in
                         (t_hand_camera_mm, t_base_tablet_mm, t_hand_pen_mm))  # fmt: skip
        return {
            "xc": float(t_c[0]), "yc": float(t_c[1]), "alpha_c": wrap_deg(a), "beta_c": -b,
            "gamma_c": wrap_deg(g - 180.0), "xt": float(t_t[0]), "yt": float(t_t[1]),
            "alpha_t": wrap_deg(at - 180.0), "beta_t": bt, "gamma_t": wrap_deg(gt),
            "xp": float(t_p[0]), "yp": float(t_p[1]),
        }  # fmt: skip
