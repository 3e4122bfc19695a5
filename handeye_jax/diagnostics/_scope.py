"""Where a calibration holds: the captures it was fitted on and the error it expects elsewhere.

One picture of landmarks at one depth leaves a camera shift and a tilt trading off (xc against
βc, yc against αc): hand commands from that capture pose, for points at that depth, are good,
and from another height they are not. :func:`capture_scope` says which case a result is in and
puts a number on it: the hand-command error the fit's covariance expects for the landmarks
seen from the first capture pose, and from one 50 mm higher and lower.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from .._jax import fast_compile, in_float64
from ..calibration import CalibrationResult, Scope
from ..models import Targets, hand_command
from ..problem import FIXED, Heights, WeakDirection, put

#: The capture height changes, mm, at which :func:`capture_scope` gives the expected error.
SCOPE_RISES_MM = (-50.0, 0.0, 50.0)


def camera_tradeoffs(weak_directions: Sequence[WeakDirection], camera: tuple[str, ...],
                     units: dict[str, str]) -> list[WeakDirection]:  # fmt: skip
    """The weak directions that move a camera-mount length and a camera-mount angle together
    (the shift/tilt trade-off of one picture at one depth)."""
    out = []
    for w in weak_directions:
        kinds = {units[p] for p in w.params if p in camera}
        if {"mm", "deg"} <= kinds:
            out.append(w)
    return out


@in_float64
def capture_scope(result: CalibrationResult) -> Scope | None:
    """The captures a result was fitted on, whether the camera mount's shift/tilt trade-off
    is left, and the expected (1σ, RMS over the first capture's views) hand-command error in
    x-y, mm, from the first capture pose moved by each of :data:`SCOPE_RISES_MM`.

    ``None`` without data or stage-1 diagnostics. The error propagates the stage-1
    covariance (Gauss–Newton, x-y residuals) through the hand command of eq. (8); the views
    are moved with the capture (same base points, so depth and image point change with it).
    """
    diag = None if result.diagnostics is None else result.diagnostics.stage1
    data = result.data
    if data is None or diag is None or not diag.precision:
        return None
    model_cls = type(result.model)
    units = dict(zip(model_cls.param_names, model_cls.param_units, strict=True))
    status = result.stage1.status or {}
    free = tuple(n for n in model_cls.param_names if status.get(n, "free") != FIXED)
    P = np.asarray(diag.precision, dtype=float)
    if P.shape != (len(free), len(free)):
        return None
    cov = np.linalg.pinv(P, hermitian=True)
    caps = data.captures
    first = caps[0]
    heights = [float(c.hand_position_mm[2]) for c in caps]
    angles = [float(c.hand_angle_deg) for c in caps]
    depth = np.concatenate([c.depth_mm for c in caps])
    model = put(result.model, free, jnp.asarray([float(getattr(result.model, n)) for n in free]))
    expected = _expected_errors(model, free, result.rig, data, cov)
    trade = camera_tradeoffs(diag.weak_directions, model_cls.groups["camera"], units)
    return Scope(
        captures=len(caps),
        capture_heights_mm=(min(heights), max(heights)),
        hand_angles_deg=(min(angles), max(angles)),
        depth_mm=(float(np.nanmin(depth)), float(np.nanmax(depth))),
        capture_position_mm=tuple(float(x) for x in first.hand_position_mm),
        camera_tradeoffs=tuple(w.note for w in trade),
        expected_error_mm=expected,
    )


def _expected_errors(model, free: tuple[str, ...], rig, data, cov: np.ndarray) -> dict[str, float]:
    """The expected hand-command error (1σ, RMS over the first capture's views of touched
    landmarks, x-y), mm, from the first capture pose moved by each of :data:`SCOPE_RISES_MM`,
    for the stage-1 covariance ``cov`` of ``free``."""
    first = data.captures[0]
    # The first capture's views of touched landmarks, with the touch's hand angle.
    angle_of = {int(m): float(a) for m, a in zip(data.touch_landmark, data.hand_angle_deg,
                                                 strict=True)}  # fmt: skip
    seen = [k for k, m in enumerate(first.landmarks) if int(m) in angle_of]
    uv, d = first.image_px[seen], first.depth_mm[seen]
    theta = np.array([angle_of[int(first.landmarks[k])] for k in seen])
    c = np.array([float(rig.cx_px), float(rig.cy_px)])
    views = (jnp.asarray(theta), jnp.asarray([first.hand_angle_deg]))
    expected = {}
    for rise in SCOPE_RISES_MM:
        d2 = d + rise  # the hand points down: a capture `rise` higher sees them that much deeper
        uv2 = c + (uv - c) * (d / d2)[:, None]
        position = first.hand_position_mm + np.array([0.0, 0.0, rise])
        seen_from = (jnp.asarray(uv2), jnp.asarray(d2), jnp.asarray(position)[None])
        J = np.asarray(_command_jacobian(model, free, rig, seen_from, views))
        var = np.einsum("ij,jk,ik->i", J, cov, J).reshape(-1, 2).sum(axis=1)
        expected[f"{rise:+g}"] = float(np.sqrt(np.mean(np.maximum(var, 0.0))))
    return expected


@fast_compile
def _command_jacobian(model, free: tuple[str, ...], rig, seen_from, views):
    """The Jacobian of eq. (8)'s hand commands, x-y flattened, in ``model``'s ``free``
    parameters: for views ``seen_from`` (image points px, depths mm, capture position mm) at
    ``views`` (touch hand angles, capture hand angle; deg). One program for every rise."""
    uv, depth, position = seen_from
    theta, capture_angle = views
    x0 = jnp.stack([jnp.asarray(getattr(model, n)) for n in free])

    def command(x):
        targets = Targets(uv, depth, theta, position, capture_angle)
        return hand_command(put(model, free, x), rig, targets).reshape(-1)

    return jax.jacfwd(command)(x0)


def scope_lines(scope: Scope | None, heights: Heights | None) -> list[str]:
    """The summary's lines on where the calibration holds, and on heights."""
    lines = []
    if scope:
        e = scope.expected_error_mm
        err = (f"expected hand-command error (1σ, from the covariance) {e['+0']:.2f} mm there, "
               f"{e['+50']:.2f} mm from a capture 50 mm higher, {e['-50']:.2f} mm from one "
               "50 mm lower")  # fmt: skip
        lo, hi = scope.capture_heights_mm
        if scope.captures == 1:
            x, y, z = scope.capture_position_mm
            d0, d1 = scope.depth_mm
            lines.append(
                f"scope: one capture: the calibration holds only for pictures taken from this "
                f"capture pose (hand at ({x:.1f}, {y:.1f}, {z:.1f}) mm) of points at about this "
                f"depth ({d0:.0f}-{d1:.0f} mm); {err}"
            )
        else:
            a0, a1 = scope.hand_angles_deg
            gone = ("the camera mount's shift/tilt trade-offs of a single picture (xc/βc, "
                    "yc/αc) are gone" if not scope.camera_tradeoffs else
                    "a camera shift/tilt trade-off is left: " + "; ".join(
                        scope.camera_tradeoffs))  # fmt: skip
            lines.append(
                f"scope: {scope.captures} captures at hand heights {lo:.0f}-{hi:.0f} mm "
                f"(spread {hi - lo:.0f} mm) and hand angles {a0:.0f} to {a1:.0f} deg: {gone}; "
                f"{err} than the first"
            )
    if heights:
        lines.append(
            f"heights: z_pen − z_camera = {heights.pen_minus_camera_mm:.3f} ± "
            f"{heights.pen_minus_camera_sigma_mm:.3f} mm is determined (hand heights at "
            f"{heights.n_touches:.0f} touch rows, depths of {heights.n_views:.0f} views); "
            f"z_camera and z_pen alone are not (z_tablet + z_camera = "
            f"{heights.tablet_plus_camera_mm:.3f} mm); mean |z error| views "
            f"{heights.f1z_mm:.3f} mm, touches {heights.f2z_mm:.3f} mm (stage 1's DE "
            "and LM values are F plus these two)"
        )
    elif scope:
        lines.append("heights: the touches recorded no hand height: commands are x-y only")
    return lines
