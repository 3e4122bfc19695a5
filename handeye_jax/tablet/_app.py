"""What the tablet server serves and saves: the session, and the posts' files.

Every file path is fixed when the server starts (:func:`~._server.make_server`); the posts
are validated (:mod:`._posts`) and written atomically, one at a time. Saves of the dataset are
limited in rate (:data:`SAVE_BURST`, then one per :data:`SAVE_INTERVAL_S`) and its backups in
number (:func:`~._calibration.prune_backups`), so a client cannot fill the disk.
"""

from __future__ import annotations

import hashlib
import json
import os
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .._core import InputError
from ..data import load_dataset
from ..geometry import mm_per_tablet_px
from . import _posts as posts
from . import _trials as trials
from ._calibration import MAX_BACKUPS, apply_touch_errors

# Dataset saves: a burst of this many, then one per interval (a run takes minutes to touch).
SAVE_BURST = 10
SAVE_INTERVAL_S = 2.0


class SaveRate:
    """A token bucket: :meth:`check` refuses (429) when no save is left; :meth:`spend` uses
    one."""

    def __init__(self, burst: int = SAVE_BURST, interval_s: float = SAVE_INTERVAL_S):
        self.burst, self.interval_s = burst, interval_s
        self._left, self._last = float(burst), time.monotonic()

    def check(self, name: str) -> None:
        now = time.monotonic()
        self._left = min(self.burst, self._left + (now - self._last) / self.interval_s)
        self._last = now
        if self._left < 1:
            wait = (1 - self._left) * self.interval_s
            raise posts.PostError(
                429, "", f"{name} was saved {self.burst} times in a short while; the page "
                f"sends this run again in a moment (wait {wait:.1f} s)",
            )  # fmt: skip

    def spend(self) -> None:
        self._left -= 1


@dataclass
class TabletApp:
    """What the server serves; every file path is fixed when the server starts.

    Attributes:
        dataset_path: the dataset whose touch errors calibration mode writes, or ``None``.
        ppi, scale: the tablet's px per inch and display scale (eq. 9).
        trials_path: the evaluation trials file (JSON).
        targets_path, targets_px: the targets file and its points (CSS px), or ``None``.
        result: what is being evaluated (result file, model, seed, dataset), or ``None``.

    What it answers names files by their names, never by a path: the page needs no more, and
    the PC's folders are nobody else's business.
    """

    dataset_path: Path | None
    ppi: float
    scale: float
    trials_path: Path
    targets_path: Path | None = None
    targets_px: np.ndarray | None = None
    result: dict[str, Any] | None = None
    trials_doc: dict[str, Any] = field(default_factory=dict)
    lock: threading.Lock = field(default_factory=threading.Lock)
    save_rate: SaveRate = field(default_factory=SaveRate)

    def session(self) -> dict[str, Any]:
        """The page's start-up data, read afresh (the dataset may have changed on disk)."""
        mm = mm_per_tablet_px(self.ppi, self.scale)
        out: dict[str, Any] = {
            "tablet": {"ppi": self.ppi, "scale": self.scale, "mm_per_px": mm},
            "dataset": None,
            "targets_file": None,
            "result": _public_result(self.result),
            "trials": {"file": self.trials_path.name, "summary": []},
            "limits": {
                "max_body_bytes": posts.MAX_BODY_BYTES,
                "max_touches": posts.MAX_TOUCHES,
                "max_trials": posts.MAX_TRIALS,
                "pointer_types": list(posts.POINTER_TYPES),
            },
        }
        if self.dataset_path is not None:
            ds = load_dataset(self.dataset_path)
            out["dataset"] = {
                "file": self.dataset_path.name,
                "backups": f"{self.dataset_path.name}.<UTC time>.bak (the first and the last "
                f"{MAX_BACKUPS})",
                "name": ds.name,
                "tablet_px": ds.tablet_px.tolist(),
                "touch_error_px": ds.touch_error_px.tolist(),
                "key": self._dataset_key(ds.tablet_px),
                "version": ds.version,
                "captures": [
                    {
                        "hand_position_mm": c.hand_position_mm.tolist(),
                        "hand_angle_deg": c.hand_angle_deg,
                        "landmarks": c.landmarks.tolist(),
                    }
                    for c in ds.captures
                ],
            }
        if self.targets_px is not None:
            assert self.targets_path is not None
            out["targets_file"] = {
                "file": self.targets_path.name,
                "tablet_px": self.targets_px.tolist(),
                "key": _key(str(self.targets_path), self.targets_px.tolist()),
            }
        with self.lock:
            out["trials"]["summary"] = trials.summarise(self.trials_doc)
        return out

    def post_calibration(self, doc: Any) -> dict[str, Any]:
        if self.dataset_path is None:
            raise posts.PostError(404, "", "no dataset: start the server with --dataset")
        with self.lock:
            ds = load_dataset(self.dataset_path)
            post = posts.parse_calibration(doc, ds.n_landmarks)
            if post.key is not None and post.key != self._dataset_key(ds.tablet_px):
                raise posts.PostError(
                    409, "key",
                    f"these touches were measured on another dataset's landmarks, not on "
                    f"{self.dataset_path.name}'s; discard them, or serve that dataset again",
                )  # fmt: skip
            self.save_rate.check(self.dataset_path.name)
            backup = apply_touch_errors(self.dataset_path, post)
            if backup is not None:
                self.save_rate.spend()
        dist = np.linalg.norm(post.touch_error_px, axis=1)
        mm = mm_per_tablet_px(self.ppi, self.scale)
        return {
            "saved": self.dataset_path.name,
            "written": backup is not None,
            "backup": backup.name if backup is not None else None,
            "mean_px": float(dist.mean()),
            "mean_mm": float(dist.mean() * mm),
            "pointer_types": {
                k: post.pointer_types.count(k) for k in sorted(set(post.pointer_types))
            },
        }

    def post_evaluation(self, doc: Any) -> dict[str, Any]:
        post = posts.parse_evaluation(doc)
        expected = {"dataset": self._dataset_points, "file": lambda: self.targets_px}
        if post.targets in expected:
            want = expected[post.targets]()
            if want is None or not np.array_equal(want, post.target_px):
                raise posts.PostError(
                    409, "touches", f"the targets are not the {post.targets}'s; reload the page"
                )
        with self.lock:
            trial = trials.find_trial(self.trials_doc, post.run_id)
            if trial is None:
                held = len(self.trials_doc["trials"])
                if held >= posts.MAX_TRIALS:
                    raise posts.PostError(
                        409, "trials",
                        f"{self.trials_path.name} holds {held} trials, the limit of "
                        f"{posts.MAX_TRIALS}; restart the server with another --trials file",
                    )  # fmt: skip
                trial = trials.make_trial(post, self.trials_doc, self.result)
                doc_new = {**self.trials_doc, "trials": [*self.trials_doc["trials"], trial]}
                trials.save_trials(doc_new, self.trials_path)
                self.trials_doc = doc_new
            summary = trials.summarise(self.trials_doc)
        keep = ("trial", "label", "mean_px", "max_px", "mean_mm", "max_mm")
        return {"saved": self.trials_path.name, **{k: trial[k] for k in keep}, "summary": summary}

    def public_error(self, e: InputError, message: str | None = None) -> str:
        """``e`` as one line for a client: its file by name, and no folder of this PC."""
        text = message if message is not None else e.message
        for path in (self.dataset_path, self.trials_path, self.targets_path):
            if path is not None:
                for folder in {str(path.parent), str(path.resolve().parent)} - {"."}:
                    text = text.replace(folder + os.sep, "")
        name = Path(e.path).name if e.path is not None and str(e.path) else None
        return str(InputError(name, e.field, text))

    def _dataset_key(self, tablet_px: np.ndarray) -> str:
        assert self.dataset_path is not None
        return _key(str(self.dataset_path.resolve()), tablet_px.tolist())

    def _dataset_points(self) -> np.ndarray | None:
        if self.dataset_path is None:
            return None
        return load_dataset(self.dataset_path).tablet_px


def _public_result(result: dict[str, Any] | None) -> dict[str, Any] | None:
    """The result being evaluated as the page sees it: its file by name."""
    if result is None:
        return None
    out = {k: v for k, v in result.items() if k != "path"}
    return {"file": Path(result["path"]).name, **out}


def _key(*parts: Any) -> str:
    """A short fingerprint the page uses to keep runs of different landmark sets apart."""
    return hashlib.sha256(json.dumps(parts).encode()).hexdigest()[:16]
