"""The Denavit–Hartenberg variant of eqs. (12)-(16); Table 6's search ranges."""

from __future__ import annotations

from typing import ClassVar

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .. import geometry as geo
from ._base import AbstractModel
from ._euler import wrap_deg, zyx_angles_deg


def _tablet_dh_frame(theta_deg: Float[Array, ""]) -> Float[Array, "3 3"]:
    """The rotation block of eq. (16): a reflection-composed DH frame about z."""
    s, c = geo.sincos_deg(theta_deg)
    zero, one = jnp.zeros_like(c), jnp.ones_like(c)
    return jnp.stack(
        [jnp.stack([c, -s, zero]), jnp.stack([-s, -c, zero]), jnp.stack([zero, zero, -one])]
    )


class DHModel(AbstractModel):
    """Camera mount and tablet pose in DH form (12 parameters), read as paper notes item 8.

    ``R_hand_camera = Rz(90 + θc1)·Rz(90 + γc)·Ry(βc)·Rx(αc)``, ``t_hand_camera = (ac1, 0, 0)``;
    ``R_base_tablet = D(θt1)·Rz(γt)·Ry(βt)·Rx(αt)`` with D the rotation block of eq. (16),
    ``t_base_tablet = (at1, 0, 0)``; pen tip ``(xp, yp, 0)``. ``dc1`` and ``dt1`` do not enter
    the objective. θc1 and γc only enter as a sum, as do θt1 and γt: the diagnostics say so.
    """

    theta_c1: Float[Array, ""]
    a_c1: Float[Array, ""]
    alpha_c: Float[Array, ""]
    beta_c: Float[Array, ""]
    gamma_c: Float[Array, ""]
    theta_t1: Float[Array, ""]
    a_t1: Float[Array, ""]
    alpha_t: Float[Array, ""]
    beta_t: Float[Array, ""]
    gamma_t: Float[Array, ""]
    xp: Float[Array, ""]
    yp: Float[Array, ""]

    name: ClassVar[str] = "dh"
    param_names: ClassVar[tuple[str, ...]] = (
        "theta_c1", "a_c1", "alpha_c", "beta_c", "gamma_c",
        "theta_t1", "a_t1", "alpha_t", "beta_t", "gamma_t",
        "xp", "yp",
    )  # fmt: skip
    # Flipping both tablet tilts mirrors the tablet through its own plane (Tables 7, 8).
    sign_twin: ClassVar[tuple[str, ...]] = ("alpha_t", "beta_t")
    groups: ClassVar[dict[str, tuple[str, ...]]] = {
        "camera": ("theta_c1", "a_c1", "alpha_c", "beta_c", "gamma_c"),
        "tablet": ("theta_t1", "a_t1", "alpha_t", "beta_t", "gamma_t"),
        "pen": ("xp", "yp"),
    }
    param_units: ClassVar[tuple[str, ...]] = (
        "deg", "mm", "deg", "deg", "deg", "deg", "mm", "deg", "deg", "deg", "mm", "mm",
    )  # fmt: skip
    # Table 6; its first row's αt βt γt are the camera's αc βc γc.
    default_ranges: ClassVar[dict[str, tuple[float, float]]] = {
        "theta_c1": (-30.0, 30.0), "a_c1": (20.0, 100.0),
        "alpha_c": (-30.0, 30.0), "beta_c": (-30.0, 30.0), "gamma_c": (-30.0, 30.0),
        "theta_t1": (0.0, 90.0), "a_t1": (80.0, 200.0),
        "alpha_t": (-45.0, 45.0), "beta_t": (-30.0, 30.0), "gamma_t": (-30.0, 30.0),
        "xp": (-20.0, 20.0), "yp": (-40.0, -10.0),
    }  # fmt: skip

    def camera_mount(self):
        R = geo.matmul3(
            geo.rot_z(90.0 + self.theta_c1),
            geo.rot_zyx(90.0 + self.gamma_c, self.beta_c, self.alpha_c),
        )
        zero = jnp.zeros_like(self.a_c1)
        return R, jnp.stack([self.a_c1, zero, zero])

    def tablet_pose(self):
        R = geo.matmul3(
            _tablet_dh_frame(self.theta_t1), geo.rot_zyx(self.gamma_t, self.beta_t, self.alpha_t)
        )
        zero = jnp.zeros_like(self.a_t1)
        return R, jnp.stack([self.a_t1, zero, zero])

    def t_hand_pen(self):
        return jnp.stack([self.xp, self.yp, jnp.zeros_like(self.xp)])

    @classmethod
    def from_frames(cls, R_hand_camera, t_hand_camera_mm, R_base_tablet, t_base_tablet_mm,
                    t_hand_pen_mm):  # fmt: skip
        # The camera: Rz(180 + θc1 + γc)·Ry(βc)·Rx(αc). The tablet: D(θ) = Rz(−θ)·Rx(180), so
        # D(θt1)·Rz(γt)·Ry(βt)·Rx(αt) = Rz(−(θt1 + γt))·Ry(−βt)·Rx(180 + αt). Only the sums
        # θc1 + γc and θt1 + γt enter: each is split in halves. The translations lie on the
        # hand's and the base's x axes: their x is kept, a y the model cannot hold is dropped.
        g, b, a = zyx_angles_deg(R_hand_camera)
        gt, bt, at = zyx_angles_deg(R_base_tablet)
        camera_turn, tablet_turn = wrap_deg(g - 180.0), wrap_deg(-gt)
        t_c, t_t, t_p = (np.asarray(t, dtype=float) for t in
                         (t_hand_camera_mm, t_base_tablet_mm, t_hand_pen_mm))  # fmt: skip
        return {
            "theta_c1": camera_turn / 2, "a_c1": float(t_c[0]), "alpha_c": a, "beta_c": b,
            "gamma_c": camera_turn / 2, "theta_t1": tablet_turn / 2, "a_t1": float(t_t[0]),
            "alpha_t": wrap_deg(at - 180.0), "beta_t": -bt, "gamma_t": tablet_turn / 2,
            "xp": float(t_p[0]), "yp": float(t_p[1]),
        }  # fmt: skip
