"""The synthetic twin: every input the real rig produces, from a rig whose truth is known.

:func:`simulate` takes a :class:`~handeye_jax._twin.TwinTruth` and a :class:`NoisePreset` and
makes what the rig would: the picture of the tablet and its depth image
(:mod:`~handeye_jax._render`), the landmarks found in them (:mod:`~handeye_jax._detect`), the
touches (operator error, the tablet's report of it, the controller's hand positions), and
held-out targets for :mod:`~handeye_jax._evaluate`. :func:`write_twin` writes them to a folder:

``dataset.toml``  the core format, ``image_px`` and ``depth`` from the detector (or exact)
``capture.png``   the colour picture, 8-bit BGR
``depth.png``     the depth image, 16-bit, mm (0 = no measurement)
``truth.json``    the rig truth (:func:`~handeye_jax._twin.load_truth` reads it back)
``heldout.csv``   held-out targets: ``u,v,depth,hand_angle`` as measured (px, px, mm, deg)
                  and where they are drawn, ``tablet_x,tablet_y`` (tablet px)

It writes into a new or empty folder only: with ``force=True`` it replaces an old twin's
files and removes what the README's loop made from them (:data:`DERIVED_FILES`), so nothing
stale is left beside the new twin.
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ._atomic import reason, write_folder_atomic
from ._constants import DERIVED_FILES, DERIVED_FOLDER
from ._constants import TWIN_SEED_RANGE as SEED_RANGE
from ._dataset import Dataset
from ._dataset_io import dataset_to_toml
from ._detect import BlobCountError, DetectSettings, depth_at, find_blobs, order_blobs
from ._errors import InputError
from ._render import DepthSensing, Imaging, render_capture, render_depth
from ._report import FIGURES, FORMATS
from ._synthetic import synthesize_dataset
from ._twin import TwinTruth
from ._validate import MAX_HELDOUT

HELDOUT_HEADER = ("u", "v", "depth", "hand_angle", "tablet_x", "tablet_y")


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


def simulate(
    truth: TwinTruth,
    preset: NoisePreset,
    seed: int,
    *,
    exact: bool = False,
    n_heldout: int = 20,
    detect_settings: DetectSettings | None = None,
) -> Twin:
    """Run the twin once.

    Args:
        truth: the rig truth.
        preset: the noise preset.
        seed: seeds every random draw here (noise, touches, held-out targets).
        exact: take ``image_px`` and depth from the truth instead of detecting them.
        n_heldout: how many held-out targets (1 to 10,000), uniform over the landmarks' area
            on the display with hand angles uniform in [0, 180) deg.
        detect_settings: how to detect the landmarks.

    Raises:
        BlobCountError: the detector does not find one blob per landmark in the picture.
        ValueError: ``seed`` is negative or ``n_heldout`` out of range.
    """
    check_seed(seed)
    if not 1 <= n_heldout <= MAX_HELDOUT:
        raise ValueError(f"n_heldout must be 1 to {MAX_HELDOUT:,} (got {n_heldout})")
    detect_settings = detect_settings or DetectSettings()
    rng_image, rng_depth, rng_touch, rng_held = np.random.default_rng(seed).spawn(4)
    capture = render_capture(truth, preset.imaging, rng_image)
    depth = render_depth(truth, preset.depth, rng_depth)
    rig, model, mm = truth.rig(), truth.htm(), truth.mm_per_tablet_px

    # Where the pen really touched: the operator's error, in tablet px (exact, not rounded).
    n = len(truth.landmarks_tablet_px)
    touch_px = rng_touch.normal(0.0, preset.touch_sigma_mm, (n, 2)) / mm
    exact_ds = synthesize_dataset(
        model, rig, truth.landmarks_tablet_px, truth.landmarks_hand_angle_deg,
        ppi=truth.ppi, scale=truth.scale, touch_error_px=touch_px,
        tablet_height_mm=truth.tablet_height_mm, camera_z_mm=truth.camera_z_mm,
        name=f"twin-seed{seed}-{preset.name}",
    )  # fmt: skip
    hand_xy = exact_ds.hand_xy_mm
    if preset.hand_round_mm:
        hand_xy = np.round(hand_xy / preset.hand_round_mm) * preset.hand_round_mm
    if exact:
        image_px, depth_mm = exact_ds.image_px, exact_ds.depth_mm
    else:
        blobs = find_blobs(capture, detect_settings)
        if len(blobs.image_px) != n:
            hint = "; try exact=True (simulate --exact) or larger dots (--dot-px)"
            raise BlobCountError("capture.png (simulated)", blobs, n, hint)
        image_px = blobs.image_px[order_blobs(blobs.image_px, truth.landmarks_tablet_px)]
        depth_mm = depth_at(depth, image_px, detect_settings.depth_window_px)
    dataset = exact_ds.replace(
        image_px=image_px, depth_mm=depth_mm, hand_xy_mm=hand_xy,
        touch_error_px=np.round(touch_px),  # the tablet reports whole px
    )  # fmt: skip

    lo, hi = truth.landmark_area_px()
    held_px = rng_held.uniform(lo, hi, (n_heldout, 2))
    held_angle = rng_held.uniform(0.0, 180.0, n_heldout)
    held_true_px, _ = truth.project(held_px)
    held_image_px = held_true_px + rng_held.normal(0.0, 1.0, held_true_px.shape) * (
        preset.target_sigma_px
    )
    held_depth = depth_at(depth, held_image_px, detect_settings.depth_window_px)
    return Twin(
        truth=truth, preset=preset, dataset=dataset, capture=capture, depth=depth,
        landmarks_image_px=exact_ds.image_px, landmarks_depth_mm=exact_ds.depth_mm,
        heldout_tablet_px=held_px, heldout_hand_angle_deg=held_angle,
        heldout_image_px=held_image_px, heldout_depth_mm=held_depth,
    )  # fmt: skip


def check_seed(seed: int) -> int:
    """``seed`` if numpy's generators take it (0 to 2^63 - 1); ``ValueError`` if not."""
    lo, hi = SEED_RANGE
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or not lo <= seed <= hi:
        raise ValueError(f"seed must be a whole number from 0 to 2^63 - 1 (got {seed!r})")
    return int(seed)


def heldout_csv_text(twin: Twin) -> str:
    """The held-out targets as ``u,v,depth,hand_angle,tablet_x,tablet_y`` (px, px, mm, deg, px)."""
    out = io.StringIO()
    out.write(",".join(HELDOUT_HEADER) + "\n")
    rows = np.column_stack([twin.heldout_image_px, twin.heldout_depth_mm,
                            twin.heldout_hand_angle_deg, twin.heldout_tablet_px])  # fmt: skip
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
    :class:`~handeye_jax._errors.InputError` naming ``out_dir`` and ``field``.
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
    stale = [p for pattern in DERIVED_FILES for p in sorted(folder.glob(pattern))]
    figures = folder / DERIVED_FOLDER
    stale += [figures / f"{name}.{ext}" for name in FIGURES for ext in FORMATS]
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
    on failure (an :class:`~handeye_jax._errors.InputError` naming the file and ``field``)
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
    paths = write_folder_atomic(out_dir, files, field)
    _remove(stale, field)
    return paths
