"""File work for ``handeye-jax detect``: the overlay picture and the in-place update."""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import numpy as np
from jaxtyping import Float

from .dataset import Dataset, save_dataset
from .detect import overlay_image, read_image
from .errors import InputError
from .simulate import encode_png, write_bytes_atomic


def write_overlay(
    capture: str | Path,
    points_px: Float[np.ndarray, "n 2"],
    depth_mm: Float[np.ndarray, " n"] | None,
    out: Path,
) -> None:
    """The picture with each point circled and numbered (with its depth in mm, if given)."""
    image = read_image(capture)
    if depth_mm is None:
        labels = [f"?{i}" for i in range(len(points_px))]
    else:
        labels = [f"{m}: {z:.0f} mm" for m, z in enumerate(depth_mm)]
    write_bytes_atomic(out, encode_png(overlay_image(image, points_px, labels)))


def backup_and_save(dataset: Dataset, path: Path) -> None:
    """Replace ``path`` with ``dataset`` and keep the previous file as ``path.bak``.

    The new file is written (and validated) beside the old one first; only then is the old
    one copied to the backup and replaced in one rename, so a failure leaves it as it was.
    """
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".new", dir=path.parent)
    os.close(fd)
    try:
        save_dataset(dataset, tmp)
        backup = path.with_name(path.name + ".bak")
        try:
            shutil.copy2(path, backup)
        except OSError as e:
            raise InputError(backup, "", f"cannot keep the previous dataset: {e}") from None
        shutil.copymode(path, tmp)
        os.replace(tmp, path)
    finally:
        Path(tmp).unlink(missing_ok=True)
