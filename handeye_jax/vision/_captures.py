"""The pictures the toolkit recommends: captures planned from a dataset's first one.

One picture from one pose leaves the camera mount's x offset trading off against its tilt
(``xc``/``βc``, ``yc``/``αc``); pictures from other heights, through a mount turned by
other hand angles, tell them apart. :func:`plan_captures` adds those captures to a dataset,
empty (no landmark seen yet), so that the tablet page lists their poses and ``detect
--capture K`` fills each. :func:`planned_view` says where such a picture will show each
landmark, before the calibration, by the rig's approximate model.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .._core import RECOMMENDED_CAPTURES as RECOMMENDED
from ..data import Capture, Dataset


def plan_captures(
    dataset: Dataset,
    rises_mm: Sequence[float] = tuple(r for r, _ in RECOMMENDED),
    turns_deg: Sequence[float] = tuple(t for _, t in RECOMMENDED),
) -> tuple[Dataset, list[int]]:
    """The dataset with an empty capture planned for each ``(rise, turn)``.

    Args:
        dataset: a dataset with at least one capture; the plan starts from its first.
        rises_mm: how much higher than the first capture each picture is taken, mm (the hand's
            z in the base frame; x and y stay the first capture's).
        turns_deg: the hand angle of each picture minus the first capture's, deg.

    Returns:
        The new dataset (version 2) and the index of each planned capture. A planned pose
        that a capture of the dataset already has is not added again; its index is given.

    Raises:
        ValueError: ``rises_mm`` and ``turns_deg`` differ in length, or hold a number that
            is not finite.
    """
    rises, turns = np.asarray(rises_mm, dtype=float), np.asarray(turns_deg, dtype=float)
    if rises.shape != turns.shape or rises.ndim != 1:
        raise ValueError(f"give one turn per rise (got {rises.size} rises, {turns.size} turns)")
    if not (np.isfinite(rises).all() and np.isfinite(turns).all()):
        raise ValueError("rises and turns must be finite")
    first = dataset.captures[0]
    caps = list(dataset.captures)
    indices = []
    for rise, turn in zip(rises, turns, strict=True):
        position = first.hand_position_mm + np.array([0.0, 0.0, rise])
        angle = first.hand_angle_deg + turn
        same = [k for k, c in enumerate(caps) if c.hand_angle_deg == angle
                and np.array_equal(c.hand_position_mm, position)]  # fmt: skip
        if same:
            indices.append(same[0])
            continue
        caps.append(Capture(position, angle, [], np.zeros((0, 2)), np.zeros(0)))
        indices.append(len(caps) - 1)
    return dataset.replace(captures=caps, version=2), indices


#: The camera mount of a rig like the paper's (HTM model; mm, deg): each parameter's value and
#: how far a real mount may be from it (the twins' ranges). A dataset's search ranges, where it
#: gives them, move the value to their middle.
APPROXIMATE_MOUNT = {"xc": (0.0, 8.0), "yc": (35.0, 7.0), "alpha_c": (0.0, 3.0),
                     "beta_c": (0.0, 3.0), "gamma_c": (0.0, 5.0)}  # fmt: skip


@dataclass(frozen=True)
class PlannedView:
    """Where a planned picture will show each landmark, by the rig's approximate model.

    Attributes:
        image_px: where the approximate mount puts each landmark, image px, ``(n, 2)``
            (NaN for a landmark behind the camera).
        outside: the landmarks it puts outside the picture (or behind the camera).
        at_risk: the landmarks it puts inside that a mount within
            :data:`APPROXIMATE_MOUNT`'s spread would put outside: near the edge.
        image_size_px: the picture's ``(width, height)``, image px.
        mount: the mount it assumed: each parameter's value and spread, ``name -> (value,
            spread)`` (mm, deg).
    """

    image_px: np.ndarray
    outside: tuple[int, ...]
    at_risk: tuple[int, ...]
    image_size_px: tuple[int, int]
    mount: dict[str, tuple[float, float]]

    def describe_mount(self) -> str:
        """The mount it assumed, in words: ``"xc 0 ± 8 mm, yc 35 ± 7 mm, …"``."""
        unit = {"xc": " mm", "yc": " mm"}
        return ", ".join(f"{k} {v:g} ± {d:g}{unit.get(k, ' deg')}"
                         for k, (v, d) in self.mount.items())  # fmt: skip

    @property
    def in_view(self) -> bool:
        """Whether every landmark is in the picture whatever the mount within the spread."""
        return not self.outside and not self.at_risk


def _rot_zyx(gamma_deg: float, beta_deg: float, alpha_deg: float) -> np.ndarray:
    """``Rz(γ)·Ry(β)·Rx(α)``, angles in degrees."""
    (sg, sb, sa), (cg, cb, ca) = (f(np.radians([gamma_deg, beta_deg, alpha_deg])) for f in
                                  (np.sin, np.cos))  # fmt: skip
    Rz = np.array([[cg, -sg, 0.0], [sg, cg, 0.0], [0.0, 0.0, 1.0]])
    Ry = np.array([[cb, 0.0, sb], [0.0, 1.0, 0.0], [-sb, 0.0, cb]])
    Rx = np.array([[1.0, 0.0, 0.0], [0.0, ca, -sa], [0.0, sa, ca]])
    return Rz @ Ry @ Rx


def _first_view_mm(dataset: Dataset) -> np.ndarray:
    """Every landmark in the camera frame of the first capture, mm, ``(n, 3)``: measured where
    the picture shows it (eq. 4), else on the plane through those (the flat tablet, mapped
    from ``tablet_px`` by least squares)."""
    first, cam = dataset.captures[0], dataset.camera
    seen = np.asarray(first.landmarks, dtype=int)
    ray = (np.asarray(first.image_px) - [cam.cx_px, cam.cy_px]) / [cam.fx_px, cam.fy_px]
    p = np.c_[ray, np.ones(len(seen))] * np.asarray(first.depth_mm)[:, None]
    tablet = np.c_[dataset.tablet_px, np.ones(len(dataset.tablet_px))]
    if len(seen) < 3 or np.linalg.matrix_rank(tablet[seen]) < 3:
        few = f"{len(seen)} landmark(s)" + (" in a row" if len(seen) >= 3 else "")
        raise ValueError(f"capture 0 shows {few}: where the tablet is takes a picture of at "
                         "least three, not in a row")  # fmt: skip
    out = tablet @ np.linalg.lstsq(tablet[seen], p, rcond=None)[0]
    out[seen] = p
    return out


def planned_view(
    dataset: Dataset,
    position_mm: Sequence[float],
    hand_angle_deg: float,
    image_size_px: tuple[int, int],
    mount: dict[str, float] | None = None,
) -> PlannedView:
    """Where a picture from another hand pose will show each landmark, by the rig's
    approximate model, from what the dataset's first capture saw.

    The landmarks' positions come from the first capture's picture and depths (the ones it
    does not show, from the tablet's plane through those it does); the camera moves with the
    hand, mounted as :data:`APPROXIMATE_MOUNT` says. A landmark is in view when every mount
    within that spread (each parameter at either end) puts it inside the picture.

    Args:
        dataset: the dataset; its first capture must show at least three landmarks, not in a
            row.
        position_mm: the hand's position ``(x, y, z)`` for the picture, mm, base frame.
        hand_angle_deg: the hand angle θ for the picture, deg.
        image_size_px: the picture's ``(width, height)``, image px.
        mount: the camera mount's ``xc``, ``yc`` (mm), ``alpha_c``, ``beta_c``, ``gamma_c``
            (deg), HTM model, if known (e.g. calibrated); by default the middle of the
            dataset's search ranges, else :data:`APPROXIMATE_MOUNT`'s values. The spread
            around it is :data:`APPROXIMATE_MOUNT`'s.

    Raises:
        ValueError: the first capture shows too few landmarks to place the tablet.
    """
    first, cam = dataset.captures[0], dataset.camera
    p_first = _first_view_mm(dataset)
    zero, sign = dataset.hand_angle_zero_deg, dataset.hand_angle_sign

    def R_base_hand(theta):  # the hand points down, turned by φ (eq. 1)
        return np.diag([-1.0, 1.0, -1.0]) @ _rot_zyx(zero + sign * theta, 0.0, 0.0)

    def picture(mount):
        R = _rot_zyx(mount["gamma_c"], mount["beta_c"] + 180.0, mount["alpha_c"] + 180.0)
        t = np.array([mount["xc"], mount["yc"], 0.0])  # zc moves both poses alike
        base = first.hand_position_mm + (p_first @ R.T + t) @ R_base_hand(first.hand_angle_deg).T
        p = ((base - np.asarray(position_mm, float)) @ R_base_hand(hand_angle_deg) - t) @ R
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = p[:, :2] / p[:, 2:] * [cam.fx_px, cam.fy_px] + [cam.cx_px, cam.cy_px]
        w, h = image_size_px
        inside = (p[:, 2] > 0) & np.all((uv >= 0) & (uv <= [w - 1, h - 1]), axis=1)
        return np.where(p[:, 2:] > 0, uv, np.nan), inside

    middle = {k: float(np.mean(dataset.search[k])) if k in dataset.search else v
              for k, (v, _) in APPROXIMATE_MOUNT.items()}  # fmt: skip
    middle.update({k: float(mount[k]) for k in APPROXIMATE_MOUNT if mount and k in mount})
    uv, inside = picture(middle)
    always = inside.copy()
    for ends in itertools.product((-1.0, 1.0), repeat=len(APPROXIMATE_MOUNT)):
        mount = {k: middle[k] + e * APPROXIMATE_MOUNT[k][1]
                 for k, e in zip(APPROXIMATE_MOUNT, ends, strict=True)}  # fmt: skip
        always &= picture(mount)[1]
    size = (int(image_size_px[0]), int(image_size_px[1]))
    return PlannedView(uv, tuple(np.flatnonzero(~inside).tolist()),
                       tuple(np.flatnonzero(inside & ~always).tolist()), size,
                       {k: (middle[k], d) for k, (_, d) in APPROXIMATE_MOUNT.items()})  # fmt: skip
