"""The synthetic twin: every input the real rig produces, from a rig whose truth is known.

:func:`simulate` takes a :class:`~handeye_jax.twin.TwinTruth` and a :class:`NoisePreset` and
makes what the rig would: the picture of the tablet and its depth image
(:mod:`~handeye_jax.twin._render`), the landmarks found in them
(:mod:`~handeye_jax.vision._detect`), the touches (operator error, the tablet's report of it,
the controller's hand positions), and held-out targets for :mod:`~handeye_jax.twin._evaluate`.
:func:`write_twin` writes them to a folder:

``dataset.toml``  the core format, ``image_px`` and ``depth`` from the detector (or exact)
``capture.png``   the colour picture, 8-bit BGR
``depth.png``     the depth image, 16-bit, mm (0 = no measurement)
``truth.json``    the rig truth (:func:`~handeye_jax.twin.load_truth` reads it back)
``heldout.csv``   held-out targets: ``u,v,depth,hand_angle`` as measured (px, px, mm, deg)
                  and where they are drawn, ``tablet_x,tablet_y`` (tablet px)

It writes into a new or empty folder only: with ``force=True`` it replaces an old twin's
files and removes what the loop of docs/twin.md made from them (:data:`DERIVED_FILES`), so
nothing stale is left beside the new twin.
"""

from __future__ import annotations

import io
import numbers
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np
from numpy.typing import ArrayLike

from .._core import (
    BOOTSTRAP_FIGURE,
    CAPTURE_RISE_MM,
    DERIVED_FILES,
    DERIVED_FOLDER,
    HELDOUT_ABOVE_MM,
    HELDOUT_RISES_MM,
    MAX_HELDOUT,
    MORE_CAPTURE_FILES,
    REPORT_FIGURES,
    REPORT_FORMATS,
    InputError,
    reason,
    write_folder_atomic,
)
from .._core import MAX_TWIN_CAPTURES as MAX_CAPTURES
from .._core import TWIN_SEED_RANGE as SEED_RANGE
from ..data import Capture, Dataset, dataset_to_toml
from ..vision import BlobCountError, DetectSettings, depth_at, find_blobs, order_blobs
from ._render import DepthSensing, Imaging, render_capture, render_depth
from ._synthetic import synthesize_dataset
from ._truth import TwinTruth
from ._wide import aimed_position, capture_distance_mm

HELDOUT_HEADER = ("u", "v", "depth", "hand_angle", "tablet_x", "tablet_y")
#: A multi-capture twin's held-out targets also carry the capture pose they were seen from
#: (mm, deg), their true position (base frame, mm), and how far above the display they stand.
HELDOUT_CAPTURE_HEADER = (*HELDOUT_HEADER, "capture_x", "capture_y", "capture_z",
                          "capture_angle", "true_x", "true_y", "true_z", "above_mm")  # fmt: skip


@dataclass(frozen=True)
class NoisePreset:
    """How far the twin's measurements stray from the truth.

    Attributes:
        name: the preset's name.
        imaging: the picture's blur, noise, vignetting and gamma.
        depth: the depth image's noise, quantisation and holes.
        touch_sigma_mm: σ of the operator's touch error in each tablet axis, mm.
        hand_round_mm: the controller reports hand positions rounded to this, mm (0 = exact).
        target_sigma_px: σ of the image position of a held-out target as the user measures
            it, per axis, image px (about the detector's own error).
    """

    name: str
    imaging: Imaging
    depth: DepthSensing
    touch_sigma_mm: float
    hand_round_mm: float
    target_sigma_px: float


PRESETS: dict[str, NoisePreset] = {
    "none": NoisePreset(
        "none", Imaging(), DepthSensing(),
        touch_sigma_mm=0.0, hand_round_mm=0.0, target_sigma_px=0.0,
    ),
    # Table 2's spread: touch errors of a few tablet px (σ ≈ 2.4 px ≈ 0.45 mm), hand positions
    # in whole mm; a fair 8-bit sRGB camera and a RealSense-like depth image.
    "paper": NoisePreset(
        "paper",
        Imaging(blur_px=0.0, noise_levels=1.5, vignetting=0.15, gamma=2.2),
        DepthSensing(noise_mm=0.5, step_mm=1.0, holes=0.02),
        touch_sigma_mm=0.45, hand_round_mm=1.0, target_sigma_px=0.15,
    ),
    # Defocus, a noisy sensor, coarse depth with many holes, a careless operator. One-pixel
    # dots drown in this picture's noise: simulate it with larger dots (dot_px >= 2).
    "harsh": NoisePreset(
        "harsh",
        Imaging(blur_px=0.4, noise_levels=3.0, vignetting=0.35, gamma=2.2),
        DepthSensing(noise_mm=1.5, step_mm=2.0, holes=0.10),
        touch_sigma_mm=1.0, hand_round_mm=1.0, target_sigma_px=0.3,
    ),
}  # fmt: skip


@dataclass(frozen=True)
class Twin:
    """Everything the twin made.

    Attributes:
        truth: the rig truth.
        preset: the noise preset.
        dataset: the calibration dataset, as the rig would record it.
        capture: the colour picture, ``uint8`` BGR ``(h, w, 3)``.
        depth: the depth image, ``uint16`` mm ``(h, w)``.
        landmarks_image_px, landmarks_depth_mm: the landmarks' true image points and depths.
        heldout_tablet_px: held-out targets on the display, tablet px, ``(k, 2)``.
        heldout_hand_angle_deg: the hand angle to touch each with, deg, ``(k,)``.
        heldout_image_px, heldout_depth_mm: each target as the user measures it (image px,
            mm): its true image point plus ``target_sigma_px`` noise, and the depth image's
            median around it.
        more_captures, more_depths: the pictures and depth images of captures 2, 3, … of a
            multi-capture twin.
        heldout_capture_position_mm, heldout_capture_angle_deg: the capture pose each
            held-out target was seen from (mm ``(k, 3)``, deg ``(k,)``), multi-capture only.
        heldout_true_mm: each target's true position, base frame, mm, ``(k, 3)``.
        heldout_above_mm: how far above the display each target stands, mm, ``(k,)``.
    """

    truth: TwinTruth
    preset: NoisePreset
    dataset: Dataset
    capture: np.ndarray
    depth: np.ndarray
    landmarks_image_px: np.ndarray
    landmarks_depth_mm: np.ndarray
    heldout_tablet_px: np.ndarray
    heldout_hand_angle_deg: np.ndarray
    heldout_image_px: np.ndarray
    heldout_depth_mm: np.ndarray
    more_captures: tuple[np.ndarray, ...] = ()
    more_depths: tuple[np.ndarray, ...] = ()
    heldout_capture_position_mm: np.ndarray | None = None
    heldout_capture_angle_deg: np.ndarray | None = None
    heldout_true_mm: np.ndarray | None = None
    heldout_above_mm: np.ndarray | None = None

    @property
    def n_captures(self) -> int:
        return 1 + len(self.more_captures)


def simulate(
    truth: TwinTruth,
    preset: NoisePreset,
    seed: int,
    *,
    captures: int | Sequence[tuple[ArrayLike, float]] = 1,
    exact: bool = False,
    n_heldout: int = 20,
    detect_settings: DetectSettings | None = None,
    aim: bool = False,
) -> Twin:
    """Run the twin once.

    With ``captures > 1``, or capture poses, the acquisition holds several pictures from
    capture poses at other heights, positions and hand angles; the touches record the hand's
    height (rounded as the hand's x-y), and ``n_heldout`` held-out targets are drawn for each
    capture rise of :data:`HELDOUT_RISES_MM` and each height of :data:`HELDOUT_ABOVE_MM` above
    the display. A held-out target above the display is the top of an object standing there,
    parallel to the display; its depth image is rendered with the object's top as the surface.

    Args:
        truth: the rig truth.
        preset: the noise preset.
        seed: seeds every random draw here (noise, touches, held-out targets).
        captures: how many pictures (1 to 8; the further ones from the poses of
            :func:`draw_capture_poses`), or their poses: (hand position mm, hand angle deg)
            each.
        exact: take ``image_px`` and depth from the truth instead of detecting them (the
            held-out targets' too).
        n_heldout: how many held-out targets (1 to 10,000; of each rise and height with
            several captures), uniform over the landmarks' area on the display with hand
            angles uniform in [0, 180) deg.
        detect_settings: how to detect the landmarks.
        aim: point the further captures' cameras at the landmarks (a wide rig's; see
            :func:`draw_capture_poses`).

    Raises:
        BlobCountError: the detector does not find one blob per landmark in the picture.
        ValueError: ``seed`` is negative or ``n_heldout`` out of range.
    """
    check_seed(seed)
    if not 1 <= n_heldout <= MAX_HELDOUT:
        raise ValueError(f"n_heldout must be 1 to {MAX_HELDOUT:,} (got {n_heldout})")
    count = int(captures) if isinstance(captures, numbers.Integral) else len(captures)
    if not 1 <= count <= MAX_CAPTURES:
        raise ValueError(f"captures must be 1 to {MAX_CAPTURES} (got {count})")
    draw = _Draw(exact, n_heldout, detect_settings or DetectSettings(), aim)
    if count > 1 or not isinstance(captures, numbers.Integral):
        return _simulate_captures(truth, preset, seed, captures, draw)
    rng_image, rng_depth, rng_touch, rng_held = np.random.default_rng(seed).spawn(4)
    capture = render_capture(truth, preset.imaging, rng_image)
    depth = render_depth(truth, preset.depth, rng_depth)
    exact_ds, touch_px = _touched(truth, preset, seed, rng_touch)
    if truth.distortion is not None:  # the lens moves every point of the picture
        exact_ds = exact_ds.replace(camera=truth.camera(), image_px=truth.project(
            truth.landmarks_tablet_px)[0])  # fmt: skip
    hand_xy = exact_ds.hand_xy_mm
    if preset.hand_round_mm:
        hand_xy = np.round(hand_xy / preset.hand_round_mm) * preset.hand_round_mm
    if exact:
        image_px, depth_mm = exact_ds.image_px, exact_ds.depth_mm
    else:
        image_px, depth_mm = _detected(truth, capture, depth, draw.settings)
    dataset = exact_ds.replace(
        image_px=image_px, depth_mm=depth_mm, hand_xy_mm=hand_xy,
        touch_error_px=np.round(touch_px),  # the tablet reports whole px
    )  # fmt: skip
    held = _heldout(truth, preset.target_sigma_px, (depth, draw.settings), rng_held, n_heldout)
    return Twin(
        truth=truth, preset=preset, dataset=dataset, capture=capture, depth=depth,
        landmarks_image_px=exact_ds.image_px, landmarks_depth_mm=exact_ds.depth_mm,
        heldout_tablet_px=held[0], heldout_hand_angle_deg=held[1],
        heldout_image_px=held[2], heldout_depth_mm=held[3],
    )  # fmt: skip


def _heldout(truth: TwinTruth, sigma_px: float, depth_reading: tuple, rng: np.random.Generator,
             n: int) -> tuple[np.ndarray, ...]:  # fmt: skip
    """``n`` held-out targets uniform over the landmarks' area on the display: their tablet
    px, hand angles (deg), image points seen with ``sigma_px`` of noise (px) and depths read
    from the depth image (``depth_reading``: the image and the detector's settings), mm."""
    depth, settings = depth_reading
    lo, hi = truth.landmark_area_px()
    held_px = rng.uniform(lo, hi, (n, 2))
    held_angle = rng.uniform(0.0, 180.0, n)
    held_true_px, _ = truth.project(held_px)
    held_image_px = held_true_px + rng.normal(0.0, 1.0, held_true_px.shape) * sigma_px
    return held_px, held_angle, held_image_px, depth_at(depth, held_image_px,
                                                         settings.depth_window_px)  # fmt: skip


def _touched(truth: TwinTruth, preset: NoisePreset, seed: int,
             rng: np.random.Generator) -> tuple[Dataset, np.ndarray]:  # fmt: skip
    """The exact dataset of the truth's single capture, the pen touching where the operator's
    error (drawn from ``rng``) put it, and that error, tablet px (exact, not rounded)."""
    rig, model, mm = truth.rig(), truth.htm(), truth.mm_per_tablet_px
    n = len(truth.landmarks_tablet_px)
    touch_px = rng.normal(0.0, preset.touch_sigma_mm, (n, 2)) / mm
    exact = synthesize_dataset(
        model, rig, truth.landmarks_tablet_px, truth.landmarks_hand_angle_deg,
        scene=truth.scene(), touch_error_px=touch_px,
    ).replace(name=f"twin-seed{seed}-{preset.name}")  # fmt: skip
    return exact, touch_px


def _detected(truth: TwinTruth, capture: np.ndarray, depth: np.ndarray,
              settings: DetectSettings) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The landmarks found in the rendered picture, in landmark order, px, and their depths
    read from the rendered depth image, mm; :class:`BlobCountError` if not one per landmark."""
    n = len(truth.landmarks_tablet_px)
    blobs = find_blobs(capture, settings)
    if len(blobs.image_px) != n:
        hint = "; try exact=True (simulate --exact) or larger dots (--dot-px)"
        raise BlobCountError("capture.png (simulated)", blobs, n, hint)
    image_px = blobs.image_px[order_blobs(blobs.image_px, truth.landmarks_tablet_px)]
    return image_px, depth_at(depth, image_px, settings.depth_window_px)


def draw_capture_poses(
    truth: TwinTruth, k: int, rng: np.random.Generator, rise_mm: float = CAPTURE_RISE_MM,
    *, aim: bool = False,
) -> list[tuple[np.ndarray, float]]:  # fmt: skip
    """``k`` capture poses ``(hand position mm, hand angle deg)`` that see every landmark.

    The first is the truth's own. The others rise evenly to ``rise_mm`` above it (±5 mm),
    move up to 15 mm sideways, and turn the hand by 8 to 25 deg either way. With ``aim`` (a
    wide rig's camera, far off the flange axis and tilted, swings out of view as the hand
    turns), or when 1,000 such draws all lose a landmark, each pose instead points the
    camera at the landmarks' centre from that much further away (:func:`aimed_position`),
    moved up to 15 mm sideways.
    """
    first = np.asarray(truth.capture_position_mm, dtype=float)
    angle0 = truth.capture_angle_deg
    poses = [(first, angle0)]
    distance0 = capture_distance_mm(truth) if aim else None
    for rise in np.linspace(0.0, rise_mm, k)[1:]:
        for attempt in range(1000 if aim else 2000):
            shift, up = rng.uniform(-15.0, 15.0, 2), rise + rng.uniform(-5.0, 5.0)
            angle = angle0 + rng.choice([-1.0, 1.0]) * rng.uniform(8.0, 25.0)
            if aim or attempt >= 1000:
                distance0 = capture_distance_mm(truth) if distance0 is None else distance0
                position = aimed_position(truth, angle, distance0 + up, tuple(shift))
            else:
                position = first + [*shift, up]
            if truth.at_capture(position, angle).sees(truth.landmarks_tablet_px):
                break
        else:
            raise ValueError("could not draw a capture pose that sees every landmark")
        poses.append((position, float(angle)))
    return poses


def _pictures(
    truth_c: TwinTruth,
    preset: NoisePreset,
    rng: np.random.Generator,
    exact: bool,
    settings: DetectSettings,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One capture's picture, depth image, and the landmarks' image points and depths in
    them (detected, or the truth's with ``exact``)."""
    picture = render_capture(truth_c, preset.imaging, rng)
    depth = render_depth(truth_c, preset.depth, rng)
    if exact:
        image_px, depth_mm = truth_c.project(truth_c.landmarks_tablet_px)
        return picture, depth, image_px, depth_mm
    return picture, depth, *_detected(truth_c, picture, depth, settings)


@dataclass(frozen=True)
class _Draw:
    """How a twin's pictures are read and its held-out targets drawn (see :func:`simulate`)."""

    exact: bool
    n_heldout: int
    settings: DetectSettings
    aim: bool


def _simulate_captures(
    truth: TwinTruth,
    preset: NoisePreset,
    seed: int,
    captures: int | Sequence[tuple[ArrayLike, float]],
    draw: _Draw,
) -> Twin:
    """:func:`simulate` of several captures (a count, or their poses)."""
    exact, settings = draw.exact, draw.settings
    rng_pose, rng_image, rng_touch, rng_held = np.random.default_rng(seed).spawn(4)
    if isinstance(captures, numbers.Integral):
        poses = draw_capture_poses(truth, int(captures), rng_pose, aim=draw.aim)
    else:
        poses, captures = [(np.asarray(p, float), float(a)) for p, a in captures], len(captures)
    shots = [_pictures(truth.at_capture(p, a), preset, rng_image, exact, settings)
             for p, a in poses]  # fmt: skip
    mm = truth.mm_per_tablet_px
    n = len(truth.landmarks_tablet_px)
    touch_px = rng_touch.normal(0.0, preset.touch_sigma_mm, (n, 2)) / mm
    touched = truth.surface_points(truth.landmarks_tablet_px + touch_px)
    hand = truth.true_command(touched, truth.landmarks_hand_angle_deg)
    if preset.hand_round_mm:
        hand = np.round(hand / preset.hand_round_mm) * preset.hand_round_mm
    caps = [Capture(p, a, np.arange(n), image_px, depth_mm)
            for (p, a), (_, _, image_px, depth_mm) in zip(poses, shots, strict=True)]  # fmt: skip
    dataset = Dataset(
        name=f"twin-seed{seed}-{preset.name}-{captures}captures",
        camera=truth.camera(), tablet_ppi=truth.ppi,
        tablet_scale=truth.scale, hand_angle_zero_deg=truth.hand_angle_zero_deg,
        hand_angle_sign=truth.hand_angle_sign, search={}, tablet_px=truth.landmarks_tablet_px,
        captures=caps, hand_xy_mm=hand[:, :2], hand_z_mm=hand[:, 2],
        hand_angle_deg=truth.landmarks_hand_angle_deg, touch_error_px=np.round(touch_px),
        version=2,
    )  # fmt: skip
    held = heldout_targets(truth, preset, rng_held, HeldoutLevels(draw.n_heldout), exact=exact,
                           settings=settings, aim=draw.aim)  # fmt: skip
    first_px, first_depth = truth.project(truth.landmarks_tablet_px)
    return Twin(
        truth=truth, preset=preset, dataset=dataset, capture=shots[0][0], depth=shots[0][1],
        landmarks_image_px=first_px, landmarks_depth_mm=first_depth,
        more_captures=tuple(s[0] for s in shots[1:]), more_depths=tuple(s[1] for s in shots[1:]),
        **held,
    )  # fmt: skip


@dataclass(frozen=True)
class HeldoutLevels:
    """Where a multi-capture twin's held-out targets are drawn: ``n_each`` targets for each
    capture rise and each height above the display (every rise with every height).

    Attributes:
        n_each: targets of each rise and height, 1 to 10,000.
        rises_mm: capture rises, mm above the truth's capture: 0 is that capture, any other
            a new position and hand angle that much higher. Finite, at least one.
        above_mm: heights above the display, mm: 0 is on it, any other the top of an object
            standing there. Finite and >= 0, at least one.
    """

    n_each: int
    rises_mm: tuple[float, ...] = HELDOUT_RISES_MM
    above_mm: tuple[float, ...] = HELDOUT_ABOVE_MM

    def __post_init__(self) -> None:
        if isinstance(self.n_each, bool) or not isinstance(self.n_each, numbers.Integral) or \
                not 1 <= self.n_each <= MAX_HELDOUT:  # fmt: skip
            raise ValueError(f"n_each: must be a whole number 1 to {MAX_HELDOUT:,} "
                             f"(got {self.n_each!r})")  # fmt: skip
        for name in ("rises_mm", "above_mm"):
            values = tuple(float(v) for v in np.atleast_1d(getattr(self, name)))
            if not values or not np.isfinite(values).all():
                raise ValueError(f"{name}: must be one or more finite numbers, mm (got "
                                 f"{getattr(self, name)!r})")  # fmt: skip
            object.__setattr__(self, name, values)
        if min(self.above_mm) < 0:
            raise ValueError(f"above_mm: must be >= 0 mm: below the display is inside the "
                             f"tablet (got {self.above_mm})")  # fmt: skip


def heldout_targets(
    truth: TwinTruth,
    preset: NoisePreset,
    rng: np.random.Generator,
    levels: HeldoutLevels,
    *,
    exact: bool = False,
    settings: DetectSettings | None = None,
    aim: bool = False,
) -> dict[str, np.ndarray]:
    """Held-out targets for each capture rise and each height above the display of
    ``levels``, ``levels.n_each`` of each, uniform over the landmarks' area where the picture
    sees them; as :class:`Twin`'s ``heldout_*`` fields.

    Args:
        truth: the rig truth.
        preset: the noise preset (the targets' image noise, the depth images').
        rng: draws the new poses, the targets and their noise.
        levels: how many targets, from which capture rises and at which heights, mm.
        exact: take the targets' image points and depths from the truth.
        settings: how depths are read from the depth image (its window).
        aim: point the camera of a new pose at the landmarks (:func:`aimed_position`), as it
            is anyway when the picture from the new pose sees too little.
    """
    draw = _Draw(exact, levels.n_each, settings or DetectSettings(), aim)
    groups = []
    for rise in levels.rises_mm:
        pose = _heldout_pose(truth, rng, rise, aim)
        for above in levels.above_mm:
            pose, group = _heldout_group(truth, preset, rng, pose, above, draw)
            groups.append(group)
    cat = [np.concatenate(column) for column in zip(*groups, strict=True)]
    names = ("tablet_px", "hand_angle_deg", "image_px", "depth_mm", "capture_position_mm",
             "capture_angle_deg", "true_mm", "above_mm")  # fmt: skip
    return {f"heldout_{n}": c for n, c in zip(names, cat, strict=True)}


class _Pose(NamedTuple):
    position: np.ndarray  # hand position, mm
    angle: float  # hand angle, deg
    aimed: np.ndarray | None  # the position pointing the camera at the landmarks, mm


def _heldout_pose(truth: TwinTruth, rng: np.random.Generator, rise: float, aim: bool) -> _Pose:
    """The pose held-out targets are seen from, ``rise`` mm above the truth's capture (0:
    that capture; any other: a new position and hand angle, or with ``aim`` the one pointing
    the camera at the landmarks)."""
    first = np.asarray(truth.capture_position_mm, dtype=float)
    if not rise:
        return _Pose(first, truth.capture_angle_deg, None)
    shift = rng.uniform(-15.0, 15.0, 2)
    angle = truth.capture_angle_deg + rng.choice([-1.0, 1.0]) * rng.uniform(10.0, 30.0)
    # A wide rig's camera swings away as the hand turns: pointed at the landmarks.
    aimed = aimed_position(truth, angle, capture_distance_mm(truth) + rise, (shift[0], shift[1]))
    return _Pose(aimed if aim else first + [*shift, rise], angle, aimed)


def _heldout_group(truth: TwinTruth, preset: NoisePreset, rng: np.random.Generator,
                   pose: _Pose, above: float, draw: _Draw) -> tuple[_Pose, tuple]:  # fmt: skip
    """``draw.n_heldout`` targets ``above`` mm above the display seen from ``pose`` (from its
    aimed position if the picture sees too little): the pose used, and the targets' tablet px,
    hand angles, image points, depths, capture positions and angles, true points and heights."""
    lo, hi = truth.landmark_area_px()

    def look(position):
        seen = replace(truth.at_capture(position, pose.angle),
                       tablet_height_mm=truth.tablet_height_mm + above)  # fmt: skip
        depth_image = None if draw.exact else render_depth(seen, preset.depth, rng)
        return seen, depth_image, _seen_targets(seen, lo, hi, draw.n_heldout, rng)

    seen, depth_image, tab = look(pose.position)
    if tab is None and pose.aimed is not None and pose.position is not pose.aimed:
        pose = pose._replace(position=pose.aimed)
        seen, depth_image, tab = look(pose.position)
    if tab is None:
        raise ValueError("the picture sees too little of the landmarks' area")
    true_px, true_depth = seen.project(tab)
    image_px = true_px + rng.normal(0.0, 1.0, true_px.shape) * preset.target_sigma_px
    depth = true_depth if draw.exact else depth_at(depth_image, image_px,
                                                   draw.settings.depth_window_px)  # fmt: skip
    if draw.exact:
        image_px = true_px
    k = len(tab)
    return pose, (tab, rng.uniform(0.0, 180.0, k), image_px, depth,
                  np.tile(pose.position, (k, 1)), np.full(k, float(pose.angle)),
                  truth.surface_points(tab, above), np.full(k, float(above)))  # fmt: skip


def _seen_targets(seen: TwinTruth, lo, hi, n: int, rng: np.random.Generator) -> np.ndarray | None:
    """``n`` targets uniform over ``[lo, hi]`` (tablet px) that the picture sees, or ``None``
    when 1,000 draws do not find them."""
    tab = np.empty((0, 2))
    for _ in range(1000):
        cand = rng.uniform(lo, hi, (n, 2))
        seen_now = np.array([p for p in cand if seen.sees(p[None])]).reshape(-1, 2)
        tab = np.vstack([tab, seen_now])[:n]  # none seen this round: (0, 2), not (0,)
        if len(tab) == n:
            return tab
    return None


def check_seed(seed: int) -> int:
    """``seed`` if numpy's generators take it (0 to 2^63 - 1); ``ValueError`` if not."""
    lo, hi = SEED_RANGE
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or not lo <= seed <= hi:
        raise ValueError(f"seed must be a whole number from 0 to 2^63 - 1 (got {seed!r})")
    return int(seed)


def heldout_csv_text(twin: Twin) -> str:
    """The held-out targets as ``u,v,depth,hand_angle,tablet_x,tablet_y`` (px, px, mm, deg, px);
    a multi-capture twin's also with :data:`HELDOUT_CAPTURE_HEADER`'s capture pose (mm, deg),
    true position (mm) and height above the display (mm)."""
    out = io.StringIO()
    columns = [twin.heldout_image_px, twin.heldout_depth_mm, twin.heldout_hand_angle_deg,
               twin.heldout_tablet_px]  # fmt: skip
    header = HELDOUT_HEADER
    if twin.heldout_true_mm is not None:
        header = HELDOUT_CAPTURE_HEADER
        columns += [twin.heldout_capture_position_mm, twin.heldout_capture_angle_deg,
                    twin.heldout_true_mm, twin.heldout_above_mm]  # fmt: skip
    out.write(",".join(header) + "\n")
    rows = np.column_stack(columns)
    for row in rows:
        out.write(",".join(repr(float(v)) for v in row) + "\n")
    return out.getvalue()


def encode_png(image: np.ndarray) -> bytes:
    """PNG bytes of a ``uint8`` or ``uint16`` image (OpenCV keeps 16 bits)."""
    ok, buf = cv2.imencode(".png", image)
    if not ok:
        raise ValueError("OpenCV could not encode the image as PNG")
    return buf.tobytes()


def check_twin_folder(out_dir: str | Path, force: bool = False, field: str = "") -> list[Path]:
    """Refuse to write a twin into a folder that holds anything, unless ``force``.

    Returns the stale files :func:`write_twin` with ``force`` removes once the new twin is in
    place: :data:`DERIVED_FILES` and the figures of ``result_report/``. Raises
    :class:`~handeye_jax._core.InputError` naming ``out_dir`` and ``field``.
    """
    folder = Path(out_dir)
    try:
        held = sorted(p.name for p in folder.iterdir()) if folder.is_dir() else []
    except OSError as e:
        raise InputError(folder, field, f"cannot list the folder: {reason(e)}") from None
    if held and not force:
        shown = ", ".join(held[:4]) + (f" and {len(held) - 4} more" if len(held) > 4 else "")
        raise InputError(
            folder, field,
            f"not empty (holds {shown}); a twin is written into a new or empty folder: choose "
            f"another, or pass --force to replace the old twin's files and remove "
            f"{', '.join(DERIVED_FILES)} and {DERIVED_FOLDER}/ made from it",
        )  # fmt: skip
    stale = [p for pattern in (*DERIVED_FILES, *MORE_CAPTURE_FILES)
             for p in sorted(folder.glob(pattern))]  # fmt: skip
    figures = folder / DERIVED_FOLDER
    stale += [figures / f"{name}.{ext}" for name in (*REPORT_FIGURES, BOOTSTRAP_FIGURE)
              for ext in REPORT_FORMATS]  # fmt: skip
    return [p for p in stale if p.is_file() or p.is_symlink()]


def _remove(paths: list[Path], field: str) -> None:
    for path in paths:
        try:
            path.unlink()
        except FileNotFoundError:
            pass
        except OSError as e:
            why = f"cannot remove this stale file (the new twin is written): {reason(e)}"
            raise InputError(path, field, why) from None
    for folder in {p.parent for p in paths if p.parent.name == DERIVED_FOLDER}:
        try:
            folder.rmdir()
        except OSError:  # it holds files of the user's: they stay
            pass


def write_twin(
    twin: Twin, out_dir: str | Path, *, force: bool = False, field: str = ""
) -> list[Path]:
    """Write the twin's files into ``out_dir`` (created if missing); returns their paths.

    ``out_dir`` must be new or empty unless ``force``: then the old twin's files are
    replaced and, once the new ones are in place, what was made from them
    (:func:`check_twin_folder`) is removed; other files are left as they are.

    Every file is encoded before the first is written, and all are put in place together:
    on failure (an :class:`~handeye_jax._core.InputError` naming the file and ``field``)
    the folder is as it was.
    """
    stale = check_twin_folder(out_dir, force, field)
    files = {
        "dataset.toml": dataset_to_toml(twin.dataset).encode("utf-8"),
        "truth.json": twin.truth.to_json().encode("utf-8"),
        "heldout.csv": heldout_csv_text(twin).encode("utf-8"),
        "capture.png": encode_png(twin.capture),
        "depth.png": encode_png(twin.depth),
    }
    # Captures 2, 3, … of a multi-capture twin (the dataset's captures in order).
    for i, (picture, depth) in enumerate(zip(twin.more_captures, twin.more_depths,
                                             strict=True), start=1):  # fmt: skip
        files[f"capture_{i}.png"] = encode_png(picture)
        files[f"depth_{i}.png"] = encode_png(depth)
    paths = write_folder_atomic(out_dir, files, field)
    _remove([p for p in stale if p.name not in files], field)
    return paths
