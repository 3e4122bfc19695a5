"""The one exception type for bad user input (files, fields, command-line values)."""

from __future__ import annotations

from pathlib import Path


class InputError(ValueError):
    """Bad user input. ``str()`` is one line: ``'<path>: <field>: <message>'``.

    The path is left out when it is ``None`` and the field when it is ``""``.

    Attributes:
        path: the file the input came from (``str``, :class:`~pathlib.Path` or ``None``).
        field: where in the file, e.g. ``"landmarks[3].depth"``; ``""`` for the whole file.
        message: what was expected and what was found, e.g. ``"must be > 0 (got -1.0)"``.
    """

    def __init__(self, path: str | Path | None, field: str, message: str):
        self.path = path
        self.field = field
        self.message = message
        super().__init__(self._line())

    def _line(self) -> str:
        parts = [str(p) for p in (self.path, self.field) if p is not None and str(p) != ""]
        parts.append(self.message)
        return " ".join(": ".join(parts).splitlines())

    def __str__(self) -> str:
        return self._line()

    def __reduce__(self):  # pickle with the three-argument constructor
        return (type(self), (self.path, self.field, self.message))
