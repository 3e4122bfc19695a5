"""A calibration's measurements and conventions, in mm / deg / px: :class:`Dataset`.

What one calibration run measured (the paper's Tables 2 and 3, or more): the landmarks drawn on
the tablet; one or more *captures*, each a picture taken from a hand pose that sees some of the
landmarks; and the *touches*, each the hand pose at which the pen touched a landmark. The file
formats (``handeye-jax.dataset/1`` and ``/2``) are read by :mod:`._read` and written by
:mod:`._write`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jax.numpy as jnp
import numpy as np

from .. import geometry as geo
from .._core import MAX_MEMBER_LANDMARKS, SEARCH_PRESETS, InputError
from .._jax import in_float64
from ..models import Rig
from ._lens import undistort_px
from ._observations import Observations, centre_landmark


@dataclass(frozen=True)
class Camera:
    """Intrinsics: focal lengths and principal point, px, and the lens distortion.

    Attributes:
        fx_px, fy_px, cx_px, cy_px: the pinhole's focal lengths and principal point, px.
        distortion: Brown–Conrady (``plumb_bob``) ``(k1, k2, p1, p2, k3)``, or ``None``: the
            pictures have none (:mod:`._lens`). Image points are undistorted before the chain.
    """

    fx_px: float
    fy_px: float
    cx_px: float
    cy_px: float
    distortion: tuple[float, float, float, float, float] | None = None

    def __post_init__(self):
        if self.distortion is not None:
            d = tuple(float(c) for c in self.distortion)
            if len(d) != 5:
                raise ValueError(f"distortion must be (k1, k2, p1, p2, k3), got {len(d)} numbers")
            object.__setattr__(self, "distortion", d)

    @property
    def px(self) -> tuple[float, float, float, float]:
        """``(fx, fy, cx, cy)``, px."""
        return (self.fx_px, self.fy_px, self.cx_px, self.cy_px)

    def undistort(self, image_px: Any) -> np.ndarray:
        """Measured image points as an ideal pinhole camera would record them, px (NaN where
        the distortion cannot be inverted); unchanged without distortion."""
        return undistort_px(np.asarray(image_px, dtype=np.float64).reshape(-1, 2), self.px,
                            self.distortion)  # fmt: skip


def capture_angle_at_zero(zero_deg: float, sign: int) -> float:
    """The hand angle θ at which ``φ = zero + sign·θ`` is 0: the capture pose of a
    version-1 dataset, whose hand frame is eq. (1)'s ``Ry(−180)``."""
    return float(-zero_deg * sign) + 0.0  # + 0.0: never -0.0


@dataclass(frozen=True, eq=False)
class Capture:
    """One picture: the hand pose it was taken from and the landmarks seen in it.

    Attributes:
        hand_position_mm: the hand's position ``(x, y, z)`` at the capture, mm, base frame.
        hand_angle_deg: the hand angle θ at the capture, deg (the controller's reading; the
            hand points down, eq. 1, turned by ``φ = zero + sign·θ`` about its axis).
        landmarks: the index of each landmark seen, ``(k,)``.
        image_px: where the picture shows each, ``(k, 2)`` px.
        depth_mm: the depth at each, ``(k,)`` mm.
    """

    hand_position_mm: np.ndarray
    hand_angle_deg: float
    landmarks: np.ndarray
    image_px: np.ndarray
    depth_mm: np.ndarray

    def __post_init__(self):
        put = _setter(self)
        put("hand_position_mm", np.array(self.hand_position_mm, dtype=np.float64).reshape(3))
        put("hand_angle_deg", float(self.hand_angle_deg))
        put("landmarks", np.array(self.landmarks, dtype=np.int64).reshape(-1))
        k = self.landmarks.shape[0]
        put("image_px", np.array(self.image_px, dtype=np.float64).reshape(k, 2))
        put("depth_mm", np.array(self.depth_mm, dtype=np.float64).reshape(k))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Capture):
            return NotImplemented
        return all(
            np.array_equal(getattr(self, f.name), getattr(other, f.name))
            for f in dataclasses.fields(self)
        )

    __hash__ = None  # arrays inside



def _checked_preset(preset: str | None) -> str | None:
    if preset is not None and preset not in SEARCH_PRESETS:
        raise ValueError(f"search_preset must be one of {', '.join(SEARCH_PRESETS)} or None "
                         f"(got {preset!r})")  # fmt: skip
    return preset


def _checked_captures(captures: Sequence[Capture], n: int) -> tuple[Capture, ...]:
    """``captures`` as a tuple, each seeing landmark indices ``0 … n − 1`` only."""
    captures = tuple(captures)
    if not captures:
        raise ValueError("a dataset needs at least one capture")
    for c, cap in enumerate(captures):
        if cap.landmarks.size and not (0 <= cap.landmarks.min() and cap.landmarks.max() < n):
            raise ValueError(f"captures[{c}].landmarks must be landmark indices 0 to {n - 1}")
    return captures


def _single_capture(
    n: int, position_mm: Any, hand_angle_deg: float, image_px: Any, depth_mm: Any
) -> Capture:
    """The one capture of a version-1 dataset, seeing its ``n`` landmarks in order, from the
    arrays :class:`Dataset` takes for it (checked: one row per landmark)."""
    image = np.array(image_px, dtype=np.float64)
    depth = np.array(depth_mm, dtype=np.float64)
    if image.shape != (n, 2) or depth.shape != (n,):
        raise ValueError(
            f"image_px must have shape ({n}, 2) and depth_mm ({n},), one row per "
            f"landmark; got {image.shape} and {depth.shape} (tablet_px: ({n}, 2))"
        )
    position = np.array(position_mm, dtype=np.float64)
    if position.shape != (3,):
        raise ValueError(f"capture_position_mm must have shape (3,), got {position.shape}")
    return Capture(position, float(hand_angle_deg), np.arange(n), image, depth)


def _touch_arrays(
    n: int,
    hand_xy_mm: Any,
    hand_angle_deg: Any,
    touch_error_px: Any,
    hand_z_mm: Any,
    touch_landmark: Any,
) -> dict[str, np.ndarray]:
    """The touches' arrays of a :class:`Dataset` with ``n`` landmarks, by field, checked: one
    row per touch (``hand_z_mm`` NaN and ``touch_landmark`` in order when not given)."""
    hand = np.array(hand_xy_mm, dtype=np.float64)
    t = hand.shape[0] if hand.ndim == 2 else -1
    if touch_landmark is None:
        touch_landmark = np.arange(t)
    if hand_z_mm is None:
        hand_z_mm = np.full(max(t, 0), np.nan)
    landmark = np.array(touch_landmark, dtype=np.int64).reshape(-1)
    arrays = {"hand_xy_mm": (hand, (2,)),
              "hand_angle_deg": (np.array(hand_angle_deg, dtype=np.float64), ()),
              "touch_error_px": (np.array(touch_error_px, dtype=np.float64), (2,)),
              "hand_z_mm": (np.array(hand_z_mm, dtype=np.float64), ()),
              "touch_landmark": (landmark, ())}  # fmt: skip
    for key, (a, tail) in arrays.items():
        if t < 0 or a.shape != (t, *tail):
            want = ", ".join(["t", *map(str, tail)])
            raise ValueError(f"{key} must have shape ({want}), one row per touch; got "
                             f"{a.shape} (hand_xy_mm: {hand.shape})")  # fmt: skip
    if t and not (landmark.min() >= 0 and landmark.max() < n):
        raise ValueError(f"touch_landmark must be landmark indices 0 to {n - 1}")
    return {key: a for key, (a, _) in arrays.items()}


def _setter(obj):
    def put(name: str, value: Any) -> None:
        object.__setattr__(obj, name, value)

    return put


#: The landmark and touch arrays of a single-capture dataset, by name: shape after the row axis.
SIMPLE_ARRAYS: dict[str, tuple[int, ...]] = {
    "tablet_px": (2,), "image_px": (2,), "depth_mm": (), "hand_xy_mm": (2,),
    "hand_angle_deg": (), "touch_error_px": (2,),
}  # fmt: skip


class Dataset:
    """One calibration's measurements and conventions, in mm / deg / px.

    Two datasets are equal when every field except ``source`` is equal.

    Attributes:
        name: a label for reports.
        camera: the intrinsics, px.
        tablet_ppi, tablet_scale: the tablet's pixel density and display scale (eq. 9).
        hand_angle_zero_deg, hand_angle_sign: ``φ = zero + sign·θh`` (paper notes, item 3).
        search: search-range overrides ``name -> (lo, hi)``, in each parameter's unit.
        search_preset: where the other search ranges come from (``[search] preset``):
            ``"estimate"`` or ``"paper"``, or ``None`` (the settings decide; by default the
            estimate).
        tablet_px: where each landmark is drawn on the tablet, px, ``(n, 2)``.
        captures: the pictures (at least one).
        touch_landmark: the landmark each touch touched, ``(t,)``.
        hand_xy_mm: hand ``(x_r, y_r)`` at each touch, mm, ``(t, 2)``.
        hand_z_mm: hand height at each touch as the controller reports it, mm, ``(t,)``;
            NaN where it was not recorded.
        hand_angle_deg: hand angle ``θh`` at each touch, deg, ``(t,)``.
        touch_error_px: touched minus drawn position, tablet px, ``(t, 2)``.
        version: the file format version it came from or is written in (1 or 2).
        source: the file it was loaded from, if any.

    A single-capture dataset whose capture sees every landmark in order and whose touches
    touch every landmark in order (the paper's, a version-1 file) is *simple*: it also has
    ``capture_position_mm``, ``image_px`` and ``depth_mm`` per landmark, and can be built
    from them (the constructor takes either form).
    """

    def __init__(
        self,
        *,
        name: str,
        camera: Camera,
        tablet_ppi: float,
        tablet_scale: float,
        hand_angle_zero_deg: float,
        hand_angle_sign: int,
        search: dict[str, tuple[float, float]],
        tablet_px: np.ndarray,
        hand_xy_mm: np.ndarray,
        hand_angle_deg: np.ndarray,
        touch_error_px: np.ndarray,
        captures: Sequence[Capture] | None = None,
        touch_landmark: np.ndarray | None = None,
        hand_z_mm: np.ndarray | None = None,
        capture_position_mm: np.ndarray | None = None,
        image_px: np.ndarray | None = None,
        depth_mm: np.ndarray | None = None,
        capture_hand_angle_deg: float | None = None,
        search_preset: str | None = None,
        version: int | None = None,
        source: str | Path | None = None,
    ):
        put = _setter(self)
        put("name", name)
        put("camera", camera)
        put("tablet_ppi", float(tablet_ppi))
        put("tablet_scale", float(tablet_scale))
        put("hand_angle_zero_deg", float(hand_angle_zero_deg))
        sign = hand_angle_sign
        if sign in (1, -1) and not isinstance(sign, bool):
            sign = int(sign)
        put("hand_angle_sign", sign)
        put("search", {str(k): (float(v[0]), float(v[1])) for k, v in search.items()})
        put("search_preset", _checked_preset(search_preset))
        tablet = np.array(tablet_px, dtype=np.float64)
        if tablet.ndim != 2 or tablet.shape[1] != 2:
            raise ValueError(f"tablet_px must have shape (n, 2), got {tablet.shape}")
        n = tablet.shape[0]
        put("tablet_px", tablet)
        if captures is None:
            if any(a is None for a in (capture_position_mm, image_px, depth_mm)):
                raise ValueError("give captures, or capture_position_mm, image_px and depth_mm")
            angle = capture_angle_at_zero(hand_angle_zero_deg, hand_angle_sign)
            if capture_hand_angle_deg is not None:
                angle = float(capture_hand_angle_deg)
            captures = (_single_capture(n, capture_position_mm, angle, image_px, depth_mm),)
        elif any(a is not None for a in (capture_position_mm, image_px, depth_mm)):
            raise ValueError("give captures or the single-capture arrays, not both")
        put("captures", _checked_captures(captures, n))
        touches = _touch_arrays(n, hand_xy_mm, hand_angle_deg, touch_error_px, hand_z_mm,
                                touch_landmark)  # fmt: skip
        for key, a in touches.items():
            put(key, a)
        if version is None:
            version = 1 if self.is_simple() and not self.has_hand_z else 2
        put("version", int(version))
        put("source", None if source is None else Path(source))

    def __setattr__(self, name, value):
        raise dataclasses.FrozenInstanceError(f"cannot assign to field {name!r}")

    #: The fields compared by ``==`` (every one but ``version`` and ``source``).
    FIELDS = (
        "name", "camera", "tablet_ppi", "tablet_scale", "hand_angle_zero_deg",
        "hand_angle_sign", "search", "search_preset", "tablet_px", "captures", "touch_landmark",
        "hand_xy_mm", "hand_z_mm", "hand_angle_deg", "touch_error_px",
    )  # fmt: skip

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Dataset):
            return NotImplemented
        for name in self.FIELDS:
            a, b = getattr(self, name), getattr(other, name)
            if isinstance(a, np.ndarray):
                if not np.array_equal(a, b, equal_nan=True):
                    return False
            elif a != b:
                return False
        return True

    __hash__ = None  # mutable arrays inside: not hashable

    def __repr__(self) -> str:
        return (f"Dataset(name={self.name!r}, landmarks={self.n_landmarks}, "
                f"captures={len(self.captures)}, touches={self.n_touches})")  # fmt: skip

    # -- shape -------------------------------------------------------------------------------
    @property
    def n_landmarks(self) -> int:
        return int(self.tablet_px.shape[0])

    @property
    def n_touches(self) -> int:
        return int(self.hand_xy_mm.shape[0])

    @property
    def n_rows(self) -> int:
        """Rows of :meth:`observations`: the landmarks of a simple dataset, else the views
        of touched landmarks paired with their touches (:meth:`rows`)."""
        if self.is_simple():
            return self.n_landmarks
        return int(self.rows()[0].size)

    @property
    def has_hand_z(self) -> bool:
        """Whether any touch recorded the hand's height."""
        return bool(np.isfinite(self.hand_z_mm).any())

    def is_simple(self) -> bool:
        """One capture seeing every landmark in order, one touch of each in order."""
        n = self.n_landmarks
        if len(self.captures) != 1:
            return False
        c = self.captures[0]
        return np.array_equal(c.landmarks, np.arange(n)) and np.array_equal(
            self.touch_landmark, np.arange(n)
        )

    def _simple(self, what: str) -> Capture:
        if not self.is_simple():
            raise ValueError(
                f"{what} is defined for a single-capture dataset that sees and touches every "
                "landmark in order; use captures and touches"
            )
        return self.captures[0]

    @property
    def capture_position_mm(self) -> np.ndarray:
        """The (only) capture's hand position, mm (single-capture datasets)."""
        if len(self.captures) != 1:
            raise ValueError("capture_position_mm is defined for a single-capture dataset")
        return self.captures[0].hand_position_mm

    @property
    def image_px(self) -> np.ndarray:
        """Each landmark's image point, px (simple datasets)."""
        return self._simple("image_px").image_px

    @property
    def depth_mm(self) -> np.ndarray:
        """Each landmark's depth, mm (simple datasets)."""
        return self._simple("depth_mm").depth_mm

    @property
    def mm_per_tablet_px(self) -> float:
        """Size of one tablet pixel in mm, eq. (9)."""
        return geo.mm_per_tablet_px(self.tablet_ppi, self.tablet_scale)

    # -- arrays for the models ---------------------------------------------------------------
    @in_float64
    def rig(self) -> Rig:
        """The known quantities as JAX arrays (float64), with the first capture's pose (its
        hand angle only when it is not the paper's φ = 0)."""
        c, first = self.camera, self.captures[0]
        angle = None
        if first.hand_angle_deg != capture_angle_at_zero(self.hand_angle_zero_deg,
                                                         self.hand_angle_sign):  # fmt: skip
            angle = first.hand_angle_deg
        return Rig(
            c.fx_px, c.fy_px, c.cx_px, c.cy_px, first.hand_position_mm,
            self.hand_angle_zero_deg, self.hand_angle_sign, angle,
        )  # fmt: skip

    def rows(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The rows of :meth:`observations` for data from several captures: each view of a
        landmark (a capture that sees it) paired with each touch of that landmark, capture
        by capture, touches in order. Returns ``(capture, view, touch)`` indices, ``(r,)``
        each (``view`` indexes the capture's own landmark arrays)."""
        caps, views, touches = [], [], []
        for c, cap in enumerate(self.captures):
            where = {int(m): k for k, m in enumerate(cap.landmarks)}
            for t, m in enumerate(self.touch_landmark):
                if int(m) in where:
                    caps.append(c)
                    views.append(where[int(m)])
                    touches.append(t)
        return (np.asarray(caps, dtype=np.int64), np.asarray(views, dtype=np.int64),
                np.asarray(touches, dtype=np.int64))  # fmt: skip

    @in_float64
    def observations(self) -> Observations:
        """The landmark data as JAX arrays (float64), tablet quantities converted to mm.

        A simple dataset (the paper's) gives one row per landmark, seen from the rig's
        capture pose. Any other gives one row per view of a touched landmark and touch of it
        (:meth:`rows`), each with its capture's pose and its touch's hand z.
        """
        if not self.is_simple() or self.has_hand_z:
            return self._capture_observations()
        cap = self._simple("observations()")
        mm = self.mm_per_tablet_px
        return Observations(
            rig=self.rig(),
            image_px=jnp.asarray(self.camera.undistort(cap.image_px), dtype=float),
            depth_mm=jnp.asarray(cap.depth_mm, dtype=float),
            tablet_mm=jnp.asarray(self.tablet_px * mm, dtype=float),
            hand_xy_mm=jnp.asarray(self.hand_xy_mm, dtype=float),
            hand_angle_deg=jnp.asarray(self.hand_angle_deg, dtype=float),
            touch_error_mm=jnp.asarray(self.touch_error_px * mm, dtype=float),
            centre_index=centre_landmark(self.tablet_px),
            mm_per_tablet_px=jnp.asarray(mm, dtype=float),
        )

    def _capture_observations(self) -> Observations:
        caps, views, touches = self.rows()
        if caps.size == 0:
            raise ValueError("no capture sees a touched landmark: nothing to calibrate")
        mm = self.mm_per_tablet_px
        image = np.stack([self.captures[c].image_px[v] for c, v in zip(caps, views, strict=True)])
        image = self.camera.undistort(image)  # the chain back-projects through a pinhole
        depth = np.array([self.captures[c].depth_mm[v] for c, v in zip(caps, views, strict=True)])
        position = np.stack([self.captures[c].hand_position_mm for c in caps])
        angle = np.array([self.captures[c].hand_angle_deg for c in caps])
        landmark = self.touch_landmark[touches]
        hand_z = self.hand_z_mm[touches]
        centre = centre_landmark(self.tablet_px)
        hits = np.flatnonzero(landmark == centre)
        if hits.size:
            centre_row = int(hits[0])  # the first capture that sees the centre landmark
        else:  # the row whose landmark is drawn nearest the centre one
            d = np.linalg.norm(self.tablet_px[landmark] - self.tablet_px[centre], axis=1)
            centre_row = int(np.argmin(d))
        f = lambda a: jnp.asarray(a, dtype=float)  # noqa: E731
        return Observations(
            rig=self.rig(), image_px=f(image), depth_mm=f(depth),
            tablet_mm=f(self.tablet_px[landmark] * mm), hand_xy_mm=f(self.hand_xy_mm[touches]),
            hand_angle_deg=f(self.hand_angle_deg[touches]),
            touch_error_mm=f(self.touch_error_px[touches] * mm), centre_index=centre_row,
            capture_position_mm=f(position), capture_hand_angle_deg=f(angle),
            hand_z_mm=f(hand_z) if np.isfinite(hand_z).any() else None,
            capture_index=jnp.asarray(caps),
            touch_index=jnp.asarray(touches), mm_per_tablet_px=jnp.asarray(mm, dtype=float),
        )  # fmt: skip

    # -- copies ----------------------------------------------------------------------------
    def _kwargs(self) -> dict[str, Any]:
        return {name: getattr(self, name) for name in self.FIELDS} | {
            "version": self.version, "source": self.source,
        }  # fmt: skip

    def replace(self, **changes: Any) -> Dataset:
        """A copy with some fields changed. For a simple dataset the per-landmark arrays
        (``image_px``, ``depth_mm``, ``capture_position_mm``, ``tablet_px``, …) may be
        changed too, together with the same number of rows."""
        kwargs = self._kwargs()
        simple_keys = {"image_px", "depth_mm", "capture_position_mm", "capture_hand_angle_deg"}
        if simple_keys & changes.keys() or (
            self.is_simple() and "tablet_px" in changes and "captures" not in changes
        ):
            cap = self._simple("replace(image_px=...)")
            kwargs.pop("captures")
            kwargs.pop("touch_landmark")
            if not self.has_hand_z:
                kwargs.pop("hand_z_mm")  # all unrecorded: as many as the new touches
            kwargs["capture_position_mm"] = cap.hand_position_mm
            kwargs["image_px"] = cap.image_px
            kwargs["depth_mm"] = cap.depth_mm
            at_zero = capture_angle_at_zero(self.hand_angle_zero_deg, self.hand_angle_sign)
            if cap.hand_angle_deg != at_zero:  # else φ = 0 under whatever convention is given
                kwargs["capture_hand_angle_deg"] = cap.hand_angle_deg
        kwargs.update(changes)
        if "version" not in changes:
            kwargs["version"] = None  # the new content decides
            if self.version == 2:
                kwargs["version"] = 2
        return Dataset(**kwargs)

    def landmark_subset(self, idx: Sequence[int]) -> Dataset:
        """The dataset of landmarks ``idx`` alone: their captures' views and their touches."""
        idx = np.asarray(idx, dtype=np.int64)
        new_of = {int(old): new for new, old in enumerate(idx)}
        caps = []
        for c in self.captures:
            keep = np.array([int(m) in new_of for m in c.landmarks], dtype=bool)
            caps.append(Capture(c.hand_position_mm, c.hand_angle_deg,
                                [new_of[int(m)] for m in c.landmarks[keep]], c.image_px[keep],
                                c.depth_mm[keep]))  # fmt: skip
        t = np.array([int(m) in new_of for m in self.touch_landmark], dtype=bool)
        kwargs = self._kwargs()
        kwargs.update(
            tablet_px=self.tablet_px[idx], captures=caps,
            touch_landmark=[new_of[int(m)] for m in self.touch_landmark[t]],
            hand_xy_mm=self.hand_xy_mm[t], hand_z_mm=self.hand_z_mm[t],
            hand_angle_deg=self.hand_angle_deg[t], touch_error_px=self.touch_error_px[t],
            version=None if self.version == 1 else 2,
        )  # fmt: skip
        return Dataset(**kwargs)


# -- checks ------------------------------------------------------------------------------------


def check_distinct(tablet_px: Any, path: str | Path | None) -> None:
    """Two landmarks drawn at the same place are one landmark measured twice: reject."""
    first: dict[tuple[float, float], int] = {}
    for j, xy in enumerate(np.asarray(tablet_px, dtype=np.float64).reshape(-1, 2)):
        key = (float(xy[0]), float(xy[1]))
        if key in first:
            raise InputError(
                path, f"landmarks[{j}].tablet_px",
                f"duplicates landmarks[{first[key]}] (both at [{key[0]}, {key[1]}])",
            )  # fmt: skip
        first[key] = j


def check_population(ds: Dataset, population: int, path: str | Path | None = None) -> None:
    """Raise :class:`InputError` if DE with ``population`` members on ``ds`` would need more
    memory than a machine has: population x landmarks at most 10^8 (about 5 GB)."""
    path = ds.source if path is None else path
    n = max(ds.n_landmarks, sum(len(c.landmarks) for c in ds.captures), ds.n_touches)
    if population * n > MAX_MEMBER_LANDMARKS:
        most = MAX_MEMBER_LANDMARKS // n
        raise InputError(
            path, "landmarks",
            f"{n:,} landmarks with a DE population of {population:,} need about "
            f"{population * n * 48 / 1e9:.0f} GB; use a population of at most "
            f"{most:,} (population x landmarks <= {MAX_MEMBER_LANDMARKS:,})",
        )  # fmt: skip
