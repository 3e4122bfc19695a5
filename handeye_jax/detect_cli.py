"""File work for ``handeye-jax detect``: the overlay picture and the in-place update."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np

from .dataset import Dataset, dataset_to_toml, save_dataset
from .detect import overlay_image, read_image
from .errors import InputError
from .simulate import encode_png, write_bytes_atomic


def write_overlay(
    capture: str | Path, points_px: np.ndarray, depth_mm: np.ndarray | None, out: Path
) -> None:
    """The picture with each point circled and numbered (and its depth, mm, if given)."""
    image = read_image(capture)
    if depth_mm is None:
        labels = [f"?{i}" for i in range(len(points_px))]
    else:
        labels = [f"{m}: {z:.0f} mm" for m, z in enumerate(depth_mm)]
    write_bytes_atomic(out, encode_png(overlay_image(image, points_px, labels)))


def backup_and_save(dataset: Dataset, path: Path) -> None:
    """Keep ``path`` as ``path.bak``, then replace ``path`` with ``dataset``, atomically.

    The new text is validated first; the backup is a copy, so the original stays in place
    until the new file replaces it in one rename.
    """
    dataset_to_toml(dataset)  # fails before anything is touched if the dataset cannot be written
    backup = path.with_name(path.name + ".bak")
    try:
        shutil.copy2(path, backup)
    except OSError as e:
        raise InputError(backup, "", f"cannot keep the previous dataset: {e}") from None
    save_dataset(dataset, path)
    os.utime(backup)
