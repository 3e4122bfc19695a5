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

from .._core import DIGEST_KEY, InputError, document_digest
from . import _npchain
from ._frames import FORMAT as FRAMES_FORMAT
from ._frames import MAX_FILE_BYTES, Frames

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
    try:
        with open(path, "rb") as f:
            data = f.read(MAX_FILE_BYTES + 1)
        if len(data) > MAX_FILE_BYTES:
            raise InputError(path, "", f"too large: more than {MAX_FILE_BYTES >> 20} MiB")
        text = data.decode("utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(path, "", f"cannot read file: {e}") from None
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
    """A result file's ``frames`` section if the file is as handeye-jax wrote it, else ``None``.

    The writer stores the SHA-256 of the rest of the document (``content_sha256``). While it
    matches, the frames are the ones the file's own parameters gave when it was written, so
    they need no check against them, which takes JAX and a second or more. An older result,
    an edited one, a frames file or one that cannot be read give ``None``: for those,
    :func:`~handeye_jax.load_frames` validates the whole file and checks the frames.
    """
    try:
        doc = read_json(path)
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
    return Frames.from_dict(doc["frames"], path, "frames")


class Predictor:
    """Where to send the hand so that the pen touches image points: NumPy, no JAX.

    Build it with :meth:`from_result` (a result file or a frames file) or :meth:`from_frames`.
    """

    def __init__(self, frames: Frames):
        if not isinstance(frames, Frames):
            raise TypeError(f"expected Frames, got {type(frames).__name__}")
        self._frames = frames
        # x and y of the camera and the pen: the chain's x-y never reads a z (_npchain says why).
        self._t_hand_camera = frames.t_hand_camera_mm[:2].copy()
        self._t_hand_pen = frames.t_hand_pen_mm[:2].copy()

    @classmethod
    def from_frames(cls, frames: Frames) -> Predictor:
        return cls(frames)

    @classmethod
    def from_result(cls, path: str | Path) -> Predictor:
        """Read a result file's ``frames`` section, or a frames file; :class:`InputError`
        names the file and field when it is missing or malformed."""
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
        return cls(Frames.from_dict(doc["frames"], path, "frames"))

    @property
    def frames(self) -> Frames:
        return self._frames

    @property
    def stage(self) -> int:
        """The stage hand commands use by default: the one the calibration chose to deploy."""
        return self._frames.deploy_stage

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
        depth = _finite(depth_mm, "depth_mm", (n,))
        if (depth <= 0).any():
            raise ValueError("depth_mm must be > 0")
        f = self._frames
        phi = f.phi_deg(_finite(hand_angle_deg, "hand_angle_deg", (n,)))
        cap = f.capture_position_mm
        if capture_position_mm is not None:
            cap = _finite(capture_position_mm, "capture_position_mm")
            if cap.shape not in ((3,), (n, 3)):
                raise ValueError(f"capture_position_mm must have shape (3,) or ({n}, 3), got "
                                 f"{cap.shape}")  # fmt: skip
        cap_angle = f.capture_hand_angle_deg
        if capture_hand_angle_deg is not None:
            cap_angle = _finite(capture_hand_angle_deg, "capture_hand_angle_deg")
            if cap_angle.shape not in ((), (n,)):
                raise ValueError(f"capture_hand_angle_deg must be a scalar or have shape "
                                 f"({n},), got {cap_angle.shape}")  # fmt: skip
        xy = _npchain.hand_command_xy(
            uv, depth, phi, stage, f.camera_px, f.R_hand_camera, self._t_hand_camera,
            self._t_hand_pen, cap, f.phi_deg(cap_angle), f.A1.as_tuple(), f.A2.as_tuple(),
            f.centres_mm,
        )  # fmt: skip
        if axes == "xy":
            return xy
        z = _npchain.image_to_base_z(uv, depth, f.camera_px, f.R_hand_camera, cap)
        return np.column_stack([xy, z + f.pen_minus_camera_z_mm])


def _finite(x: Any, name: str, shape: tuple[int, ...] | None = None) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if shape is not None:
        if a.shape not in ((), shape):
            raise ValueError(f"{name} must have shape {shape} or be a scalar, got {a.shape}")
        a = np.broadcast_to(a, shape)
    if not np.isfinite(a).all():
        raise ValueError(f"{name} must be finite")
    return a
