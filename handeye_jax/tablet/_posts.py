"""Strict reading of what the tablet page posts: JSON bodies of touches, in CSS px.

Every coordinate is in tablet px, which are CSS px on the tablet's page (eq. 9: one tablet px
is ``25.4 / ppi * scale`` mm). A body that is not exactly the documented shape is refused
with :class:`PostError`, whose HTTP status, field and message the server sends back.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

# Bounds on what one post may hold, so a post (or many) cannot grow the files without end.
# A run touches each point by jogging the robot: the paper's has 9; 100 is a 10 x 10 grid.
MAX_TOUCHES = 100
# A bigger body is not a run: 100 touches take about 10 kB.
MAX_BODY_BYTES = 64 * 1024
# Evaluation trials in one trials file (each post rewrites it; a trial of 100 touches ~32 kB).
MAX_TRIALS = 100
# No screen is wider or taller than this many CSS px (browsers' canvas size limit).
MAX_SCREEN_PX = 16384.0
POINTER_TYPES = ("pen", "touch", "mouse")
TARGET_SOURCES = ("dataset", "file", "grid")
MAX_LABEL_CHARS = 200
MAX_KEY_CHARS = 64


class PostError(ValueError):
    """A refused post. ``status`` is the HTTP status (4xx); ``field`` names the bad field."""

    def __init__(self, status: int, field: str, message: str):
        self.status = status
        self.field = field
        self.message = message
        super().__init__(f"{field}: {message}" if field else message)


@dataclass(frozen=True)
class CalibrationPost:
    """Touches of every landmark, in landmark order.

    Attributes:
        run_id: the page's id for this run (to recognise a resend).
        tablet_px: where the page drew each landmark, CSS px, ``(n, 2)``.
        touch_error_px: touched minus drawn position, CSS px, ``(n, 2)``.
        pointer_types: ``"pen"``, ``"touch"`` or ``"mouse"`` for each touch.
        key: the fingerprint of the dataset the page drew (``/api/session``'s
            ``dataset.key``), or ``None`` if the page did not send one.
    """

    run_id: str
    tablet_px: np.ndarray
    touch_error_px: np.ndarray
    pointer_types: tuple[str, ...]
    key: str | None = None


@dataclass(frozen=True)
class EvaluationPost:
    """One evaluation trial: every target touched once, in order.

    Attributes:
        run_id: the page's id for this trial (to recognise a resend).
        label: what was deployed, e.g. ``"stage 2"``; trials are summarised per label.
        targets: where the targets came from: ``"dataset"``, ``"file"`` or ``"grid"``.
        target_px: where each target was drawn, CSS px, ``(n, 2)``.
        touch_px: where the pen touched, CSS px, ``(n, 2)``.
        pointer_types: the pointer type of each touch.
    """

    run_id: str
    label: str
    targets: str
    target_px: np.ndarray
    touch_px: np.ndarray
    pointer_types: tuple[str, ...]


def parse_json_body(body: bytes) -> Any:
    """Decode a UTF-8 JSON body; NaN and Infinity literals are refused, and so are arrays
    nested too deep for the parser and integers too long to convert (4300+ digits)."""

    def no_constants(name: str) -> Any:
        raise PostError(400, "", f"{name} is not a number (JSON allows finite numbers only)")

    try:
        return json.loads(body.decode("utf-8"), parse_constant=no_constants)
    except PostError:  # a ValueError too: it says which literal
        raise
    except RecursionError:
        raise PostError(400, "", "body is nested too deep to be a run of touches") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise PostError(400, "", f"body is not valid UTF-8 JSON: {e}") from None
    except ValueError:  # an integer literal of 4300+ digits
        raise PostError(400, "", "body holds a number with too many digits") from None


def _object(
    x: Any, where: str, keys: tuple[str, ...], optional: tuple[str, ...] = ()
) -> dict[str, Any]:
    if not isinstance(x, dict):
        raise PostError(400, where, f"must be a JSON object with keys {', '.join(keys)}")
    for k in x:
        if k not in keys and k not in optional:
            known = ", ".join((*keys, *optional))
            raise PostError(400, _join(where, k), f"unknown key; expected {known}")
    for k in keys:
        if k not in x:
            raise PostError(400, _join(where, k), "missing")
    return x


def _string(x: Any, where: str, max_chars: int = MAX_LABEL_CHARS) -> str:
    if not isinstance(x, str) or not x.strip() or len(x) > max_chars:
        raise PostError(400, where, f"must be a non-empty string of at most {max_chars} chars")
    if not x.isprintable():  # a control character (ESC) or a lone surrogate: shown, saved
        bad = next(c for c in x if not c.isprintable())  # and printed, it breaks them
        raise PostError(400, where, f"must be printable text (got {ascii(bad)} at "
                        f"{x.index(bad)})")  # fmt: skip
    return x


def _choice(x: Any, where: str, choices: tuple[str, ...]) -> str:
    if x not in choices:
        raise PostError(400, where, f"must be one of {', '.join(choices)} (got {x!r})")
    return x


def _point(x: Any, where: str, lo: float, hi: float) -> list[float]:
    if not isinstance(x, list) or len(x) != 2:
        raise PostError(400, where, "must be an array of 2 numbers [x, y], px")
    out = []
    for i, v in enumerate(x):
        if isinstance(v, int) and not isinstance(v, bool) and not lo <= v <= hi:
            # before any float(): a 4,000-digit integer has none (OverflowError)
            got = v if abs(v) < 10**15 else f"an integer of {len(str(abs(v)))} digits"
            raise PostError(400, f"{where}[{i}]", f"must be within [{lo:g}, {hi:g}] px (got {got})")
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise PostError(400, f"{where}[{i}]", f"must be a finite number (got {v!r})")
        if not lo <= v <= hi:
            raise PostError(400, f"{where}[{i}]", f"must be within [{lo:g}, {hi:g}] px (got {v})")
        out.append(float(v))
    return out


def _touches(x: Any, where: str, n: int | None) -> list[Any]:
    if not isinstance(x, list) or not x:
        raise PostError(400, where, "must be a non-empty array of touches")
    if len(x) > MAX_TOUCHES:
        raise PostError(413, where, f"at most {MAX_TOUCHES} touches (got {len(x)})")
    if n is not None and len(x) != n:
        raise PostError(400, where, f"needs one touch per landmark: {n} (got {len(x)})")
    return x


def _index(x: Any, where: str, want: int) -> None:
    if isinstance(x, bool) or not isinstance(x, int) or x != want:
        raise PostError(400, where, f"touches must be in order: expected m = {want} (got {x!r})")


def parse_calibration(doc: Any, n_landmarks: int) -> CalibrationPost:
    """Validate a calibration post against a dataset of ``n_landmarks`` landmarks."""
    doc = _object(doc, "", ("run_id", "touches"), optional=("key",))
    run_id = _string(doc["run_id"], "run_id")
    key = _string(doc["key"], "key", MAX_KEY_CHARS) if "key" in doc else None
    touches = _touches(doc["touches"], "touches", n_landmarks)
    drawn, errors, kinds = [], [], []
    for i, t in enumerate(touches):
        where = f"touches[{i}]"
        t = _object(t, where, ("m", "tablet_px", "touch_error_px", "pointer_type"))
        _index(t["m"], f"{where}.m", i)
        xy = _point(t["tablet_px"], f"{where}.tablet_px", 0.0, MAX_SCREEN_PX)
        d = _point(t["touch_error_px"], f"{where}.touch_error_px", -MAX_SCREEN_PX, MAX_SCREEN_PX)
        for k in range(2):
            if not 0.0 <= xy[k] + d[k] <= MAX_SCREEN_PX:
                raise PostError(
                    400, f"{where}.touch_error_px[{k}]", "puts the touch outside any screen"
                )
        kinds.append(_choice(t["pointer_type"], f"{where}.pointer_type", POINTER_TYPES))
        drawn.append(xy)
        errors.append(d)
    return CalibrationPost(run_id, np.array(drawn), np.array(errors), tuple(kinds), key)


def parse_evaluation(doc: Any) -> EvaluationPost:
    """Validate an evaluation trial post."""
    doc = _object(doc, "", ("run_id", "label", "targets", "touches"))
    run_id = _string(doc["run_id"], "run_id")
    label = _string(doc["label"], "label")
    source = _choice(doc["targets"], "targets", TARGET_SOURCES)
    touches = _touches(doc["touches"], "touches", None)
    targets, touched, kinds = [], [], []
    for i, t in enumerate(touches):
        where = f"touches[{i}]"
        t = _object(t, where, ("m", "target_px", "touch_px", "pointer_type"))
        _index(t["m"], f"{where}.m", i)
        targets.append(_point(t["target_px"], f"{where}.target_px", 0.0, MAX_SCREEN_PX))
        touched.append(_point(t["touch_px"], f"{where}.touch_px", 0.0, MAX_SCREEN_PX))
        kinds.append(_choice(t["pointer_type"], f"{where}.pointer_type", POINTER_TYPES))
    return EvaluationPost(run_id, label, source, np.array(targets), np.array(touched), tuple(kinds))


def _join(where: str, key: str) -> str:
    return f"{where}.{key}" if where else key
