"""Reading input files safely: regular files only, never more than a stated size.

Every loader reads through :func:`read_bytes`. The file is opened once, without blocking (a
FIFO with no writer cannot hang the open), and the opened descriptor is checked with
``fstat``, so nothing can swap the file between a check and the open: a folder, FIFO, device
or socket is refused, and at most ``cap`` bytes are read. The parsers turn what the standard
library raises on hostile text (nesting deeper than the recursion limit, integers of more
than 4,300 digits, CSV fields over 131,072 characters) into an
:class:`~handeye_jax._core.InputError` naming the file, like any other bad input.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import os
import stat
import tomllib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from ._atomic import reason
from ._errors import InputError
from ._validate import join_key

MiB = 1 << 20
#: Largest JSON or CSV input (truth, targets, trials, points, held-out targets), bytes.
MAX_TEXT_BYTES = 16 * MiB
#: Largest dataset, bytes. TOML is parsed in pure Python (16 MiB took 6-17 s); this holds
#: MAX_LANDMARKS landmarks in the canonical layout (1.4 MiB) with room for comments.
MAX_DATASET_BYTES = 4 * MiB
#: Largest result, bytes: one with MAX_LANDMARKS landmarks and diagnostics is about 11 MiB.
MAX_RESULT_BYTES = 32 * MiB
#: Most objects in a JSON file: a result with MAX_LANDMARKS landmarks holds about 50,000. A
#: file of nothing but ``{}`` would otherwise cost 75 bytes of memory per byte of text.
MAX_JSON_OBJECTS = 1_000_000
#: Largest picture or depth image file, bytes.
MAX_IMAGE_BYTES = 64 * MiB

_KINDS = (
    (stat.S_ISDIR, "a folder"),
    (stat.S_ISFIFO, "a FIFO"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)
_FLAGS = os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_NOCTTY", 0) | getattr(os, "O_BINARY", 0)


def size_text(n: int) -> str:
    """A size in bytes for messages: ``'16 MiB'``, ``'20.5 MiB'``, ``'300 bytes'``."""
    if n < MiB:
        return f"{n:,} bytes"
    return f"{n / MiB:.1f}".removesuffix(".0") + " MiB"


def read_bytes(path: str | Path, cap: int, what: str = "file") -> bytes:
    """The bytes of the regular file ``path``, at most ``cap`` of them.

    Raises :class:`InputError` naming ``path`` ("cannot read ``what``: ...") if it cannot be
    opened, is not a regular file, or holds more than ``cap`` bytes.
    """
    path = Path(path)

    def fail(why: str):
        raise InputError(path, "", f"cannot read {what}: {why}")

    try:
        fd = os.open(path, _FLAGS)
    except OSError as e:
        fail(reason(e))
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            kind = next((k for is_kind, k in _KINDS if is_kind(info.st_mode)), "not a file")
            fail(f"not a regular file ({kind})")
        too_big = f"larger than {size_text(cap)}, the most this toolkit reads for one {what}"
        if info.st_size > cap:
            fail(f"is {info.st_size:,} bytes, {too_big}")
        chunks, total = [], 0
        while chunk := os.read(fd, min(cap + 1 - total, MiB)):
            chunks.append(chunk)
            total += len(chunk)
            if total > cap:  # it grew since the fstat
                fail(too_big)
        return b"".join(chunks)
    except OSError as e:
        fail(reason(e))
    finally:
        os.close(fd)


def read_text(path: str | Path, cap: int, what: str = "file") -> tuple[bytes, str]:
    """The file's bytes (:func:`read_bytes`) and its text, UTF-8 with an optional BOM."""
    raw = read_bytes(path, cap, what)
    try:
        return raw, raw.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        raise InputError(path, "", f"cannot read {what}: not UTF-8 text ({e})") from None


# -- parsing ---------------------------------------------------------------------------------


def parse_toml(text: str, path: str | Path | None, context: str = "") -> dict[str, Any]:
    """The parsed TOML document; ``context`` is added to a syntax error's message."""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise InputError(path, "", f"not valid TOML{context}: {e}") from None
    except RecursionError:
        raise InputError(path, "", "not valid here: arrays or tables nested too deeply") from None
    except ValueError as e:  # an integer beyond Python's limit on digits
        raise InputError(path, "", f"not valid here: {_digits(str(e))}") from None


def _digits(message: str) -> str:
    if "digits" in message:
        return "an integer of more than 4,300 digits"
    return " ".join(message.split())


def load_json(path: str | Path, cap: int = MAX_TEXT_BYTES, what: str | None = None) -> Any:
    """Read (:func:`read_text`) and parse (:func:`parse_json`) a JSON file.

    ``what`` names the file in messages ("cannot read ``what``: ..."), syntax errors included.
    """
    _, text = read_text(path, cap, what or "file")
    return parse_json(text, path, f"cannot read {what}: " if what else "")


def parse_json(text: str, path: str | Path | None, lead: str = "") -> Any:
    """The parsed JSON document; raises :class:`InputError` (``lead`` + why) naming ``path``.

    A key repeated within an object is an error (not "the last one wins"), named with its
    path, e.g. ``rig.camera_px.fx``; so are nesting deeper than Python's recursion limit,
    integers of more digits than Python converts and more than :data:`MAX_JSON_OBJECTS`
    objects.
    """

    def fail(field: str, why: str):
        raise InputError(path, field, f"{lead}{why}")

    def parse_int(digits: str) -> int:
        try:
            return int(digits)
        except ValueError:  # beyond Python's limit on digits
            fail("", f"not valid here: an integer of {len(digits.lstrip('-'))} digits")

    objects = 0
    repeated = False

    def from_pairs(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
        nonlocal objects, repeated
        objects += 1
        if objects > MAX_JSON_OBJECTS:
            fail("", f"not valid here: more than {MAX_JSON_OBJECTS:,} objects")
        obj = dict(pairs)
        if len(obj) == len(pairs):
            return obj
        repeated = True
        return _Object.marked(obj, pairs)

    try:
        doc = json.loads(text, object_pairs_hook=from_pairs, parse_int=parse_int)
    except json.JSONDecodeError as e:
        fail("", f"not valid JSON: {e}")
    except RecursionError:
        fail("", "not valid here: arrays or objects nested too deeply")
    if repeated:  # only then walk the document, to name where
        raise InputError(path, _repeated_key(doc), "duplicate key: a key may appear only once "
                         "in an object")  # fmt: skip
    return doc


class _Object(dict):
    """A JSON object with a repeated key: ``repeated`` is the first such key."""

    repeated: str

    @classmethod
    def marked(cls, obj: dict[str, Any], pairs: list[tuple[str, Any]]) -> _Object:
        seen: set[str] = set()
        for key, _ in pairs:
            if key in seen:
                break
            seen.add(key)
        out = cls(obj)
        out.repeated = key
        return out


def _repeated_key(doc: Any) -> str:
    """Where the first repeated key in document order is, e.g. ``rig.camera_px.fx``."""
    stack: list[tuple[tuple, Any]] = [((), doc)]
    while stack:
        path, x = stack.pop()
        if isinstance(x, _Object):
            path = (*path, x.repeated)
            break
        items = x.items() if isinstance(x, dict) else enumerate(x)
        stack.extend(reversed([((*path, k), v) for k, v in items if isinstance(v, dict | list)]))
    where = ""
    for k in path:
        where = f"{where}[{k}]" if isinstance(k, int) else join_key(where, k)
    return where


def csv_rows(text: str, path: str | Path | None) -> Iterator[list[str]]:
    """The rows of a CSV text that hold something (blank rows are skipped as they are read).

    A field over the csv module's limit, or anything else it cannot read, raises
    :class:`InputError` naming ``path`` and the line.
    """
    reader = csv.reader(io.StringIO(text))
    try:
        for row in reader:
            if any(cell.strip() for cell in row):
                yield row
    except csv.Error as e:
        where = f"line {reader.line_num}"
        if "field limit" in str(e):
            limit = csv.field_size_limit()
            raise InputError(path, where, f"has a field longer than {limit:,} characters") from None
        raise InputError(path, where, f"not valid CSV: {e}") from None


# -- digests ---------------------------------------------------------------------------------

#: The key under which a written document carries :func:`document_digest` of the rest of it.
DIGEST_KEY = "content_sha256"


def document_digest(doc: dict[str, Any]) -> str:
    """SHA-256 (hex) of a JSON document's canonical text: sorted keys, no spaces, floats as
    Python's shortest round-trip repr. The same document gives the same digest however its
    file is indented, so a reader can tell a file as it was written from an edited one.
    Raises ``ValueError`` for what JSON cannot hold (NaN, infinities)."""
    text = json.dumps(doc, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(text.encode()).hexdigest()
