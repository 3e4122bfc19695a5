"""Typed payloads: a frozen dataclass is written to a JSON document and read back, checked
whole, by one description, its own fields.

A field's annotation says what its value is; :func:`spec` adds its JSON key where it differs
from the field's name (``F`` for ``F_mm``), a further check of the value (``length``: a
finite number >= 0), and when the key is left out (``omit="none"`` or ``"empty"``).
:func:`to_document` writes a payload in field order; :func:`read` checks a document and builds
the payload, naming the file and the field of the first thing wrong (an
:class:`~handeye_jax.InputError`). A missing field takes its default, or is an error if it
has none. Keys a payload does not know are left unread (older and newer files load) unless
the class sets ``strict = True``.

Annotations understood: ``float``, ``int``, ``bool``, ``str``, ``X | None``,
``tuple[X, ...]`` and ``tuple[X, Y]`` (arrays), ``dict[str, X]`` (objects), ``Literal[...]``
and nested payloads. A class with its own JSON form defines ``to_json()`` and a classmethod
``from_json(reader, value, where)``; one with rules across its fields, ``checked(reader,
where)``, which returns the payload (brought up to date, for a legacy form).
"""

from __future__ import annotations

import dataclasses
import difflib
import types
import typing
from collections.abc import Callable
from functools import cache
from typing import Any, Literal

from ._errors import InputError
from ._validate import Reader, describe, join_key

OMIT_NONE = "none"
OMIT_EMPTY = "empty"
Check = Callable[[Reader, Any, str], Any]


def spec(
    key: str | None = None,
    *,
    check: Check | None = None,
    omit: Literal["none", "empty"] | None = None,
    **field_options: Any,
) -> Any:
    """A payload field: its JSON ``key`` (default: the field's name), a further ``check`` of
    its value once read, and ``omit``: leave the key out when the value is ``None`` or empty."""
    metadata = {"key": key, "check": check, "omit": omit}
    return dataclasses.field(metadata=metadata, **field_options)


def length(r: Reader, x: float, where: str) -> float:
    """A length or a mean of lengths, mm: >= 0."""
    if x < 0:
        r.fail(where, f"must be >= 0 mm (got {x})")
    return x


def count(r: Reader, x: int, where: str) -> int:
    """A count: >= 0."""
    if x < 0:
        r.fail(where, f"must be at least 0 (got {x})")
    return x


def bounded(limit: float, *, positive: bool = False) -> Check:
    """A number at most ``limit`` in magnitude (and > 0 if ``positive``)."""

    def check(r: Reader, x: float, where: str) -> float:
        return r.number(x, where, positive=positive, limit=limit)

    return check


def each(check: Check) -> Check:
    """``check`` applied to every number of an array (of arrays) or object."""

    def check_all(r: Reader, x: Any, where: str) -> Any:
        if isinstance(x, tuple):
            return tuple(check_all(r, v, f"{where}[{i}]") for i, v in enumerate(x))
        if isinstance(x, dict):
            return {k: check_all(r, v, join_key(where, k)) for k, v in x.items()}
        return x if x is None else check(r, x, where)

    return check_all


@cache
def _fields(cls: type) -> tuple[tuple[dataclasses.Field, str, Any], ...]:
    hints = typing.get_type_hints(cls)
    return tuple((f, f.metadata.get("key") or f.name, hints[f.name])
                 for f in dataclasses.fields(cls))  # fmt: skip


def _omitted(value: Any, omit: str | None) -> bool:
    if omit == OMIT_NONE:
        return value is None
    if omit == OMIT_EMPTY:
        return value is None or len(value) == 0
    return False


def to_document(value: Any) -> Any:
    """A payload (or any value inside one) as JSON-ready values."""
    if hasattr(value, "to_json"):
        return value.to_json()
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        out = {}
        for f, key, _ in _fields(type(value)):
            v = getattr(value, f.name)
            if not _omitted(v, f.metadata.get("omit")):
                out[key] = to_document(v)
        return out
    if isinstance(value, tuple | list):
        return [to_document(v) for v in value]
    if isinstance(value, dict):
        return {str(k): to_document(v) for k, v in value.items()}
    if hasattr(value, "tolist"):  # a NumPy scalar or array
        return value.tolist()
    return value


def read(r: Reader, cls: type, doc: Any, where: str = "") -> Any:
    """The payload ``cls`` from a parsed document, every field checked (see the module)."""
    if hasattr(cls, "from_json"):
        return cls.from_json(r, doc, where)
    if not isinstance(doc, dict):
        r.fail(where, f"must be an object (got {describe(doc)})")
    fields = _fields(cls)
    if getattr(cls, "strict", False):
        keys = [key for _, key, _ in fields]
        for k in doc:
            if k not in keys:
                hint = difflib.get_close_matches(k, keys, n=1)
                expected = f"did you mean {hint[0]!r}?" if hint else f"expected {', '.join(keys)}"
                r.fail(join_key(where, k), f"unknown key; {expected}")
    values = {}
    for f, key, hint in fields:
        at = join_key(where, key)
        if key not in doc:
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                r.fail(at, "missing")
            continue
        value = _read(r, hint, doc[key], at)
        check = f.metadata.get("check")
        values[f.name] = value if check is None or value is None else check(r, value, at)
    try:
        out = cls(**values)
    except InputError:
        raise
    except (ValueError, TypeError) as e:  # the class's own checks, e.g. a negative sigma
        r.fail(where, str(e))
    # Rules across fields (lengths that must agree, legacy forms brought up to date).
    return out.checked(r, where) if hasattr(out, "checked") else out


def _read(r: Reader, hint: Any, x: Any, where: str) -> Any:
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        if x is None and type(None) in args:
            return None
        (inner,) = [a for a in args if a is not type(None)]
        return _read(r, inner, x, where)
    if isinstance(hint, type) and (dataclasses.is_dataclass(hint) or hasattr(hint, "from_json")):
        return read(r, hint, x, where)
    if origin is tuple:
        return _read_tuple(r, args, x, where)
    if origin is dict:
        if not isinstance(x, dict):
            r.fail(where, f"must be an object (got {describe(x)})")
        return {k: _read(r, args[1], v, join_key(where, k)) for k, v in x.items()}
    if origin is Literal:
        if x not in args or isinstance(x, bool) != isinstance(args[0], bool):
            r.fail(where, f"must be one of {', '.join(map(repr, args))} (got {describe(x)})")
        return x
    return _read_scalar(r, hint, x, where)


def _read_tuple(r: Reader, args: tuple, x: Any, where: str) -> tuple:
    if not isinstance(x, list):
        r.fail(where, f"must be an array (got {describe(x)})")
    if len(args) == 2 and args[1] is Ellipsis:
        return tuple(_read(r, args[0], v, f"{where}[{i}]") for i, v in enumerate(x))
    if len(x) != len(args):
        r.fail(where, f"must be an array of {len(args)} (got {describe(x)})")
    pairs = enumerate(zip(args, x, strict=True))
    return tuple(_read(r, a, v, f"{where}[{i}]") for i, (a, v) in pairs)


def _read_scalar(r: Reader, hint: Any, x: Any, where: str) -> Any:
    if hint is float:
        return r.number(x, where)
    if hint is bool:
        if not isinstance(x, bool):
            r.fail(where, f"must be true or false (got {describe(x)})")
        return x
    if hint is int:
        if isinstance(x, bool) or not isinstance(x, int):
            r.fail(where, f"must be an integer (got {describe(x)})")
        return x
    if hint is str:
        if not isinstance(x, str):
            r.fail(where, f"must be a string (got {describe(x)})")
        return x
    raise TypeError(f"a payload field of type {hint!r} has no reader")
