"""Abstract bases for everything the optimiser fits: stage-1 models and stage-2 corrections.

The equinox abstract/final pattern: abstract classes declare fields-to-be and abstract methods,
and define concrete methods once; final classes fill in the abstract methods and nothing else.
Each parameter is a scalar field, so a model is a pytree that ``jit``, ``grad`` and ``vmap``
pass through, and ``from_vector``/``to_vector`` convert to the flat vectors optimisers use.
"""

from __future__ import annotations

import abc
from collections.abc import Mapping
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .. import geometry as geo
from ._rig import Rig


class AbstractParametric(eqx.Module):
    """A set of named scalar parameters with units and default search ranges.

    Class attributes of a final subclass:
        name: short identifier used in files and on the command line.
        param_names: parameter names, in vector order; also the field names.
        param_units: unit of each parameter, ``"mm"``, ``"deg"`` or ``"1"``.
        default_ranges: the search range ``(lo, hi)`` of each parameter, in its unit.
        groups: named groups of parameters that are refitted together when a part of the rig
            changes (``camera``, ``tablet``, ``pen`` for a model), by name.
        sign_twin: parameters whose signs can flip together without changing the fit (the
            tablet mirrored through its own plane); empty where there is no such symmetry.
            Every stage answers it, so a result reports which twin it found.
    """

    sign_twin: ClassVar[tuple[str, ...]] = ()
    name: eqx.AbstractClassVar[str]
    param_names: eqx.AbstractClassVar[tuple[str, ...]]
    param_units: eqx.AbstractClassVar[tuple[str, ...]]
    default_ranges: eqx.AbstractClassVar[Mapping[str, tuple[float, float]]]
    groups: eqx.AbstractClassVar[Mapping[str, tuple[str, ...]]]

    @classmethod
    def from_vector(cls, theta: Float[Array, " d"], **static):
        """Build from a flat vector in ``param_names`` order (works on tracers)."""
        return cls(**{n: theta[i] for i, n in enumerate(cls.param_names)}, **static)

    @classmethod
    def from_dict(cls, values: Mapping[str, float], **static):
        """Build from a name → value map holding exactly ``param_names``."""
        return cls(**{n: jnp.asarray(values[n], dtype=float) for n in cls.param_names}, **static)

    @classmethod
    def nominal(cls, **static):
        """The middle of every parameter's default search range (a template whose values do
        not matter, e.g. when every parameter is free)."""
        return cls.from_dict({n: sum(cls.default_ranges[n]) / 2 for n in cls.param_names},
                             **static)  # fmt: skip

    def to_vector(self) -> Float[Array, " d"]:
        """The parameters as a flat vector in ``param_names`` order."""
        return jnp.stack([jnp.asarray(getattr(self, n)) for n in self.param_names])

    def to_dict(self) -> dict[str, float]:
        """The parameters as a name → Python float map."""
        return {n: float(getattr(self, n)) for n in self.param_names}

    @classmethod
    def search_bounds(
        cls, overrides: Mapping[str, tuple[float, float]] | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """``(lower, upper)`` search bounds; ``overrides`` replace defaults by name.

        Names in ``overrides`` that this class does not have are ignored, so one dataset's
        ``[search]`` table can serve several models.
        """
        overrides = overrides or {}
        ranges = [overrides.get(n, cls.default_ranges[n]) for n in cls.param_names]
        lo, hi = np.array(ranges, dtype=np.float64).T
        return lo, hi


class AbstractModel(AbstractParametric):
    """A stage-1 model: the camera mount, the tablet pose and the pen offset.

    Final subclasses implement :meth:`camera_mount`, :meth:`tablet_pose` and
    :meth:`t_hand_pen`; the chain of eqs. (5), (8) and (10) is written here once.
    """

    @abc.abstractmethod
    def camera_mount(self) -> tuple[Float[Array, "3 3"], Float[Array, "3"]]:
        """``(R_hand_camera, t_hand_camera)``: the camera in the hand frame (eq. 2 or 12–14)."""

    @abc.abstractmethod
    def tablet_pose(self) -> tuple[Float[Array, "3 3"], Float[Array, "3"]]:
        """``(R_base_tablet, t_base_tablet)``: the tablet in the base frame (eq. 11 or 15–16)."""

    @abc.abstractmethod
    def t_hand_pen(self) -> Float[Array, "3"]:
        """The pen tip in the hand frame at φ = 0, mm (``z_p`` is not identifiable: 0)."""

    @classmethod
    def from_frames(
        cls,
        R_hand_camera: Float[np.ndarray, "3 3"],
        t_hand_camera_mm: Float[np.ndarray, "3"],
        R_base_tablet: Float[np.ndarray, "3 3"],
        t_base_tablet_mm: Float[np.ndarray, "3"],
        t_hand_pen_mm: Float[np.ndarray, "3"],
    ) -> dict[str, float]:
        """The parameters whose chain is nearest these frames (exactly them where the model
        can hold them), name → value: what turns a closed-form estimate of the rig
        (:func:`handeye_jax.closed_form_estimate`) into a start and a search box.

        Only the x and y of the translations enter (the chain never sees a z). A model
        without this conversion raises :class:`NotImplementedError`, and its searches keep its
        ``default_ranges``.

        Args:
            R_hand_camera, t_hand_camera_mm: the camera in the hand frame (mm).
            R_base_tablet, t_base_tablet_mm: the tablet in the base frame (mm).
            t_hand_pen_mm: the pen tip in the hand frame at φ = 0, mm.
        """
        raise NotImplementedError(f"model {cls.name!r} has no conversion from frames")

    def image_to_base(
        self,
        image_px: Float[Array, "n 2"],
        depth_mm: Float[Array, " n"],
        rig: Rig,
        capture_position_mm: Float[Array, "n 3"] | None = None,
        capture_phi_deg: Float[Array, " n"] | None = None,
    ) -> Float[Array, "n 3"]:
        """Image points with depth to the base frame, ``x_bi`` of eq. (5), mm.

        Its z takes the camera at ``z_c = 0`` on the hand (the models carry no z, which the
        x-y objective never sees): the true height is this z minus ``z_c``.

        Args:
            image_px: ``(u, v)`` in pixels.
            depth_mm: depth at each point in mm.
            rig: intrinsics and (by default) the capture pose of the hand.
            capture_position_mm: each point's capture position, mm, ``(n, 3)``; with
                ``capture_phi_deg``, each point's capture pose instead of the rig's.
            capture_phi_deg: the hand's turn ``φc = zero + sign·θc`` at each point's capture,
                deg: ``R_base_hand = Ry(-180)·Rz(φc)`` (the camera turns with the hand).
        """
        p_camera = rig.p_camera(image_px, depth_mm)
        R_hand_camera, t_hand_camera = self.camera_mount()
        p_hand = geo.transform_points(R_hand_camera, t_hand_camera, p_camera)
        if capture_position_mm is None:
            R_base_hand, t_base_hand = rig.T_base_hand_capture()
            return geo.transform_points(R_base_hand, t_base_hand, p_hand)
        return geo.hand_to_base(p_hand, capture_phi_deg, capture_position_mm)

    def tablet_to_base(self, tablet_mm: Float[Array, "n 2"]) -> Float[Array, "n 3"]:
        """Tablet points (mm, on the display plane) to the base frame, ``x_bt`` of eq. (10)."""
        R_base_tablet, t_base_tablet = self.tablet_pose()
        # The points lie on the display plane (z = 0): only R's first two columns act.
        return geo.transform_points(R_base_tablet[:, :2], t_base_tablet, tablet_mm)

    def tablet_vector_to_base(self, v_tablet_mm: Float[Array, "n 2"]) -> Float[Array, "n 3"]:
        """Tablet-plane displacements to the base frame (rotation only), as in eq. (20)."""
        R_base_tablet, _ = self.tablet_pose()
        return geo.rotate_vectors(R_base_tablet[:, :2], v_tablet_mm)

    def pen_offset(self, phi_deg: Float[Array, " n"]) -> Float[Array, "n 3"]:
        """The pen offset ``x'`` in the base frame for pen angles φ (eqs. 6–7), mm."""
        return geo.pen_offset(self.t_hand_pen(), phi_deg)


class AbstractCorrection(AbstractParametric):
    """A stage-2 correction: two planar maps A1 (image chain) and A2 (hand positions).

    Each map turns about a centre point that the objective supplies: the centre landmark of
    the points being mapped (paper notes, item 5).
    """

    @abc.abstractmethod
    def first(
        self, xy_mm: Float[Array, "n 2"], centre_mm: Float[Array, "2"]
    ) -> Float[Array, "n 2"]:
        """A1, applied to base-frame ``(x, y)`` of the image chain, mm."""

    @abc.abstractmethod
    def second(
        self, xy_mm: Float[Array, "n 2"], centre_mm: Float[Array, "2"]
    ) -> Float[Array, "n 2"]:
        """A2, applied to hand positions ``A1(x_bi) − x'``, mm."""
