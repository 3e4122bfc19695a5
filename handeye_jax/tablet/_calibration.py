"""Writing the touching errors the tablet measured into a dataset, keeping every version."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..data import Dataset, backup_path, update_dataset
from ._posts import CalibrationPost, PostError


def apply_touch_errors(path: str | Path, post: CalibrationPost) -> Path | None:
    """Write ``post.touch_error_px`` (tablet px) into the dataset at ``path``.

    The dataset is read and validated from disk, so edits made since the page loaded are kept,
    and only the ``touch_error_px`` values are rewritten: the file's comments, key order and
    layout stay as they were (:func:`~handeye_jax.update_dataset`). Its previous bytes go to
    a new ``DATASET.<UTC time>.bak``, so every version stays; both writes are atomic (both or
    neither). A post whose landmarks are not the dataset's raises :class:`PostError`
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

    return update_dataset(path, with_touch_errors, keep_backup=True, backup=backup_path(path))
