"""Hand commands from a calibration with NumPy alone: :class:`Predictor`.

For the robot PC: it reads the ``frames`` section of a result file (or the document of
``handeye-jax export --format json``) with the standard library's JSON reader and computes
eq. (8) or (25) for many points at once. It gives the same numbers as
:meth:`handeye_jax.CalibrationResult.predict` (the JAX path, for differentiation and batches).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from .._core import DIGEST_KEY, InputError, document_digest, read_text
from ..data import undistort_px
from . import _npchain
from ._frames import FORMAT as FRAMES_FORMAT
from ._frames import MAX_FILE_BYTES, Frames
from ._npframes import MODELS, chain_of
from ._trust import Checked, Reach, check_result_document

RESULT_FORMAT = "handeye-jax.result/1"


class _Duplicate(Exception):
    pass


def _no_duplicates(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out = dict(pairs)
    if len(out) != len(pairs):
        seen = set()
        for k, _ in pairs:
            if k in seen:
                raise _Duplicate(k)
            seen.add(k)
    return out


def read_json(path: str | Path) -> Any:
    """A JSON file, parsed; :class:`InputError` naming the file if it cannot be (too large,
    unreadable, not JSON, a key twice in one object)."""
    path = Path(path)
    _, text = read_text(path, MAX_FILE_BYTES)  # a regular file only: a FIFO would hang open()
    return _parse_json(text, path)


def _parse_json(text: str, path: Path) -> Any:
    try:
        return json.loads(text, object_pairs_hook=_no_duplicates)
    except _Duplicate as e:
        raise InputError(path, "", f"duplicate key {str(e)!r:.60}: a key may appear only once "
                         "in an object") from None  # fmt: skip
    except json.JSONDecodeError as e:
        raise InputError(path, "", f"not valid JSON: {e}") from None
    except (RecursionError, ValueError) as e:  # nesting, or an integer of too many digits
        raise InputError(path, "", f"not valid here: {type(e).__name__}") from None


def stored_frames(path: str | Path) -> Frames | None:
    """A result file's ``frames`` section if the file is as handeye-jax wrote it and its
    parts agree (:func:`stored_result`), else ``None``."""
    checked = stored_result(path)
    return None if checked is None else checked.frames


def stored_result(path: str | Path) -> Checked | None:
    """A result file's frames and reach, checked with NumPy alone, if the file is as
    handeye-jax wrote it; else ``None``.

    The writer stores the SHA-256 of the rest of the document (``content_sha256``). While it
    matches, the file needs no validation of every field, which takes JAX and a second or
    more; but anyone editing a file can recompute the digest, so its parts are still checked
    against each other (:func:`~handeye_jax.robot.check_result_document`: an
    :class:`InputError` if they disagree). An older result, an edited one, a frames file or
    one that is not JSON give ``None``: for those, :func:`~handeye_jax.load_frames` validates
    the whole file and makes the same checks. A file that cannot be read at all (missing, a
    FIFO, too large) is an :class:`InputError` here.
    """
    path = Path(path)
    _, text = read_text(path, MAX_FILE_BYTES)  # unreadable is an error either way
    try:
        doc = _parse_json(text, path)
    except InputError:  # the full reader says what is wrong, in its own words
        return None
    if not isinstance(doc, dict) or doc.get("format") != RESULT_FORMAT or "frames" not in doc:
        return None
    digest = doc.pop(DIGEST_KEY, None)
    try:
        if not isinstance(digest, str) or digest != document_digest(doc):
            return None
    except ValueError:  # NaN or infinity, which the writer never writes
        return None
    if not isinstance(doc.get("model"), str) or doc["model"] not in MODELS:  # checked by JAX
        return None
    return check_result_document(doc, path)


def result_reach(path: str | Path) -> Reach:
    """The reach of a result file's rig (:class:`~handeye_jax.robot.Reach`), its parts
    checked as :func:`stored_result` checks them."""
    return check_result_document(read_json(path), path).reach


class Predictor:
    """Where to send the hand so that the pen touches image points: NumPy, no JAX.

    Build it with :meth:`from_result` (a result file or a frames file) or :meth:`from_frames`.
    :attr:`reach` says where its commands may go.
    """

    def __init__(self, frames: Frames, reach: Reach | None = None):
        if not isinstance(frames, Frames):
            raise TypeError(f"expected Frames, got {type(frames).__name__}")
        self._frames = frames
        self._reach = Reach.of_frames(frames) if reach is None else reach
        self._chain = chain_of(frames)

    @classmethod
    def from_frames(cls, frames: Frames, reach: Reach | None = None) -> Predictor:
        return cls(frames, reach)

    @classmethod
    def from_result(cls, path: str | Path) -> Predictor:
        """Read a result file's ``frames`` section, or a frames file; :class:`InputError`
        names the file and field when it is missing or malformed, or when a result's parts
        disagree (its frames, parameters, rig, data and residuals, checked with NumPy:
        :func:`~handeye_jax.robot.check_result_document`)."""
        doc = read_json(path)
        if not isinstance(doc, dict):
            raise InputError(path, "", "must be a JSON object")
        fmt = doc.get("format")
        if fmt == FRAMES_FORMAT:
            return cls(Frames.from_dict(doc, path))
        if fmt != RESULT_FORMAT:
            raise InputError(path, "format", f"expected {RESULT_FORMAT!r} or {FRAMES_FORMAT!r} "
                             f"(got {fmt!r:.60})")  # fmt: skip
        if "frames" not in doc:
            raise InputError(
                path, "frames", "missing: the file was written before results carried their "
                f"frames; run `handeye-jax export {path} --format json --out FRAMES.json` and "
                "load FRAMES.json",
            )  # fmt: skip
        return cls(*check_result_document(doc, path))

    @property
    def frames(self) -> Frames:
        return self._frames

    @property
    def stage(self) -> int:
        """The stage hand commands use by default: the one the calibration chose to deploy."""
        return self._frames.deploy_stage

    @property
    def reach(self) -> Reach:
        """Where the calibration's commands may go: around the hand positions it recorded
        (:class:`~handeye_jax.robot.Reach`); :meth:`Reach.excess_mm` says how far a command
        lies beyond."""
        return self._reach

    @property
    def axes(self) -> str:
        """The coordinates the calibration determines for a hand command: ``"xy"``, or
        ``"xyz"`` when the touches recorded the hand's heights (``z_p − z_c`` is known)."""
        return "xyz" if self._frames.has_height else "xy"

    def hand_command(
        self,
        image_px: Any,
        depth_mm: Any,
        hand_angle_deg: Any,
        stage: int | None = None,
        capture_position_mm: Any = None,
        capture_hand_angle_deg: Any = None,
        axes: str = "xy",
    ) -> np.ndarray:
        """Hand commands ``(x, y)`` in mm in the base frame, shape (n, 2), or ``(x, y, z)``,
        shape (n, 3), with ``axes="xyz"``. A target is any point seen in a picture at its
        depth, from any capture pose.

        Args:
            image_px: ``(u, v)`` of each target in the captured picture, px, shape (n, 2).
            depth_mm: depth at each target, mm, shape (n,).
            hand_angle_deg: the hand angle θh the robot will touch with, deg, (n,) or scalar.
            stage: 2 for eq. (25) with the affine correction, 1 for eq. (8); default: the
                stage the calibration chose to deploy (:attr:`Frames.deploy_stage`).
            capture_position_mm: the hand position when the picture was taken, mm, (3,) or
                (n, 3); default: the calibration's capture.
            capture_hand_angle_deg: the hand angle θh when the picture was taken, deg, scalar
                or (n,); default: the calibration's. The camera turns with the hand.
            axes: ``"xy"``, or ``"xyz"`` to add the hand's height (a calibration whose
                touches recorded the hand's heights; else refused, see :attr:`axes`).
        """
        stage = self._frames.deploy_stage if stage is None else stage
        if stage not in (1, 2):
            raise ValueError(f"stage must be 1 or 2 (got {stage!r})")
        if axes not in ("xy", "xyz"):
            raise ValueError(f"axes must be 'xy' or 'xyz' (got {axes!r})")
        if axes == "xyz" and not self._frames.has_height:
            missing = [c for c in self._frames.undetermined if c.endswith(".z")]
            raise ValueError(f"axes must be 'xy': the calibration does not determine "
                             f"{', '.join(missing) or 'the height'} nor z_pen − z_camera (its "
                             "touches recorded no hand height)")  # fmt: skip
        uv = _finite(image_px, "image_px")
        if uv.ndim != 2 or uv.shape[1] != 2:
            raise ValueError(f"image_px must have shape (n, 2), got {uv.shape}")
        n = uv.shape[0]
        f = self._frames
        uv = undistort_px(uv, f.camera_px, f.distortion)  # the chain is a pinhole's
        if not np.isfinite(uv).all():
            bad = int(np.flatnonzero(~np.isfinite(uv).all(axis=1))[0])
            raise ValueError(f"image_px[{bad}] cannot be undistorted with the calibration's "
                             "lens distortion (the model does not invert there)")  # fmt: skip
        depth = _finite(depth_mm, "depth_mm", (n,))
        if (depth <= 0).any():
            raise ValueError("depth_mm must be > 0")
        phi = f.phi_deg(_finite(hand_angle_deg, "hand_angle_deg", (n,)))
        cap, cap_angle = _capture_pose(f, n, capture_position_mm, capture_hand_angle_deg)
        xy = _npchain.hand_command_xy(self._chain, uv, depth, phi, cap, f.phi_deg(cap_angle),
                                      stage=stage)  # fmt: skip
        if axes == "xy":
            return xy
        z = _npchain.image_to_base_z(self._chain, uv, depth, cap)
        return np.column_stack([xy, z + f.pen_minus_camera_z_mm])


def _capture_pose(
    frames: Frames, n: int, position_mm: Any, hand_angle_deg: Any
) -> tuple[np.ndarray, Any]:
    """The capture pose of ``n`` targets, checked: the hand position, mm, ``(3,)`` or
    ``(n, 3)``, and its hand angle θh, deg, scalar or ``(n,)``; the calibration's for each
    one not given."""
    position = frames.capture_position_mm
    if position_mm is not None:
        position = _finite(position_mm, "capture_position_mm")
        if position.shape not in ((3,), (n, 3)):
            raise ValueError(f"capture_position_mm must have shape (3,) or ({n}, 3), got "
                             f"{position.shape}")  # fmt: skip
    angle = frames.capture_hand_angle_deg
    if hand_angle_deg is not None:
        angle = _finite(hand_angle_deg, "capture_hand_angle_deg")
        if angle.shape not in ((), (n,)):
            raise ValueError(f"capture_hand_angle_deg must be a scalar or have shape "
                             f"({n},), got {angle.shape}")  # fmt: skip
    return position, angle


def _finite(x: Any, name: str, shape: tuple[int, ...] | None = None) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if shape is not None:
        if a.shape not in ((), shape):
            raise ValueError(f"{name} must have shape {shape} or be a scalar, got {a.shape}")
        a = np.broadcast_to(a, shape)
    if not np.isfinite(a).all():
        raise ValueError(f"{name} must be finite")
    return a
