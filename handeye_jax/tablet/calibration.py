"""Writing the touching errors the tablet measured into a dataset, keeping a backup."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..dataset import Dataset, update_dataset
from .posts import CalibrationPost, PostError


def apply_touch_errors(path: str | Path, post: CalibrationPost) -> bool:
    """Write ``post.touch_error_px`` (tablet px) into the dataset at ``path``.

    The dataset is read and validated from disk, so edits made since the page loaded are kept,
    and only the ``touch_error_px`` values are rewritten: the file's comments, key order and
    layout stay as they were (:func:`~handeye_jax.dataset.update_dataset`). Its previous bytes
    go to ``DATASET.bak``; both writes are atomic. A post whose landmarks are not the
    dataset's raises :class:`PostError` (409) and writes nothing.

    Returns ``True`` if the file was written, ``False`` if it already held these values (a
    resent post), in which case the backup is left alone.
    """
    path = Path(path)

    def with_touch_errors(ds: Dataset) -> Dataset:
        if ds.n_landmarks != len(post.tablet_px) or not np.array_equal(
            ds.tablet_px, post.tablet_px
        ):
            raise PostError(
                409, "touches",
                f"the landmarks of {path} are not the ones the page drew; reload the page",
            )  # fmt: skip
        return ds.replace(touch_error_px=post.touch_error_px)

    return update_dataset(path, with_touch_errors, keep_backup=True)
