"""Writing the touching errors the tablet measured into a dataset, keeping its versions: the
first (the dataset before any save) and the last :data:`MAX_BACKUPS`."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..data import Dataset, backup_path, update_dataset
from ._posts import CalibrationPost, PostError

# Backups kept besides the first: a save every 2 s for a day would otherwise be 43,200 files.
MAX_BACKUPS = 50
_STAMP = r"\d{4}-\d\d-\d\dT\d\d-\d\d-\d\d\.\d{3}Z"


def apply_touch_errors(path: str | Path, post: CalibrationPost) -> Path | None:
    """Write ``post.touch_error_px`` (tablet px) into the dataset at ``path``.

    The dataset is read and validated from disk, so edits made since the page loaded are kept,
    and only the ``touch_error_px`` values are rewritten: the file's comments, key order and
    layout stay as they were (:func:`~handeye_jax.update_dataset`). Its previous bytes go to
    a new ``DATASET.<UTC time>.bak``; both writes are atomic (both or neither). Then the
    oldest backups but the first are removed, down to :data:`MAX_BACKUPS` besides it
    (:func:`prune_backups`). A post whose landmarks are not the dataset's raises :class:`PostError`
    (409) and writes nothing.

    Returns the backup's path if the file was written, ``None`` if it already held these
    values (a resent post), in which case no backup is made.
    """
    path = Path(path)

    def with_touch_errors(ds: Dataset) -> Dataset:
        if ds.n_landmarks != len(post.tablet_px) or not np.array_equal(
            ds.tablet_px, post.tablet_px
        ):
            raise PostError(
                409, "touches",
                f"the landmarks of {path.name} are not the ones the page drew; reload the page",
            )  # fmt: skip
        if not np.array_equal(ds.touch_landmark, np.arange(ds.n_landmarks)):
            raise PostError(
                409, "touches",
                f"{path.name} does not hold one [[touches]] per landmark in landmark order "
                "(landmark = 0, 1, ...), which the page's touches are: add them in that order",
            )  # fmt: skip
        return ds.replace(touch_error_px=post.touch_error_px)

    backup = update_dataset(path, with_touch_errors, keep_backup=True, backup=backup_path(path))
    if backup is not None:
        prune_backups(path)
    return backup


def prune_backups(path: str | Path, keep: int = MAX_BACKUPS) -> list[Path]:
    """Remove the backups of the dataset at ``path`` (``DATASET.<UTC time>[-k].bak``) but the
    first and the last ``keep``; returns those removed, oldest first. Other files are never
    touched; a backup that cannot be removed is left."""
    path = Path(path)
    pattern = re.compile(re.escape(path.name) + rf"\.({_STAMP})(?:-(\d+))?\.bak")
    found = []
    for p in path.parent.iterdir():
        if m := pattern.fullmatch(p.name):
            found.append(((m[1], int(m[2] or 1)), p))  # -2, -3…: later in the same ms
    ordered = [p for _, p in sorted(found)]
    removed = []
    for p in ordered[1:-keep] if keep > 0 else ordered[1:]:
        try:
            p.unlink()
            removed.append(p)
        except OSError:
            pass
    return removed
