"""Converting a version-1 dataset file to version 2."""

from __future__ import annotations

import tomllib
from pathlib import Path

from .._core import (
    MAX_DATASET_BYTES,
    InputError,
    StagedFiles,
    read_bytes,
    read_text,
)
from ._dataset import Dataset
from ._read import dataset_from_document, parse_dataset_text
from ._write import backup_path, dataset_to_toml


def convert_path(path: str | Path) -> Path:
    """Where :func:`convert_to_v2` writes by default: ``NAME.v2.toml`` beside ``NAME.toml``."""
    path = Path(path)
    stem = path.name.removesuffix(".toml") if path.name.endswith(".toml") else path.name
    return path.with_name(f"{stem}.v2.toml")


def convert_to_v2(
    path: str | Path,
    out: str | Path | None = None,
    *,
    overwrite: bool = False,
    backup: str | Path | None = None,
) -> Dataset:
    """Read a dataset (either version) and write it to ``out`` as version 2; returns it.

    Args:
        path: the dataset to read (``handeye-jax.dataset/1`` or ``/2``).
        out: where to write (default :func:`convert_path`, ``NAME.v2.toml`` beside it); may be
            ``path`` itself, with ``overwrite``.
        overwrite: replace an existing ``out``; its previous bytes are kept at ``backup``
            (default a new ``OUT.<UTC time>.bak``, :func:`backup_path`), written together with
            the new file (both or neither). Without it an existing ``out`` is refused.
        backup: where the replaced file goes.

    The new file is in the canonical layout (the old file's comments are not carried over;
    the old file stays, at ``path`` or as the backup). The written text is validated as
    :func:`load_dataset` reads it and reads back equal to the dataset before anything is
    written. Raises :class:`InputError` naming the file and field.
    """
    path = Path(path)
    out = convert_path(path) if out is None else Path(out)
    ds = parse_dataset_text(read_text(path, MAX_DATASET_BYTES)[1], path)
    text = dataset_to_toml(ds, version=2)
    if dataset_from_document(tomllib.loads(text), out) != ds:  # never a lossy conversion
        raise InputError(path, "", "the version-2 text does not read back equal; nothing written")
    files: dict[Path, bytes] = {}
    if out.exists():
        if not overwrite:
            raise InputError(out, "", "exists; not overwritten (overwrite=True replaces it and "
                             "keeps it as a backup)")  # fmt: skip
        target = Path(backup) if backup is not None else backup_path(out)
        files[target] = read_bytes(out, MAX_DATASET_BYTES, "dataset to replace")
    files[out] = text.encode("utf-8")
    StagedFiles(files).commit()
    return ds
