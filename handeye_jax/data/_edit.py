"""Editing a dataset file in place: only the values that changed are rewritten, so the
user's comments, key order and layout survive."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import tomlkit
import tomlkit.exceptions
import tomlkit.items

from .._core import (
    MAX_DATASET_BYTES,
    InputError,
    StagedFiles,
    read_text,
)
from ._dataset import Dataset
from ._read import parse_dataset_text
from ._write import backup_path, dataset_to_document

_BOM = b"\xef\xbb\xbf"
_TABLES = (tomlkit.items.Table, tomlkit.items.InlineTable, tomlkit.TOMLDocument)
_ARRAYS = (tomlkit.items.Array, tomlkit.items.AoT)


def _plain(item: Any) -> Any:
    """A tomlkit item as plain Python values (what tomllib would give)."""
    return item.unwrap() if hasattr(item, "unwrap") else item


def _same(old: Any, new: Any) -> bool:
    """Equal values, numbers compared by value (``168`` is ``168.0``), booleans apart."""
    old = _plain(old)
    if isinstance(new, list):
        return (isinstance(old, list) and len(old) == len(new)
                and all(_same(a, b) for a, b in zip(old, new, strict=True)))  # fmt: skip
    if isinstance(new, dict):
        return (
            isinstance(old, dict)
            and old.keys() == new.keys()
            and all(_same(old[k], new[k]) for k in new)
        )
    if isinstance(old, bool) or isinstance(new, bool):
        return type(old) is type(new) and old == new
    return old == new and type(old) in (int, float, str) and type(new) in (int, float, str)


def _sync_table(node: Any, new: dict[str, Any]) -> None:
    """Make the tomlkit table ``node`` hold ``new``, changing only the values that differ."""
    for key in [k for k in node if k not in new]:
        del node[key]
    for key, value in new.items():
        if key not in node:
            node[key] = value
        else:
            _sync_entry(node, key, value)


def _multiline(value: Any) -> Any:
    """An array of arrays (a capture's ``image_px``) as a tomlkit array of one item a line."""
    if isinstance(value, list) and value and all(isinstance(v, list) for v in value):
        array = tomlkit.array()
        array.extend(value)
        array.multiline(True)
        return array
    return value


def _sync_entry(container: Any, key: Any, new: Any) -> None:
    """Set ``container[key]`` to ``new`` in place: unchanged values keep their text."""
    old = container[key]
    if isinstance(new, dict) and isinstance(old, _TABLES):
        _sync_table(old, new)
    elif isinstance(new, list) and isinstance(old, _ARRAYS):
        for i in range(min(len(old), len(new))):
            _sync_entry(old, i, new[i])
        while len(old) > len(new):
            del old[len(old) - 1]
        grown = len(new) > len(old)
        for value in new[len(old) :]:
            if isinstance(old, tomlkit.items.AoT) and isinstance(value, dict):
                table = tomlkit.table()
                for key, v in value.items():
                    table.add(key, _multiline(v))
                table.add(tomlkit.nl())  # a blank line before the next table, as written anew
                value = table
            old.append(value)
        if grown and isinstance(old, tomlkit.items.Array) and any(isinstance(v, list) for v in new):
            old.multiline(True)  # a capture's new image_px: one [u, v] a line, as written anew
    elif not _same(old, new):
        container[key] = new  # tomlkit keeps the old value's indent and trailing comment


def _edited_text(text: str, ds: Dataset, version: int) -> str:
    """``text`` (a dataset's TOML) with its values changed to ``ds``'s, layout and comments kept."""
    doc = tomlkit.parse(text)
    new = dataset_to_document(ds, version)
    if "search" not in new and "search" in doc:
        new["search"] = {}  # keep the (now empty) table and its comments
    _sync_table(doc, new)
    return tomlkit.dumps(doc)


def update_dataset(
    path: str | Path,
    new: Dataset | Callable[[Dataset], Dataset],
    *,
    keep_backup: bool = True,
    backup: str | Path | None = None,
) -> Path | None:
    """Change the values of the dataset file at ``path`` to ``new``'s, keeping the file's text.

    Only the values that differ are rewritten (with tomlkit), so the user's comments, key order
    and layout survive; a version-1 file stays version 1 while ``new`` fits it. ``new`` may be
    a function of the dataset on disk (read once, so an edit made since the caller loaded it is
    not undone). The current file must be a valid dataset; the edited text is validated as
    :func:`load_dataset` would and must read back equal to ``new`` before anything is written;
    then the previous bytes go to ``backup`` (by default a new :func:`backup_path`, so every
    version is kept; with ``keep_backup``) and the file is replaced, both or neither, so a
    failure at any point leaves the file and its backups byte-identical. Raises
    :class:`InputError` naming the file and field.

    Returns the backup written, or ``None`` if there was none (``keep_backup=False``, or the
    file already held these values: then nothing is written).
    """
    path = Path(path)
    raw, text = read_text(path, MAX_DATASET_BYTES)
    current = parse_dataset_text(text, path)
    ds = new(current) if callable(new) else new
    if ds == current:
        return None
    try:
        edited = _edited_text(text, ds, current.version)
    except (tomlkit.exceptions.TOMLKitError, KeyError, TypeError, ValueError) as e:
        why = f"cannot edit the file in place ({e}); nothing written"
        raise InputError(path, "", why) from None
    check = parse_dataset_text(edited, path, " after editing in place; nothing written")
    if check != ds:
        raise InputError(path, "", "editing in place does not read back equal; nothing written")
    data = (_BOM if raw.startswith(_BOM) else b"") + edited.encode("utf-8")
    # The backup and the new file land together: a failed write keeps the old backups too.
    target = (Path(backup) if backup else backup_path(path)) if keep_backup else None
    files = {target: raw} if target is not None else {}
    StagedFiles({**files, path: data}).commit()
    return target
