"""Writing the touching errors the tablet measured into a dataset, keeping every version."""

from __future__ import annotations

import datetime as dt
from pathlib import Path

import numpy as np

from ..dataset import Dataset, update_dataset
from .posts import CalibrationPost, PostError


def versioned_backup_path(path: str | Path, now: dt.datetime | None = None) -> Path:
    """A new file beside ``path`` for its current version: ``DATASET.<UTC time>.bak``.

    E.g. ``myrig.toml.2026-12-02T07-37-28.123Z.bak`` (UTC, to the millisecond, ``-`` for
    ``:`` so every file system takes it); names sort by time. An existing file is never
    chosen: a second save in the same millisecond gets ``...123Z-2.bak``, and so on.

    Args:
        path: the dataset file.
        now: the time of the save (UTC); the clock's when not given.
    """
    path = Path(path)
    now = dt.datetime.now(dt.UTC) if now is None else now.astimezone(dt.UTC)
    stamp = now.strftime("%Y-%m-%dT%H-%M-%S.") + f"{now.microsecond // 1000:03d}Z"
    candidate = path.with_name(f"{path.name}.{stamp}.bak")
    n = 1
    while candidate.exists() or candidate.is_symlink():
        n += 1
        candidate = path.with_name(f"{path.name}.{stamp}-{n}.bak")
    return candidate


def apply_touch_errors(path: str | Path, post: CalibrationPost) -> Path | None:
    """Write ``post.touch_error_px`` (tablet px) into the dataset at ``path``.

    The dataset is read and validated from disk, so edits made since the page loaded are kept,
    and only the ``touch_error_px`` values are rewritten: the file's comments, key order and
    layout stay as they were (:func:`~handeye_jax.dataset.update_dataset`). Its previous bytes
    go to a new :func:`versioned_backup_path`, so every version stays; both writes are atomic
    (both or neither). A post whose landmarks are not the dataset's raises :class:`PostError`
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
        return ds.replace(touch_error_px=post.touch_error_px)

    backup = versioned_backup_path(path)
    written = update_dataset(path, with_touch_errors, keep_backup=True, backup=backup)
    return backup if written else None
