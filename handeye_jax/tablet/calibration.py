"""Writing the touching errors the tablet measured into a dataset, keeping a backup."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..dataset import load_dataset, save_dataset
from .posts import CalibrationPost, PostError


def apply_touch_errors(path: str | Path, post: CalibrationPost) -> bool:
    """Write ``post.touch_error_px`` (tablet px) into the dataset at ``path``.

    The dataset is read and validated from disk, so edits made since the page loaded are kept.
    Its previous bytes go to ``DATASET.bak``; both writes are atomic. A post whose landmarks
    are not the dataset's raises :class:`PostError` (409) and writes nothing.

    Returns ``True`` if the file was written, ``False`` if it already held these values (a
    resent post), in which case the backup is left alone.
    """
    path = Path(path)
    ds = load_dataset(path)
    if ds.n_landmarks != len(post.tablet_px) or not np.array_equal(ds.tablet_px, post.tablet_px):
        raise PostError(
            409, "touches",
            f"the landmarks of {path} are not the ones the page drew; reload the page",
        )  # fmt: skip
    if np.array_equal(ds.touch_error_px, post.touch_error_px):
        return False
    save_dataset(ds.replace(touch_error_px=post.touch_error_px), path, keep_backup=True)
    return True
